"""The `d2a` command line: global options, subcommand registration and exit codes.

Exit codes: 0 ok, 1 runtime failure, 2 usage or config error, 3 integrity failure.
"""

from __future__ import annotations

import os
import sys
import traceback
from typing import Optional

import typer

from d2a_cli import (artifacts_cmd, config_cmd, drive_cmd, eval_cmd, intent_swap_cmd, make_track_cmd, render_cmd,
                     report_cmd, reproduce_cmd, study_cmd, train_assistant_cmd, train_humans_cmd)
from d2a_cli.common import DeviceOpt, JsonOpt, SeedOpt, StoreOpt, apply_options, current, report_error, wants_json
from d2a_core import mkl_on_amd
from d2a_core.errors import D2AError

app = typer.Typer(
    name="d2a",
    help="Dream2Assist: intent-inferring shared-control assistance for racing.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # help texts contain literal [brackets]
    context_settings={"help_option_names": ["-h", "--help"]},
)
app.command("make-track")(make_track_cmd.make_track)
app.command("train-humans")(train_humans_cmd.train_humans)
app.command("train-assistant")(train_assistant_cmd.train_assistant)
app.command("eval")(eval_cmd.eval_assistants)
app.command("intent-swap")(intent_swap_cmd.intent_swap)
app.command("report")(report_cmd.report)
app.command("reproduce")(reproduce_cmd.reproduce)
app.command("render")(render_cmd.render)
app.command("drive")(drive_cmd.drive)
app.command("study")(study_cmd.study)
app.add_typer(artifacts_cmd.app, name="artifacts")
app.add_typer(config_cmd.app, name="config")


def _version(value: bool) -> None:
    if value:
        from d2a_core.artifacts import code_version

        info = code_version()
        commit = f" ({info['git_commit'][:12]}{'-dirty' if info['dirty'] else ''})" if info["git_commit"] else ""
        typer.echo(f"d2a {info['version']}{commit}")
        raise typer.Exit()


@app.callback()
def cli(
    store: StoreOpt = None,
    json_out: JsonOpt = False,
    seed: SeedOpt = None,
    device: DeviceOpt = None,
    version: Optional[bool] = typer.Option(
        None, "--version", callback=_version, is_eager=True, help="Show the version and exit."
    ),
) -> None:
    """Dream2Assist: intent-inferring shared-control assistance for racing."""
    apply_options(store, json_out, seed, device)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: run the app and map every failure to its exit code."""
    argv = sys.argv[1:] if argv is None else argv
    current.json = wants_json(argv)
    mkl_on_amd.enable()  # before any command imports torch
    try:
        code = app(args=argv, prog_name="d2a", standalone_mode=False)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.TyperException as exc:  # usage errors: bad option, missing argument (exit 2)
        if current.json:
            report_error(exc.format_message(), exc.exit_code, "UsageError")
        elif hasattr(exc, "show"):
            exc.show()
        else:
            report_error(exc.format_message(), exc.exit_code, "UsageError")
        sys.exit(exc.exit_code)
    except (typer.Abort, KeyboardInterrupt):  # Ctrl-C: the store is consistent (writes are atomic)
        report_error("aborted", 130, "Aborted")
        sys.exit(130)
    except D2AError as exc:
        report_error(str(exc), exc.exit_code, type(exc).__name__)
        sys.exit(exc.exit_code)
    except OSError as exc:  # the environment refused something (disk full, read-only, permissions)
        where = f"{exc.filename}: " if exc.filename else ""
        report_error(f"{where}{exc.strerror or exc}", 1, type(exc).__name__)
        sys.exit(1)
    except MemoryError:
        report_error("out of memory (a config value may ask for far too much; see d2a config show)", 1,
                     "MemoryError")
        sys.exit(1)
    except Exception as exc:  # a bug: a runtime error (1); the traceback only when asked for
        if os.environ.get("D2A_DEBUG"):
            traceback.print_exc(file=sys.stderr)
        report_error(f"internal error {type(exc).__name__}: {exc} (please report it; D2A_DEBUG=1 shows the "
                     "traceback)", 1, type(exc).__name__)
        sys.exit(1)
    # standalone_mode=False returns the exit code of a typer.Exit (e.g. after --help) or None
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
