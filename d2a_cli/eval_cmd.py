"""`d2a eval`: the paper's evaluation protocol, paired, on stored assistants and humans."""

from __future__ import annotations

from typing import Annotated, Any, Optional

import typer
from rich.table import Column, Table

from d2a_cli.common import (
    AssistantSeedsOpt,
    before_after,
    BaselineOpt,
    EnvsOpt,
    HumansOpt,
    PairOpt,
    RunContext,
    TrackOpt,
    out_console,
    print_stage,
    with_common_options,
)
from d2a_core.evaluation.criteria import CRITERION_METRIC


@with_common_options(seed=False)
def eval_assistants(
    track: TrackOpt,
    pair: PairOpt,
    method: Annotated[Optional[str], typer.Option(
        "--method", help="The main method [default: dream2assist].", show_default=False)] = None,
    baseline: BaselineOpt = None,
    seeds: AssistantSeedsOpt = None,
    assistant: Annotated[Optional[list[str]], typer.Option(
        "--assistant", help="Evaluate this assistant artifact (id, prefix or alias; repeatable), e.g. a "
                            "checkpoint along a run, instead of the final assistants of --method/--seed.",
        show_default=False)] = None,
    humans: HumansOpt = None,
    episodes: Annotated[int, typer.Option("--episodes", min=1, max=10_000, help="Paired episodes per human.")] = 20,
    eval_seed: Annotated[int, typer.Option("--eval-seed", min=0, max=2**31 - 1, help="Seed of the evaluation episodes' env seeds.")] = 0,
    envs: EnvsOpt = 8,
    *,
    run: RunContext,
) -> None:
    """Paired evaluation: each human unassisted and with each assistant, on the same episodes."""
    # imported here, not at module level: it pulls in torch, which every other `d2a` command
    # would then pay for at start-up (seconds)
    from d2a_core.evaluation.safety import SAFETY_MARGIN
    from d2a_core.pipelines.evaluate import CRITERION, METRICS, evaluate

    result = evaluate(run.store(), track, pair, method=method, baselines=baseline or [], seeds=seeds, humans=humans,
                      episodes=episodes, eval_seed=eval_seed, n_envs=envs, device=run.device, progress=print_stage,
                      assistants=assistant)

    def render(r: dict[str, Any]) -> None:
        # the paper's Table 1 transposed (one column per assistant, so it fits a terminal): the
        # change against the same human unassisted, mean ± std over humans
        for intent in r["evaluations"][0]["intents"] if r["evaluations"] else []:
            for group in ("imperfect", "near_perfect"):
                shown = [e for e in r["evaluations"] if e["intents"][intent].get(group) is not None]
                if not shown:
                    continue
                table = Table("", *(Column(_title(e), no_wrap=True) for e in shown),
                              title=f"{intent}, {group.replace('_', '-')} humans: change with assistance",
                              caption="Δ: assisted - unassisted, mean ± std over humans")
                blocks = [e["intents"][intent][group] for e in shown]
                for m in METRICS:
                    table.add_row(f"Δ {_SHORT[m]}", *(f"{b[m]['mean']:+.2f} ± {b[m]['std']:.2f}" for b in blocks))
                table.add_row(f"{CRITERION_METRIC[intent].replace('_', ' ')}, unassisted → assisted", *(_criterion_change(b, CRITERION) for b in blocks))
                table.add_row("intent F1", *("-" if e["intents"][intent]["intent_f1"] is None
                                             else f"{e['intents'][intent]['intent_f1']:.3f}" for e in shown))
                out_console.print(table)
        for e in r["evaluations"]:
            for flag in e.get("safety_flags", []):
                out_console.print(
                    f"[bold red]safety:[/] {_title(e)} raises the {_SHORT[flag['metric']]} of the {flag['intent']} "
                    f"{flag['group'].replace('_', '-')} humans by {flag['change']:+.2f} (more than "
                    f"{SAFETY_MARGIN:.2f})", highlight=False)

    run.emit(result, render)


_SHORT = {"progress_m": "progress (m)", "return": "return", "collision": "collision rate", "off_track": "off-track rate",
          "intervention": "intervention", "mean_speed_m_s": "mean speed (m/s)"}

def _title(e: dict[str, Any]) -> str:
    step = e.get("assistant_env_step")
    return f"{e['method']} seed {e['seed']}" + (f" ({step // 1000}k)" if step else "")


def _criterion_change(block: dict[str, Any], criterion: str) -> str:
    before, change = block.get(f"{criterion}_unassisted"), block.get(criterion)
    if before is None or change is None or before["mean"] is None:
        return "-"  # an evaluation stored before the criterion was recorded
    return before_after(before["mean"], before["mean"] + change["mean"])
