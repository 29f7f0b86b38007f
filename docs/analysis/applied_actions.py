"""What the car was actually driven with under assistance, per intent and human group, from a
stored `d2a eval`'s per-step log (`steps.npz`): the human's and the assistant's mean action, the
applied (blended, clipped) action's mean and spread, and the per-step correlation of the
assistant's action with the human's (negative: the assistant cancels the human). An assistant
that serves the intent drives pass and stay drivers differently; one that ignores it applies the
same action to both. docs/experiments/assistant-policy.md, "One action for every driver".

    python docs/analysis/applied_actions.py STORE EVAL_ID [EVAL_ID ...]
"""

from __future__ import annotations

import io
import sys

import numpy as np

from d2a_core.artifacts import Store


def main(store_path: str, refs: list[str]) -> None:
    store = Store(store_path)
    print("| evaluation (assistant) | humans | human steer, accel | assistant steer, accel | applied steer: mean ± std "
          "| applied accel: mean ± std | corr(human, assistant): steer, accel |")
    print("|---|---|---|---|---|---|---|")
    for ref in refs:
        eval_id = store.resolve(ref)
        stored = store.read_json(eval_id, "eval.json")
        steps = np.load(io.BytesIO(store.read_bytes(eval_id, "steps.npz")))
        humans, rows, intents = stored["result"]["humans"], stored["assisted"], list(stored["result"]["intents"])
        group = np.array([humans[rows[k]["human"]]["group"] for k in steps["episode"]])
        human, assist = steps["human_action"], steps["assistant_action"]
        applied = np.clip(human + assist, -1.0, 1.0)  # SharedControl's blend
        name = f"`{eval_id[:12]}` ({stored['result']['method']} seed {stored['result']['seed']})"
        for label, intent in enumerate(intents):
            for g in ("imperfect", "near_perfect"):
                mask = (steps["label"] == label) & (group == g)
                if not mask.any():
                    continue
                h, a, b = human[mask], assist[mask], applied[mask]
                corr = [np.corrcoef(h[:, k], a[:, k])[0, 1] for k in (0, 1)]
                print(f"| {name} | {intent} {g.replace('_', '-')} | {h[:, 0].mean():+.2f}, {h[:, 1].mean():+.2f} "
                      f"| {a[:, 0].mean():+.2f}, {a[:, 1].mean():+.2f} | {b[:, 0].mean():+.2f} ± {b[:, 0].std():.2f} "
                      f"| {b[:, 1].mean():+.2f} ± {b[:, 1].std():.2f} | {corr[0]:+.2f}, {corr[1]:+.2f} |")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
