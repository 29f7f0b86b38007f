"""On which side each human drives beside the opponent, unassisted and assisted, from stored
`d2a eval` results: per human, the share of steps on the opponent's left (`share_left`), the
episodes that held the left or the right, and collisions with the car and with the barrier. An
assistant that has learnt one passing side and imposes it shows as drivers moved to that side
whatever side they took alone, and as car collisions where the two disagree.
docs/experiments/assistant-policy.md, "One passing side for everyone (open)".

    python docs/analysis/passing_side.py STORE EVAL_ID [EVAL_ID ...] [--intent pass]

EVAL_ID: `evaluation` artifacts (the `id`s of `d2a eval --json`) or their aliases.
"""

from __future__ import annotations

import numpy as np

from d2a_core.artifacts import Store
from eval_humans import humans_of, parse_args  # beside this script, on sys.path when it runs


def _mean(rows: list[dict], key: str) -> float:
    values = [row[key] for row in rows if row.get(key) is not None]
    return float(np.mean(values)) if values else float("nan")


def _pair(unassisted: list[dict], assisted: list[dict], key: str) -> str:
    return f"{_mean(unassisted, key):.2f} → {_mean(assisted, key):.2f}"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(__doc__.splitlines()[0], argv)
    store = Store(args.store)
    print("| evaluation | human (group, env step) | share of steps on the left | held left / held right "
          "| car collisions | barrier collisions |")
    print("|---|---|---|---|---|---|")
    for eval_id, stored, index, human in humans_of(store, args.evals, args.intent):
        alone = [row for row in stored["unassisted"] if row["human"] == index]
        helped = [row for row in stored["assisted"] if row["human"] == index]
        held = f"{_pair(alone, helped, 'held_left')} / {_pair(alone, helped, 'held_right')}"
        print(f"| `{eval_id[:12]}` | {human['group']}, {human['env_step'] // 1000}k "
              f"| {_pair(alone, helped, 'share_left')} | {held} "
              f"| {_pair(alone, helped, 'collision_car')} | {_pair(alone, helped, 'collision_barrier')} |")
    print("\nEach cell: unassisted → assisted, the mean over the human's paired episodes.")


if __name__ == "__main__":
    main()
