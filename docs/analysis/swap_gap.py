"""Where the car is when an intent swap happens, and where the drivers of each intent ever are.

An intent-swap trial replaces the human mid-episode (`d2a intent-swap`). This reads the trials'
episode logs and prints, per trial, the gap to the opponent at the swap and at the end, the new
driver's mean throttle after the swap (assisted and, on the same env seed, unassisted), the
assistant's throttle and its estimate of the new intent. Given evaluation artifacts (`d2a eval`),
it also prints, per intent and gap band, how many steps the drivers spent there and what the
assistant read: a state no driver of an intent ever reached is one the intent head has never seen
labelled with that intent.

    python docs/analysis/swap_gap.py STORE SWAP_ID [SWAP_ID ...] [--eval EVAL_ID ...] [--direction to-pass|to-stay]
"""

from __future__ import annotations

import argparse
import collections

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.sim.episode_log.reader import read_episode

BANDS = ((-np.inf, -50.0), (-50.0, -20.0), (-20.0, 0.0), (0.0, np.inf))
"""Gap bands (m, ego ahead positive), after the first second, when both cars are still side by side."""


def _col(episode, agent: str, name: str) -> np.ndarray:
    return np.asarray(episode.state[agent][name], float)


def swap_rows(store: Store, swap_id: str, new_label: int) -> None:
    art = store.get(swap_id)
    print(f"intent-swap {art.id[:12]} (assistant seed {art.labels.get('seed', art.seed)}):")
    print("  first -> second human | swap step | gap at swap / end m | new driver's throttle, assisted | "
          "assistant's throttle | p(new intent) | unassisted: throttle, gap at end m")
    for name in sorted(art.files):
        if not (name.startswith("episodes/assisted/") and name.endswith(".mcap")):
            continue
        ep = read_episode(store.path(art.id, name))
        meta = ep.metadata
        if meta["swap_label"] != new_label:
            continue
        k = int(meta["swap_step"])
        alone = read_episode(store.path(art.id, name.replace("/assisted/", "/unassisted/")))
        gap = _col(ep, "ego", "ds")
        p_new = _col(ep, "assistant", f"intent_probs.{'pass' if new_label == 0 else 'stay'}")
        print(f"  {meta['human']:>3} -> {meta['swap_human']:<3} | {k:>4} | {gap[k]:+6.0f} / {gap[-1]:+5.0f} | "
              f"{np.nanmean(_col(ep, 'ego', 'human_action.accel')[k:]):+.2f} | "
              f"{np.nanmean(_col(ep, 'ego', 'assistant_action.accel')[k:]):+.2f} | {np.nanmean(p_new[k:]):.2f} | "
              f"{np.nanmean(_col(alone, 'ego', 'human_action.accel')[k:]):+.2f}, {_col(alone, 'ego', 'ds')[-1]:+.0f}")


def band_rows(store: Store, eval_id: str) -> None:
    art = store.get(eval_id)
    steps, throttle, p_pass = (collections.defaultdict(list) for _ in range(3))
    for name in sorted(art.files):
        if not name.endswith(".mcap"):
            continue
        condition = name.split("/")[1]
        ep = read_episode(store.path(art.id, name))
        gap = _col(ep, "ego", "ds")
        accel = _col(ep, "ego", "human_action.accel")
        later = np.arange(len(gap)) >= 10
        for lo, hi in BANDS:
            mask = later & (gap >= lo) & (gap < hi)
            key = (condition, ep.metadata["intent"], lo)
            steps[key].append(int(mask.sum()))
            throttle[key].extend(accel[mask].tolist())
            if "assistant" in ep.state:
                p_pass[key].extend(_col(ep, "assistant", "intent_probs.pass")[mask].tolist())
    print(f"eval {art.id[:12]}: steps after the first second, by gap to the opponent")
    print("  condition | intent | gap band m | steps | driver's throttle | p(pass)")
    for (condition, intent, lo), counts in sorted(steps.items()):
        hi = dict(BANDS)[lo]
        n = sum(counts)
        th = f"{np.nanmean(throttle[(condition, intent, lo)]):+.2f}" if n else "-"
        pp = np.asarray(p_pass[(condition, intent, lo)], float)
        read = f"{np.nanmean(pp):.2f}" if np.isfinite(pp).any() else "-"  # unassisted logs carry no estimate
        print(f"  {condition} | {intent} | [{lo:+.0f}, {hi:+.0f}) | {n} | {th} | {read}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store")
    ap.add_argument("swaps", nargs="+", help="intent-swap artifact ids")
    ap.add_argument("--eval", nargs="*", default=[], help="evaluation artifact ids (d2a eval)")
    ap.add_argument("--direction", choices=("to-pass", "to-stay"), default="to-pass")
    args = ap.parse_args()
    store = Store(args.store)
    for swap_id in args.swaps:
        swap_rows(store, swap_id, 0 if args.direction == "to-pass" else 1)
    for eval_id in args.eval:
        band_rows(store, eval_id)


if __name__ == "__main__":
    main()
