"""`d2a study`: one participant drives a protocol's trials, with and without the assistant."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, out_console, with_common_options


@with_common_options(seed=False)
def study(
    protocol: Annotated[Path, typer.Option("--protocol", help="Study protocol (YAML): the trials, the assistant, "
                                                              "the track (docs/drive.md).")],
    participant: Annotated[str, typer.Option("--participant", help="Who drives (the label of every drive).")],
    realtime: Annotated[Optional[bool], typer.Option(
        "--realtime/--fast", help="Pace each trial at the env's rate (default; scripted trials always run fast).",
        show_default=False)] = None,
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    *,
    run: RunContext,
) -> None:
    """Run a small study: each trial asks (or tells) the intent, is driven in the window, and asks
    whether the participant did what they meant. Every trial is stored as a `drive`, the whole run
    as a `study` with its table (alone against assisted, and paired by start); `d2a report`
    includes it."""
    from d2a_core import config as config_mod
    from d2a_core.drive.study import run_study

    resolved = config_mod.load(preset, config_file, overrides or [])
    result = run_study(run.store(), protocol, participant, resolved.config,
                       realtime=realtime if realtime is not None else True, device=run.device)

    def show(r: dict[str, Any]) -> None:
        out_console.print(f"study {r['id'][:12]}: {participant}, {len(r['trials'])} trials", highlight=False)
        for g in r["table"]["groups"]:
            out_console.print(f"  {g['intent']:>5} {'assisted' if g['assisted'] else 'alone':>8}: {g['trials']} trials, "
                              f"met {g['met_intent']:.2f}, said so {g['self_report']:.2f}, {g['progress_m']:.0f} m, "
                              f"collisions {g['collision']:.2f}", highlight=False)

    run.emit(result, show)
