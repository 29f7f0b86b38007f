"""What a group's collisions are: contacts with the opponent or with the barrier, and where.

`d2a eval` counts an episode as collided when the car touched the opponent or a barrier. This
splits that share per intent and human group (unassisted → assisted) and, from the assisted
episodes' logs, says where the contacts happened: the gap to the opponent (ego ahead positive),
the lateral offset (positive = left), and the assistant's and the applied steering at the
contact (positive = left). It tells an assistant that presses a driver into the opponent from
one that presses it into the wall. It also splits off the episodes that ended off the road
(the other way to crash) and says where the assisted car left it.

    python docs/analysis/contacts.py STORE EVAL_ID [EVAL_ID ...]
"""

from __future__ import annotations

import collections
import sys

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.sim.episode_log.reader import read_episode

GROUPS = ("imperfect", "near_perfect")


def _col(episode, name: str) -> np.ndarray:
    return np.asarray(episode.state["ego"][name], float)


def contact_steps(store: Store, art_id: str, name: str) -> list[tuple[float, ...]]:
    """(gap m, lateral m, assistant steer, applied steer) at each step in contact."""
    ep = read_episode(store.path(art_id, name))
    hit = _col(ep, "collision").astype(bool)
    columns = [_col(ep, key) for key in ("ds", "e", "assistant_action.steer", "applied_action.steer")]
    return [tuple(float(c[i]) for c in columns) for i in np.flatnonzero(hit)]


def off_track_end(store: Store, art_id: str, name: str) -> tuple[float, ...]:
    """(s m, gap m, lateral m, speed m/s) at the step that left the road."""
    ep = read_episode(store.path(art_id, name))
    return tuple(float(_col(ep, key)[-1]) for key in ("s", "ds", "e", "speed"))


def report(store: Store, ref: str) -> None:
    art = store.get(ref)
    data = store.read_json(art.id, "eval.json")
    result = data["result"]
    humans = result["humans"]
    print(f"evaluation {art.id[:12]}: {result['method']} seed {result['seed']}"
          f"{' (held-out humans)' if result['held_out'] else ''}")
    print("  intent, group | opponent contacts unassisted → assisted | barrier contacts unassisted → assisted | "
          "assisted contact steps: gap m, lateral m, assistant steer, applied steer (means) | "
          "off track unassisted → assisted | where assisted cars left the road: s m, gap m, lateral m, speed m/s (means)")
    episodes = collections.defaultdict(list)
    for condition in ("unassisted", "assisted"):
        for ep in data[condition]:
            episodes[(condition, ep["human"])].append(ep)
    names = {}
    for name in art.files:
        if name.startswith("episodes/assisted/") and name.endswith(".mcap"):
            human, seed = name.rsplit("/", 1)[1].removesuffix(".mcap").split("-seed")
            names[(int(human.removeprefix("human")), int(seed))] = name
    for intent in result["intents"]:
        for group in GROUPS:
            members = [i for i, h in enumerate(humans) if h.get("intent") == intent and h.get("group") == group]
            if not members:
                continue
            shares = {}
            for condition in ("unassisted", "assisted"):
                eps = [ep for i in members for ep in episodes[(condition, i)]]
                shares[condition] = (np.mean([ep["collision_car"] for ep in eps]),
                                     np.mean([ep["collision_barrier"] for ep in eps]),
                                     np.mean([ep["off_track"] for ep in eps]))
            steps, ends = [], []
            for i in members:
                for ep in episodes[("assisted", i)]:
                    if ep["collision"] and (i, ep["seed"]) in names:
                        steps += contact_steps(store, art.id, names[(i, ep["seed"])])
                    if ep["off_track"] and (i, ep["seed"]) in names:
                        ends.append(off_track_end(store, art.id, names[(i, ep["seed"])]))
            where = ("none" if not steps else
                     ", ".join(f"{v:+.2f}" for v in np.nanmean(np.asarray(steps), axis=0)) + f" ({len(steps)} steps)")
            left = ("none" if not ends else
                    ", ".join(f"{v:+.1f}" for v in np.mean(np.asarray(ends), axis=0)) + f" ({len(ends)} episodes)")
            print(f"  {intent}, {group.replace('_', '-')} | {shares['unassisted'][0]:.2f} → {shares['assisted'][0]:.2f}"
                  f" | {shares['unassisted'][1]:.2f} → {shares['assisted'][1]:.2f} | {where}"
                  f" | {shares['unassisted'][2]:.2f} → {shares['assisted'][2]:.2f} | {left}")


def main(store_path: str, refs: list[str]) -> None:
    store = Store(store_path)
    for ref in refs:
        report(store, ref)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
