"""The intent head's accuracy along assistant runs: on its own replay batches (`wm/intent_accuracy`,
the data it is trained on) and on the run's recent training episodes (`episode/intent_accuracy`),
one line per run. docs/experiments/intent-estimate.md, "The humans' mode actions in training
(adopted)".

    python docs/analysis/intent_head_curves.py STORE OUT.png RUN_ID [RUN_ID ...]

RUN_ID: `assistant-run` artifacts (the `run_id` of `d2a train-assistant --json`) or their aliases.
"""

from __future__ import annotations

import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from d2a_core.artifacts import Store  # noqa: E402

PANELS = (("wm/intent_accuracy", "replay batches (training data)"),
          ("episode/intent_accuracy", "recent training episodes"))


def main(store_path: str, out: str, refs: list[str]) -> None:
    store = Store(store_path)
    fig, axes = plt.subplots(1, len(PANELS), figsize=(8.0, 2.8), sharey=True, layout="constrained")
    for ref in refs:
        art = store.get(ref)
        rows = [json.loads(line) for line in store.path(art.id, "curve.jsonl").read_text().splitlines()]
        label = f"seed {art.seed} ({art.id[:8]})"
        for ax, (key, _) in zip(axes, PANELS):
            points = [(r["env_step"], r[key]) for r in rows if r.get(key) is not None]
            ax.plot(*zip(*points), marker=".", label=label)
    for ax, (key, title) in zip(axes, PANELS):
        ax.set_title(f"{title}\n{key}", fontsize=9)
        ax.set_xlabel("env steps")
        ax.axhline(0.95, color="grey", linestyle="--", linewidth=0.8)
    axes[0].set_ylabel("per-step intent accuracy")
    axes[0].legend(fontsize=7)
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
