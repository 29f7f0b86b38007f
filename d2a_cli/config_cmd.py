"""`d2a config`: show the resolved configuration a run would use."""

from __future__ import annotations

from typing import Annotated, Optional

import typer
import yaml

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, out_console, with_common_options
from d2a_core import config as config_mod

app = typer.Typer(help="Inspect configurations.", no_args_is_help=True)


@app.command("show")
@with_common_options
def show(
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    sources: Annotated[bool, typer.Option("--sources", help="Also show where each non-default value came from.")] = False,
    pair: Annotated[Optional[str], typer.Option(
        "--pair", help="The config of an assistant for this intent pair (e.g. left-right): with the "
                       "preset's and file's `pairs.<pair>` values.")] = None,
    *,
    run: RunContext,
) -> None:
    """Resolve preset < --config file < --set overrides, validate, and print the result."""
    resolved = config_mod.load(preset, config_file, overrides or [], pair=pair)
    result = {"preset": preset, "config_file": resolved.config_file, "overrides": resolved.overrides,
              "pair": pair, "config": resolved.as_dict(), "sources": resolved.sources}

    def render(result: dict) -> None:
        out_console.print(yaml.safe_dump(result["config"], sort_keys=False).rstrip(), highlight=False)
        if sources:
            out_console.print("\n# sources of non-default values")
            for key, src in sorted(result["sources"].items()):
                out_console.print(f"# {key}: {src}", highlight=False)

    run.emit(result, render)
