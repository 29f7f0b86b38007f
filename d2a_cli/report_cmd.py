"""`d2a report`: the paper's tables and figures from the store, beside the paper's numbers."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.table import Table

from d2a_cli.common import RunContext, err_console, out_console, with_common_options


@with_common_options(seed=False)
def report(
    tracks: Annotated[Optional[list[str]], typer.Option(
        "--track", help="Only this track (repeatable) [default: every track with results].",
        show_default=False)] = None,
    pairs: Annotated[Optional[list[str]], typer.Option(
        "--pair", help="Only this intent pair, e.g. pass-stay (repeatable) [default: every pair].",
        show_default=False)] = None,
    out: Annotated[Optional[Path], typer.Option(
        "--out", help="Also copy the report's files into this directory.", show_default=False)] = None,
    *,
    run: RunContext,
) -> None:
    """Tables (Markdown, HTML, JSON) and figures from evaluations, intent swaps, runs and populations."""
    from d2a_core.report import build_report

    err_console.print("building the report (tables, figures, t-SNE) ...", highlight=False)
    result = build_report(run.store(), tracks=tracks, pairs=pairs, out=out)
    printed = {"id": result["id"], "alias": result["alias"], "files": result["files"], "tables": result["tables"],
               "skipped_figures": result["skipped_figures"], "inputs": result["inputs"], "out": result["out"]}

    def render(r: dict[str, Any]) -> None:
        table = Table("table", "rows", "from", title=f"report {r['id'][:12]} ({r['alias']})")
        for kind, tables in r["tables"].items():
            if not isinstance(tables, list):
                continue
            for t in tables:
                if "id" in t:
                    table.add_row(t["id"], str(len(t.get("rows", []))), str(len(t.get("sources", []))))
        out_console.print(table)
        figures = [f for f in r["files"] if f.startswith("figures/") and f.endswith(".png")]
        out_console.print(f"{len(figures)} figures: {', '.join(figures)}", highlight=False, soft_wrap=True)
        for kind, why in r["skipped_figures"].items():
            out_console.print(f"not drawn: {kind}: {why}", highlight=False, soft_wrap=True)
        where = r["out"] or f"d2a artifacts export {r['id'][:12]} DIR"
        out_console.print(f"open report.html or report.md in {where}", highlight=False, soft_wrap=True)

    run.emit(printed, render)
