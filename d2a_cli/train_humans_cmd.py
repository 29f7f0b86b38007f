"""`d2a train-humans`: train a population of synthetic drivers per intent."""

from __future__ import annotations

import contextlib
from typing import Annotated, Any

import typer
from rich.table import Table

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, TrainingBars, out_console, with_common_options
from d2a_core import config as config_mod
from d2a_core.objectives.rewards import INTENTS


@with_common_options
def train_humans(
    intent: Annotated[list[str], typer.Option("--intent", help=f"Intent to train, repeatable: {', '.join(INTENTS)}.")],
    track: Annotated[str, typer.Option("--track", help="Track name, alias or artifact id (built by make-track).")],
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    alias: Annotated[bool, typer.Option(
        "--alias/--no-alias", help="Point humans/<track>/<intent> (and .../expert) at this population; --no-alias "
                                   "for a side population (another seed, a sweep), kept as "
                                   "humans/<track>/<intent>/side/<id>.")] = True,
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
    # The lease keeps what this run creates or loads (track, replays, checkpoints not yet aliased)
    # safe from a concurrent `d2a artifacts gc` for as long as this process lives.
    with store.lease(), contextlib.ExitStack() as cleanup:
        bars = TrainingBars(cleanup, resolved.config.humans.env_steps)
        for name in intent:
            result = train_population(store, track, name, resolved, run.seed, device=run.device,
                                      progress=bars.reporter(name), move_aliases=alias)
            bars.finish(name, result, "population")
            populations.append(result)

    def render(r: dict[str, Any]) -> None:
        for pop in r["populations"]:
            # short headers so that the table fits 80 columns; --json has every metric by name
            table = Table("id", "step", "return", "prog m", "fin", "fin ahead", "coll", "off", "held", "m/s", "ok",
                          title=f"humans/{pop['track']}/{pop['intent']}  expert {pop['expert'][:12]}"
                                + ("" if pop["expert_meets_intent"] else " (no checkpoint meets the intent)"))
            for c in pop["checkpoints"]:
                m = c["metrics"]
                table.add_row(c["id"][:8], f"{c['env_step']}" + ("*" if c.get("filled") else ""), f"{m['return']:.0f}",
                              f"{m['progress_m']:.0f}", f"{m['finished']:.2f}", f"{m['finished_ahead']:.2f}",
                              f"{m['collision']:.2f}", f"{m['off_track']:.2f}", f"{c['criterion']:.2f}",
                              f"{m['mean_speed_m_s']:.1f}",
                              ("E " if c["id"] == pop["expert"] else "") + ("yes" if c["meets_intent"] else "no"))
            table.caption = ("per checkpoint, over its evaluation episodes: fin = finished, fin ahead = finished "
                             "ahead of the opponent, coll = collided, off = left the track (shares of episodes); "
                             "held = the intent's criterion (pass: finished ahead; stay: finished never ahead; "
                             "left/right: share of steps on that side); ok = meets the intent; E = the expert"
                             + ("; *: a snapshot added to fill the imperfect span (humans.snapshot_every)"
                                if any(c.get("filled") for c in pop["checkpoints"]) else ""))
            out_console.print(table)

    run.emit({"populations": populations}, render)
