"""What the human and the assistant do as the car closes on the opponent, from the assisted MCAP
episode logs of stored `d2a eval` results: per human of one intent, over its assisted episodes,
the share that collided, the smallest lateral gap |de| while closing in or alongside (ds in
[-12 m, +2 m]), and the mean steer and throttle of the human and of the assistant there. An
assistant whose steer is the human's negated holds the car on its line against the driver.
docs/experiments/assistant-policy.md, "One passing side for everyone (open)".

    python docs/analysis/pass_approach.py STORE EVAL_ID [EVAL_ID ...] [--intent pass]
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.sim.episode_log.reader import read_episode
from eval_humans import humans_of, parse_args  # beside this script, on sys.path when it runs

CLOSING_M = (-12.0, 2.0)  # ds window: a car length or so behind, up to alongside


def episode_row(path: Path) -> tuple[float, ...] | None:
    """(collided, min |de| while closing, human steer, assistant steer, human accel, assistant
    accel) of one episode; None when the car never got close to the opponent."""
    ego = read_episode(path).state["ego"]
    ds, de = np.asarray(ego["ds"]), np.asarray(ego["de"])
    near = (ds > CLOSING_M[0]) & (ds < CLOSING_M[1])
    if not near.any():
        return None
    field = lambda name: float(np.asarray(ego[name])[near].mean())  # noqa: E731
    return (float(np.asarray(ego["collision"]).astype(bool).any()), float(np.abs(de[near]).min()),
            field("human_action.steer"), field("assistant_action.steer"),
            field("human_action.accel"), field("assistant_action.accel"))


def main(argv: list[str] | None = None) -> None:
    args = parse_args(__doc__.splitlines()[0], argv)
    store = Store(args.store)
    print("| evaluation | human (group, env step) | episodes near the opponent | collided | min lateral gap m "
          "| steer: human / assistant | throttle: human / assistant |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "episode.mcap"
        for eval_id, _, index, human in humans_of(store, args.evals, args.intent):
            logs = [name for name in store.get(eval_id).files
                    if name.startswith("episodes/assisted/") and Path(name).name.startswith(f"human{index:03d}-")]
            rows = []
            for name in logs:
                path.write_bytes(store.read_bytes(eval_id, name))
                row = episode_row(path)
                if row is not None:
                    rows.append(row)
            if not rows:
                continue
            r = np.array(rows).mean(axis=0)
            print(f"| `{eval_id[:12]}` | {human['group']}, {human['env_step'] // 1000}k | {len(rows)} | {r[0]:.2f} "
                  f"| {r[1]:.1f} | {r[2]:+.2f} / {r[3]:+.2f} | {r[4]:+.2f} / {r[5]:+.2f} |")
    print("\nMeans over the human's assisted episodes that came within the ds window "
          f"[{CLOSING_M[0]:g} m, {CLOSING_M[1]:g} m] of the opponent; steer and throttle are means over those steps.")


if __name__ == "__main__":
    main()
