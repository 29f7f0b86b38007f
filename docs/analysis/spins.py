"""How often a group's cars spin, and what the assistant does while they do.

A car spins when its rear lets go: the sideslip (the angle between where the car points and
where it moves) grows past what a driver can catch. This counts, per intent and human group
(unassisted → assisted), the share of episodes in which the sideslip passed `SPIN_RAD`, how many
of those episodes ended in a collision or off the road, and, over the assisted steps in a spin,
the human's and the assistant's mean throttle and the assistant's steering along the slip
(positive: counter-steering), and its counter-steer while a slide is still small
(`SLIDE_RAD`). A driver catches a slide by counter-steering early and a spin by lifting the
throttle; an assistant that waits, then holds the throttle open, keeps the rear sliding.

    python docs/analysis/spins.py STORE EVAL_ID [EVAL_ID ...]
"""

from __future__ import annotations

import collections
import sys

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.sim.episode_log.reader import read_episode
from eval_table import GROUPS  # this script's folder is on the path when it runs

SPIN_RAD = 0.3  # sideslip (rad) past which a `quick` driver alone never recovered on the straightaway
SLIDE_RAD = (0.1, 0.2)  # a slide still caught by counter-steering


def episode_spin(store: Store, art_id: str, name: str) -> tuple[bool, np.ndarray, np.ndarray]:
    """Whether the episode spun; (human accel, assistant accel, assistant steer along the slip)
    at each step in a spin; the assistant's steer along the slip at each step of a small slide."""
    ego = read_episode(store.path(art_id, name)).state["ego"]

    def col(key: str) -> np.ndarray:
        return np.nan_to_num(np.asarray(ego[key], float))  # the first step has no action yet

    slip = col("sideslip")
    spin = np.abs(slip) > SPIN_RAD
    steps = np.stack([col("human_action.accel")[spin], col("assistant_action.accel")[spin],
                      col("assistant_action.steer")[spin] * np.sign(slip[spin])], axis=1)
    slide = (np.abs(slip) > SLIDE_RAD[0]) & (np.abs(slip) <= SLIDE_RAD[1])
    return bool(spin.any()), steps, col("assistant_action.steer")[slide] * np.sign(slip[slide])


def report(store: Store, ref: str) -> None:
    art = store.get(ref)
    data = store.read_json(art.id, "eval.json")
    result = data["result"]
    humans = result["humans"]
    print(f"evaluation {art.id[:12]}: {result['method']} seed {result['seed']}"
          f"{' (held-out humans)' if result['held_out'] else ''}")
    print("  intent, group | episodes that spin, unassisted → assisted | of those, ended crashed (collision or off "
          "road) | assisted spin steps: human accel, assistant accel, assistant steer along the slip (means) | "
          f"assisted slide steps (sideslip {SLIDE_RAD[0]}-{SLIDE_RAD[1]} rad): assistant steer along the slip")
    ended = {}
    for condition in ("unassisted", "assisted"):
        for ep in data[condition]:
            ended[(condition, ep["human"], ep["seed"])] = bool(ep["collision"] or ep["off_track"])
    spins: dict[tuple, list] = collections.defaultdict(list)
    for name in sorted(art.files):
        if not (name.startswith("episodes/") and name.endswith(".mcap")):
            continue
        condition = name.split("/")[1]
        human, seed = name.rsplit("/", 1)[1].removesuffix(".mcap").split("-seed")
        human, seed = int(human.removeprefix("human")), int(seed)
        spun, steps, slide = episode_spin(store, art.id, name)
        spins[(condition, human)].append((spun, ended.get((condition, human, seed), False), steps, slide))
    for intent in result["intents"]:
        for group in GROUPS:
            members = [i for i, h in enumerate(humans) if h.get("intent") == intent and h.get("group") == group]
            cells = {}
            for condition in ("unassisted", "assisted"):
                eps = [ep for i in members for ep in spins[(condition, i)]]
                if not eps:
                    continue
                spun = [ep for ep in eps if ep[0]]
                crashed = np.mean([ep[1] for ep in spun]) if spun else float("nan")
                cells[condition] = (np.mean([ep[0] for ep in eps]), crashed, len(spun))
            if len(cells) < 2:
                continue
            steps = [ep[2] for i in members for ep in spins[("assisted", i)] if len(ep[2])]
            during = ("none" if not steps else
                      ", ".join(f"{v:+.2f}" for v in np.concatenate(steps).mean(axis=0))
                      + f" ({sum(len(s) for s in steps)} steps)")
            slides = np.concatenate([ep[3] for i in members for ep in spins[("assisted", i)]])
            early = "none" if not len(slides) else f"{slides.mean():+.2f} ({len(slides)} steps)"
            (u_share, u_crash, u_n), (a_share, a_crash, a_n) = cells["unassisted"], cells["assisted"]
            print(f"  {intent}, {group.replace('_', '-')} | {u_share:.2f} → {a_share:.2f} | "
                  f"{u_crash:.2f} ({u_n}) → {a_crash:.2f} ({a_n}) | {during} | {early}")


def main(store_path: str, refs: list[str]) -> None:
    store = Store(store_path)
    for ref in refs:
        report(store, ref)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
