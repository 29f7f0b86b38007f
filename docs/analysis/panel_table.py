"""The training panel of assistant runs as a markdown table: per checkpoint, the intent estimate's
per-step F1, what assistance changed for the weak humans and the experts of each intent of the
pair (pass-stay or left-right, each with its own criterion; the panel rule: the weak humans gain
progress, the experts keep >= 95 % of theirs), and the
estimate's accuracy per panel group. The panel tables of docs/results.md and docs/experiments/
come from it.

    python docs/analysis/panel_table.py STORE RUN_ID [RUN_ID ...]

RUN_ID: `assistant-run` artifacts (the `run_id` of `d2a train-assistant --json`) or their aliases.
"""

from __future__ import annotations

import json
import sys

from d2a_core.artifacts import Store
from d2a_core.evaluation.criteria import CRITERION_METRIC

CRITERION_NAME = {"finished_ahead": "finished ahead", "finished_never_ahead": "never ahead",
                  "held_left": "held left", "held_right": "held right"}


def _intents(evaluation: dict) -> list[str]:
    """The pair's intents in the panel's order (pass, stay or left, right)."""
    return list(dict.fromkeys(entry["intent"] for entry in evaluation["panel"]))


def header(intents: list[str]) -> str:
    cells = []
    for intent in intents:
        name = CRITERION_NAME[CRITERION_METRIC[intent]]
        cells += [f"{intent} weak: progress gain m, {name}", f"{intent} expert: progress ratio, {name}"]
    groups = " / ".join(f"{intent} weak / expert" for intent in intents)
    return (f"| run, env step | intent F1 | {' | '.join(cells)} | accuracy per group: {groups} |\n"
            f"|{'---|' * (3 + len(cells))}")


def _goal(summary: dict, intent: str, group: str) -> str:
    name = CRITERION_METRIC[intent]
    return f"{summary[f'{intent}/{group}/{name}_unassisted']:.2f} → {summary[f'{intent}/{group}/{name}_assisted']:.2f}"


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def row(label: str, summary: dict, intents: list[str]) -> str:
    # methods without an intent estimate (dreamer) have no F1 or accuracy: "-"
    accuracy = " / ".join(_num(summary.get(f"{intent}/{group}/intent_accuracy"))
                          for intent in intents for group in ("weak", "expert"))
    cells = []
    for intent in intents:
        cells.append(f"{summary[f'{intent}/weak/progress_gain']:+.0f}, {_goal(summary, intent, 'weak')}")
        cells.append(f"{summary[f'{intent}/expert/progress_ratio']:.2f}, {_goal(summary, intent, 'expert')}")
    return f"| {label} | {_num(summary.get('intent_f1'))} | {' | '.join(cells)} | {accuracy} |"


def main(store_path: str, refs: list[str]) -> None:
    store = Store(store_path)
    printed = None
    for ref in refs:
        run = store.get(ref)
        checkpoints = [art for art in map(store.get, run.inputs) if art.kind == "assistant"]
        for art in sorted(checkpoints, key=lambda a: a.labels["env_step"]):
            evaluation = json.loads(store.path(art.id, "eval.json").read_text())
            summary, intents = evaluation["summary"], _intents(evaluation)
            if intents != printed:
                print(header(intents))
                printed = intents
            label = f"{art.labels.get('method', '')} seed {art.seed} {art.labels['env_step'] // 1000}k `{art.id[:12]}`"
            print(row(label, summary, intents))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
