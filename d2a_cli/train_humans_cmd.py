"""`d2a train-humans`: train a population of synthetic drivers per intent."""

from __future__ import annotations

import contextlib
from typing import Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, err_console, out_console, with_common_options
from d2a_core import config as config_mod
from d2a_core.objectives.rewards import INTENTS


@with_common_options
def train_humans(
    intent: Annotated[list[str], typer.Option("--intent", help=f"Intent to train, repeatable: {', '.join(INTENTS)}.")],
    track: Annotated[str, typer.Option("--track", help="Track name, alias or artifact id (built by make-track).")],
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    *,
    run: RunContext,
) -> None:
    """Train DreamerV3 drivers on r_task + r_intent; store checkpoints (imperfect humans) and the expert."""
    from d2a_core.training.humans import train_population

    unknown = [i for i in intent if i not in INTENTS]
    if unknown:
        raise typer.BadParameter(f"unknown intent(s) {', '.join(unknown)}; choose from {', '.join(INTENTS)}",
                                 param_hint="--intent")
    resolved = config_mod.load(preset, config_file, overrides or [])
    store = run.store()
    populations = []
    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("{task.fields[stats]}"), TimeElapsedColumn(), console=err_console)
    # The lease keeps what this run creates or loads (track, replays, checkpoints not yet aliased)
    # safe from a concurrent `d2a artifacts gc` for as long as this process lives.
    with store.lease(), contextlib.ExitStack() as cleanup:
        for name in intent:
            # the bar appears with the first progress report, so that an argument error found while
            # loading the track (no such track, an ambiguous prefix) is printed alone
            state: dict[str, Any] = {"task": None, "next": 0.0}

            def progress(p: dict[str, Any], name=name, state=state) -> None:
                if not bar.live.is_started:
                    bar.start()
                    cleanup.callback(bar.stop)
                if state["task"] is None:
                    state["task"] = bar.add_task(f"{name}", total=resolved.config.humans.env_steps, stats="")
                ret = p["recent_return"]
                stats = f"{p['updates_per_s']:.2f} upd/s" + (f"  return {ret:.1f}" if ret is not None else "")
                bar.update(state["task"], completed=p["env_steps"], stats=stats)
                done = p["env_steps"] / p["total"]
                if not err_console.is_terminal and done >= state["next"]:  # logs, not a live bar
                    err_console.print(f"{p['intent']}: {p['env_steps']}/{p['total']} env steps, {stats}")
                    state["next"] += 0.05

            result = train_population(store, track, name, resolved, run.seed, device=run.device, progress=progress)
            if result["cached"]:
                made = result["cached_from"]
                commit = (made.get("git_commit") or "unknown commit")[:12]
                err_console.print(f"{name}: reusing stored population {result['id'][:12]} (same run key), trained "
                                  f"{made.get('created')} by d2a {made.get('version')} at {commit}, "
                                  f"training code version {made.get('training_code_version')}", soft_wrap=True)
            if state["task"] is not None:
                bar.update(state["task"], completed=resolved.config.humans.env_steps,
                           stats="(stored result)" if result["cached"] else "done")
            populations.append(result)

    def render(r: dict[str, Any]) -> None:
        for pop in r["populations"]:
            # short headers so that the table fits 80 columns; --json has every metric by name
            table = Table("id", "step", "return", "prog m", "fin", "fin ahead", "coll", "off", "held", "m/s", "ok",
                          title=f"humans/{pop['track']}/{pop['intent']}  expert {pop['expert'][:12]}"
                                + ("" if pop["expert_meets_intent"] else " (no checkpoint meets the intent)"))
            for c in pop["checkpoints"]:
                m = c["metrics"]
                table.add_row(c["id"][:8], str(c["env_step"]), f"{m['return']:.0f}",
                              f"{m['progress_m']:.0f}", f"{m['finished']:.2f}", f"{m['finished_ahead']:.2f}",
                              f"{m['collision']:.2f}", f"{m['off_track']:.2f}", f"{c['criterion']:.2f}",
                              f"{m['mean_speed_m_s']:.1f}",
                              ("E " if c["id"] == pop["expert"] else "") + ("yes" if c["meets_intent"] else "no"))
            out_console.print(table)

    run.emit({"populations": populations}, render)
