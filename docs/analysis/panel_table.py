"""The training panel of assistant runs as a markdown table: per checkpoint, the intent estimate's
per-step F1, what assistance changed for the weak humans and the experts of each intent (the
panel rule: the weak humans gain progress, the experts keep >= 95 % of theirs), and the
estimate's accuracy per panel group. The panel tables of docs/results.md and docs/experiments/
come from it.

    python docs/analysis/panel_table.py STORE RUN_ID [RUN_ID ...]

RUN_ID: `assistant-run` artifacts (the `run_id` of `d2a train-assistant --json`) or their aliases.
"""

from __future__ import annotations

import json
import sys

from d2a_core.artifacts import Store

HEADER = ("| run, env step | intent F1 | pass weak: progress gain m, finished ahead | pass expert: progress ratio, "
          "finished ahead | stay weak: progress gain m, never ahead | stay expert: ratio, never ahead | accuracy per "
          "group: pass weak / expert / stay weak / expert |\n|---|---|---|---|---|---|---|")
GROUPS = ("pass/weak", "pass/expert", "stay/weak", "stay/expert")


def _goal(summary: dict, group: str) -> str:
    name = "finished_ahead" if group.startswith("pass") else "finished_never_ahead"
    return f"{summary[f'{group}/{name}_unassisted']:.2f} → {summary[f'{group}/{name}_assisted']:.2f}"


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def row(label: str, summary: dict) -> str:
    # methods without an intent estimate (dreamer) have no F1 or accuracy: "-"
    accuracy = " / ".join(_num(summary.get(f"{group}/intent_accuracy")) for group in GROUPS)
    return (f"| {label} | {_num(summary.get('intent_f1'))} "
            f"| {summary['pass/weak/progress_gain']:+.0f}, {_goal(summary, 'pass/weak')} "
            f"| {summary['pass/expert/progress_ratio']:.2f}, {_goal(summary, 'pass/expert')} "
            f"| {summary['stay/weak/progress_gain']:+.0f}, {_goal(summary, 'stay/weak')} "
            f"| {summary['stay/expert/progress_ratio']:.2f}, {_goal(summary, 'stay/expert')} | {accuracy} |")


def main(store_path: str, refs: list[str]) -> None:
    store = Store(store_path)
    print(HEADER)
    for ref in refs:
        run = store.get(ref)
        checkpoints = [art for art in map(store.get, run.inputs) if art.kind == "assistant"]
        for art in sorted(checkpoints, key=lambda a: a.labels["env_step"]):
            summary = json.loads(store.path(art.id, "eval.json").read_text())["summary"]
            label = f"{art.labels.get('method', '')} seed {art.seed} {art.labels['env_step'] // 1000}k `{art.id[:12]}`"
            print(row(label, summary))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
