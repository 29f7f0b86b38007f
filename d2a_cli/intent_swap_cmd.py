"""`d2a intent-swap`: the human's intent flips mid-episode; how fast does the assistant follow?"""

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


@with_common_options(seed=False)
def intent_swap(
    track: TrackOpt,
    pair: PairOpt,
    method: MainMethodOpt = "dream2assist",
    baseline: BaselineOpt = None,
    seeds: AssistantSeedsOpt = None,
    humans: HumansOpt = None,
    trials: Annotated[int, typer.Option("--trials", min=1, max=10_000, help="Trials per direction.")] = 10,
    window: Annotated[tuple[float, float], typer.Option(
        "--window", help="Earliest and latest swap time (s after the start).")] = (3.0, 8.0),
    eval_seed: Annotated[int, typer.Option("--eval-seed", min=0, max=2**31 - 1, help="Seed of the trials (humans, swap times, env seeds).")] = 0,
    envs: EnvsOpt = 8,
    *,
    run: RunContext,
) -> None:
    """Swap the human for the comparably trained human of the other intent mid-episode; measure recovery."""
    from d2a_core.pipelines.intent_swap import intent_swap as run_swap

    result = run_swap(run.store(), track, pair, method=method, baselines=baseline or [], seeds=seeds, humans=humans,
                      trials=trials, window_s=window, eval_seed=eval_seed, n_envs=envs, device=run.device,
                      progress=print_stage)

    def render(r: dict[str, Any]) -> None:
        table = Table("method", "seed", "direction", "recovery s", "median trial s", "recovered",
                      "d progress m", "d collision", "intervention", title="intent swap")
        for s in r["intent_swaps"]:
            for direction, metrics in s["metrics"].items():
                curve = s["directions"].get(direction)
                rec = "-" if not curve or curve["recovery_s"] is None else f"{curve['recovery_s']:.1f}"
                med = "-" if not curve or curve["median_trial_recovery_s"] is None else \
                    f"{curve['median_trial_recovery_s']:.1f}"
                got = "-" if not curve else f"{curve['recovered_trials']}/{curve['trials']}"
                table.add_row(s["method"], str(s["seed"]), direction, rec, med, got,
                              f"{metrics['progress_m']['delta_mean']:+.1f}", f"{metrics['collision']['delta_mean']:+.2f}",
                              f"{metrics['intervention']['assisted']:.2f}")
        out_console.print(table)

    run.emit(result, render)
