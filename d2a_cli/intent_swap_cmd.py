"""`d2a intent-swap`: the human's intent flips mid-episode; how fast does the assistant follow?"""

from __future__ import annotations

from typing import Annotated, Any, Optional

import typer
from rich.table import Table

from d2a_cli.common import RunContext, err_console, out_console, with_common_options


@with_common_options(seed=False)
def intent_swap(
    track: Annotated[str, typer.Option("--track", help="Track name, alias or artifact id.")],
    pair: Annotated[str, typer.Option("--pair", help="Intent pair: pass-stay or left-right.")],
    method: Annotated[str, typer.Option("--method", help="The main method.")] = "dream2assist",
    baseline: Annotated[Optional[list[str]], typer.Option(
        "--baseline", help="A method compared with the main one (repeatable).", show_default=False)] = None,
    seeds: Annotated[Optional[list[int]], typer.Option(
        "--seed", help="Training seed of the assistants (repeatable) [default: every stored seed].",
        show_default=False)] = None,
    humans: Annotated[Optional[list[str]], typer.Option(
        "--humans", help="Population of each intent of the pair, in order [default: humans/<track>/<intent>].",
        show_default=False)] = None,
    trials: Annotated[int, typer.Option("--trials", min=1, help="Trials per direction.")] = 10,
    window: Annotated[tuple[float, float], typer.Option(
        "--window", help="Earliest and latest swap time (s after the start).")] = (3.0, 8.0),
    eval_seed: Annotated[int, typer.Option("--eval-seed", help="Seed of the trials (humans, swap times, env seeds).")] = 0,
    envs: Annotated[int, typer.Option("--envs", min=1, max=64, help="Envs stepped together.")] = 8,
    *,
    run: RunContext,
) -> None:
    """Swap the human for the comparably trained human of the other intent mid-episode; measure recovery."""
    from d2a_core.pipelines.intent_swap import intent_swap as run_swap

    def progress(p: dict[str, Any]) -> None:
        err_console.print(f"[{p['done'] + 1}/{p['total']}] {p['stage']}", highlight=False)

    result = run_swap(run.store(), track, pair, method=method, baselines=baseline or [], seeds=seeds, humans=humans,
                      trials=trials, window_s=window, eval_seed=eval_seed, n_envs=envs, device=run.device,
                      progress=progress)

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
