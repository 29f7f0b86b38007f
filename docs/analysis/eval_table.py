"""Stored `d2a eval` results as one markdown table: per evaluation, the assistant (method, seed,
checkpoint), per-step intent F1 overall and per intent, and for each intent's imperfect and
near-perfect humans the change in progress, the intent's own criterion unassisted → assisted,
the change in collision rate and the intervention. The protocol tables of docs/results.md
("Straightaway, pass-stay (Table 1)"), training and held-out humans, come from it.

    python docs/analysis/eval_table.py STORE EVAL_ID [EVAL_ID ...]

EVAL_ID: `evaluation` artifacts (the `id`s of `d2a eval --json`) or their aliases.
"""

from __future__ import annotations

import sys

from d2a_core.artifacts import Store
from d2a_core.pipelines.evaluate import CRITERION

GROUPS = ("imperfect", "near_perfect")


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def cell(block: dict) -> str:
    before = block[f"{CRITERION}_unassisted"]["mean"]
    after = before + block[CRITERION]["mean"]
    return (f"{block['progress_m']['mean']:+.0f} m, {before:.2f} → {after:.2f}, "
            f"{block['collision']['mean']:+.2f}, {block['intervention']['mean']:.2f}")


def main(store_path: str, refs: list[str]) -> None:
    store = Store(store_path)
    results = [store.read_json(store.resolve(ref), "eval.json")["result"] for ref in refs]
    intents = list(results[0]["intents"])
    columns = [f"{intent} {group.replace('_', '-')}" for intent in intents for group in GROUPS]
    print("| assistant | held out | intent F1 (" + " / ".join(intents) + ") | "
          + " | ".join(columns) + " |")
    print("|---|---|---|" + "---|" * len(columns))
    for r in results:
        step = store.get(r["assistant"]).labels.get("env_step")
        name = f"{r['method']} seed {r['seed']} {step // 1000}k `{r['assistant'][:12]}`"
        f1 = f"{_num(r['intent_f1'])} ({' / '.join(_num(r['intents'][i]['intent_f1']) for i in intents)})"
        cells = [cell(r["intents"][i][g]) if g in r["intents"][i] else "-" for i in intents for g in GROUPS]
        print(f"| {name} | {'yes' if r['held_out'] else 'no'} | {f1} | " + " | ".join(cells) + " |")
    print("\nEach group: progress change, the intent's criterion unassisted → assisted (pass: finished "
          "ahead; stay: finished never ahead; left/right: the share of steps on that side while racing), "
          "collision-rate change, intervention ||a_A||; means over "
          "the group's humans.")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
