"""`d2a drive`: a person at the wheel, alone or with a stored assistant; the drive is stored."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, out_console, with_common_options


@with_common_options
def drive(
    intent: Annotated[str, typer.Option("--intent", help="What you mean to do, stated before the drive: "
                                                         "pass or stay (left, right on their pairs).")],
    track: Annotated[Optional[str], typer.Option(
        "--track", help="Track name, alias or id (default with --assistant: the track it was trained on).")] = None,
    assistant: Annotated[Optional[str], typer.Option(
        "--assistant", help="Assistant to share the car with (id, prefix or alias); without it you drive alone.")] = None,
    participant: Annotated[Optional[str], typer.Option("--participant", help="Who drives (a label for a study).")] = None,
    trial: Annotated[Optional[str], typer.Option("--trial", help="Which trial this is (a label for a study).")] = None,
    script: Annotated[Optional[Path], typer.Option(
        "--script", help="YAML list of timed key presses ({t, down|up}) instead of a person: a scripted, "
                         "repeatable drive through the same window.")] = None,
    seconds: Annotated[Optional[float], typer.Option(
        "--seconds", min=0.1, help="End the drive after this many race seconds (default: the env's time limit).")] = None,
    realtime: Annotated[Optional[bool], typer.Option(
        "--realtime/--fast", help="Pace the race at the env's rate (default), or run as fast as it computes "
                                  "(the default with --script).", show_default=False)] = None,
    screenshot: Annotated[Optional[Path], typer.Option("--screenshot", help="Save the last frame as a PNG.")] = None,
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    *,
    run: RunContext,
) -> None:
    """Drive a race car in a window at 10 Hz: arrows or WASD (steer, throttle, brake), or a gamepad's
    left stick; Escape stops without storing. With --assistant its action is added to yours as in
    training, and the window shows which intent it reads and how hard it intervenes. The drive is
    stored as a `drive` artifact (MCAP episode log and metrics); --seed picks the start and opponent."""
    from d2a_core import config as config_mod
    from d2a_core.drive.script import load_script
    from d2a_core.drive.one_drive import DriveSpec
    from d2a_core.drive.one_drive import drive as run_drive

    resolved = config_mod.load(preset, config_file, overrides or [])
    events = load_script(script) if script is not None else None
    spec = DriveSpec(track=track, assistant=assistant, intent=intent, seed=run.seed, participant=participant,
                     trial=trial, max_seconds=seconds)
    pace = realtime if realtime is not None else script is None
    result = run_drive(run.store(), spec, resolved.config, script=events, realtime=pace, screenshot=screenshot,
                       device=run.device)

    def show(r: dict[str, Any]) -> None:
        m = r["metrics"]
        aid = f" with {r['method']} {r['assistant'][:12]}" if r["assistant"] else " alone"
        out_console.print(
            f"drive {r['id'][:12]}: {r['intent']}{aid} on {r['track']}: {m['progress_m']:.0f} m, "
            f"{'finished' if m['finished'] else 'not finished'}, {'collided, ' if m['collision'] else ''}"
            f"intent {'met' if r['met_intent'] else 'not met'}"
            + (f", read as {r['intent']} on {100 * r['read_as_stated']:.0f} % of steps" if r["read_as_stated"] is not None else ""),
            highlight=False)

    run.emit(result, show)
