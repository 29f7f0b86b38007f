"""`d2a make-track`: compile a track and record its opponent replays."""

from __future__ import annotations

from typing import Annotated, Any, Optional

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, err_console, out_console, with_common_options
from d2a_core import config as config_mod


@with_common_options
def make_track(
    source: Annotated[str, typer.Argument(
        help="A track name (tracks/NAME.yaml), a spec file (.yaml) or a racing-line CSV "
             "(x_m, y_m, w_tr_right_m, w_tr_left_m[, z_m]).")],
    start: Annotated[Optional[float], typer.Option("--start", help="CSV only: cut the section starting this many "
                                                   "metres along the lap.", show_default=False)] = None,
    length: Annotated[Optional[float], typer.Option("--length", help="CSV only: length of the section to cut (m).",
                                                    show_default=False)] = None,
    name: Annotated[Optional[str], typer.Option("--name", help="Track name (default: from the spec or file name).",
                                                show_default=False)] = None,
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    *,
    run: RunContext,
) -> None:
    """Compile a track into an artifact (alias track/NAME) and drive its opponent replays."""
    from d2a_core.pipelines.make_track import make_track as build

    resolved = config_mod.load(preset, config_file, overrides or [])
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task("compiling track", total=resolved.config.opponents.count)

        def progress(what: str, done: int, total: int) -> None:
            bar.update(task, description=what, completed=done, total=total)

        result = build(run.store(), source, resolved, run.seed, start_m=start, length_m=length, name=name,
                       progress=progress)

    def render(r: dict[str, Any]) -> None:
        out_console.print(f"[bold]{r['alias']}[/] {r['id'][:12]}  {r['length_m']:.0f} m to the finish, "
                          f"{r['elevation_range_m']:.1f} m elevation range, {r['barriers']} barrier(s)")
        table = Table("opponent", "id", "pace", "finish time (s)")
        for o in r["opponents"]:
            table.add_row(str(o["index"]), o["id"][:12], f"{o['pace']:.2f}", f"{o['finish_time_s']:.1f}")
        out_console.print(table)

    run.emit(result, render)
