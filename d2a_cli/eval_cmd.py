"""`d2a eval`: the paper's evaluation protocol, paired, on stored assistants and humans."""

from __future__ import annotations

from typing import Annotated, Any

import typer
from rich.table import Table

from d2a_cli.common import (
    AssistantSeedsOpt,
    BaselineOpt,
    EnvsOpt,
    HumansOpt,
    MainMethodOpt,
    PairOpt,
    RunContext,
    TrackOpt,
    out_console,
    print_stage,
    with_common_options,
)
from d2a_core.pipelines.evaluate import CRITERION, METRICS


@with_common_options(seed=False)
def eval_assistants(
    track: TrackOpt,
    pair: PairOpt,
    method: MainMethodOpt = "dream2assist",
    baseline: BaselineOpt = None,
    seeds: AssistantSeedsOpt = None,
    humans: HumansOpt = None,
    episodes: Annotated[int, typer.Option("--episodes", min=1, help="Paired episodes per human.")] = 20,
    eval_seed: Annotated[int, typer.Option("--eval-seed", help="Seed of the evaluation episodes' env seeds.")] = 0,
    envs: EnvsOpt = 8,
    *,
    run: RunContext,
) -> None:
    """Paired evaluation: each human unassisted and with each assistant, on the same episodes."""
    from d2a_core.pipelines.evaluate import evaluate

    result = evaluate(run.store(), track, pair, method=method, baselines=baseline or [], seeds=seeds, humans=humans,
                      episodes=episodes, eval_seed=eval_seed, n_envs=envs, device=run.device, progress=print_stage)

    def render(r: dict[str, Any]) -> None:
        # shaped like the paper's Table 1: change vs the same human unassisted, mean +- std over humans
        for intent in r["evaluations"][0]["intents"] if r["evaluations"] else []:
            for group in ("imperfect", "near_perfect"):
                table = Table("method", "seed", *(f"d {m}" for m in METRICS), f"{_CRITERION_NAMES[intent]}: u -> a",
                              "F1",
                              title=f"{intent}, {group.replace('_', '-')} humans: change with assistance")
                for e in r["evaluations"]:
                    block = e["intents"][intent].get(group)
                    if block is None:
                        continue
                    f1 = e["intents"][intent]["intent_f1"]
                    table.add_row(e["method"], str(e["seed"]),
                                  *(f"{block[m]['mean']:+.2f} ± {block[m]['std']:.2f}" for m in METRICS),
                                  _criterion_change(block),
                                  "-" if f1 is None else f"{f1:.3f}")
                out_console.print(table)

    run.emit(result, render)


# the rate each intent's drivers are judged by (`d2a_core.evaluation.criteria`)
_CRITERION_NAMES = {"pass": "finished ahead", "stay": "finished never ahead", "left": "held left",
                    "right": "held right"}


def _criterion_change(block: dict[str, Any]) -> str:
    before, change = block.get(f"{CRITERION}_unassisted"), block.get(CRITERION)
    if before is None or change is None or before["mean"] is None:
        return "-"  # an evaluation stored before the criterion was recorded
    return f"{before['mean']:.2f} -> {before['mean'] + change['mean']:.2f}"
