"""The table of docs/experiments/intent-estimate.md, "What the estimate reads, step by step" (and
of docs/results.md, "Straightaway, pass-stay (Table 1)"): per human of a `d2a eval` artifact, the
estimate's probability of the true intent, the human's and the assistant's acceleration, by part
of the episode (each episode cut by its own length), means over the human's assisted episodes;
prints a Markdown table.

    python docs/analysis/intent_by_episode_part.py STORE EVAL_ID
"""

from __future__ import annotations

import json
import sys

import numpy as np

from d2a_core.artifacts import Store

PARTS = ((0, .1), (.1, .25), (.25, .5), (.5, .75), (.75, 1))


def main(store_path: str, ref: str) -> None:
    store = Store(store_path)
    art = store.get(ref)
    steps = np.load(store.path(art.id, "steps.npz"))
    result = json.loads(store.path(art.id, "eval.json").read_text())
    humans = result["result"]["humans"]
    rows: dict[tuple, list[list[float]]] = {}
    for i, episode in enumerate(result["assisted"]):
        mask = steps["episode"] == i
        n = int(mask.sum())
        if not n:
            continue

        def by_part(x: np.ndarray) -> list[float]:
            return [float(x[int(n * a):max(int(n * a) + 1, int(n * b))].mean()) for a, b in PARTS]

        h = humans[episode["human"]]
        rows.setdefault((h["intent"], h["env_step"], h["group"]), []).append(
            by_part(steps["p_true"][mask]) + by_part(steps["human_action"][mask][:, 1])
            + by_part(steps["assistant_action"][mask][:, 1])
            + [episode["finished_ahead"], episode["finished_never_ahead"]])
    print("| human | group | p(true intent): first 10 %, 10-25, 25-50, 50-75, 75-100 % | human accel | "
          "assistant accel | assisted: finished ahead / never ahead |")
    print("|---|---|---|---|---|---|")
    fmt = lambda v: " ".join(f"{x:.2f}" for x in v)  # noqa: E731
    for key in sorted(rows):
        v = np.array(rows[key]).mean(0)
        print(f"| {key[0]} {key[1] / 1000:g}k | {key[2].replace('_', '-')} | {fmt(v[:5])} | {fmt(v[5:10])} | "
              f"{fmt(v[10:15])} | {v[15]:.2f} / {v[16]:.2f} |")


if __name__ == "__main__":
    main(*sys.argv[1:3])
