"""`d2a reproduce`: the experiment grid (tracks x pairs x methods x seeds) as one resumable command."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.markup import escape
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from d2a_cli.common import ConfigFileOpt, PresetOpt, RunContext, SetOpt, err_console, out_console, with_common_options


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


class _Bar:
    """The grid's progress on stderr: a bar of cells and, per running cell, the last line of its log."""

    def __init__(self) -> None:
        self.live = err_console.is_terminal
        self.progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                                 TextColumn("{task.fields[count]}"), TextColumn("{task.fields[note]}"),
                                 TimeElapsedColumn(), console=err_console, disable=not self.live)
        self.total = None
        self.n = 0
        self.finished_cells = 0
        self.tasks: dict[str, Any] = {}

    def begin(self, cells) -> None:
        self.n = len(cells)
        self.total = self.progress.add_task("cells", total=self.n, note="", count=f"0/{self.n}")
        self.progress.start()

    def started(self, cell, key: str) -> None:
        if self.live:
            self.tasks[cell.name] = self.progress.add_task(f"  {cell.name}", total=None, note="", count="")
        else:
            err_console.print(f"start   {cell.name}", highlight=False, soft_wrap=True)

    def finished(self, cell, outcome: dict[str, Any]) -> None:
        task = self.tasks.pop(cell.name, None)
        if task is not None:
            self.progress.remove_task(task)
        self.finished_cells += 1
        self.progress.update(self.total, advance=1, count=f"{self.finished_cells}/{self.n}")
        status = outcome["status"]
        colour = {"ran": "green", "done": "dim", "failed": "bold red", "blocked": "yellow"}.get(status, "")
        line = f"[{colour}]{status:<7}[/] {escape(cell.name)}"
        if status == "ran":
            line += f"  {outcome['seconds']:.1f} s"
        if outcome.get("error") and status == "failed":
            line += f"  {escape(outcome['error'])}"
        self.progress.console.print(line, highlight=False, soft_wrap=True)

    def tick(self, running: dict[str, str]) -> None:
        for name, last in running.items():
            task = self.tasks.get(name)
            if task is not None:
                self.progress.update(task, note=escape(last[-70:]))

    def stop(self) -> None:
        self.progress.stop()


@with_common_options(seed=False)
def reproduce(
    tracks: Annotated[Optional[list[str]], typer.Option(
        "--track", help="Track of the grid (repeatable) [default: straightaway].", show_default=False)] = None,
    pairs: Annotated[Optional[list[str]], typer.Option(
        "--pair", help="Intent pair of the grid (repeatable) [default: pass-stay].", show_default=False)] = None,
    methods: Annotated[Optional[list[str]], typer.Option(
        "--method", help="Assistant method (repeatable) [default: every implemented method].",
        show_default=False)] = None,
    seeds: Annotated[int, typer.Option("--seeds", min=1, max=100, help="Assistant training seeds 0 .. N-1 per method.")] = 3,
    humans_seeds: Annotated[Optional[list[int]], typer.Option(
        "--humans-seed", help="Seed of the population per intent that every assistant seed trains with; "
                              "repeat it to train on several populations per intent (the first is the "
                              "reference: its aliases, expert and panel; evaluation uses it) [default: 0].",
        show_default=False)] = None,
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    episodes: Annotated[Optional[int], typer.Option(
        "--episodes", min=1, max=10_000, help="eval: paired episodes per human [default: 1 smoke, 20 otherwise].",
        show_default=False)] = None,
    trials: Annotated[Optional[int], typer.Option(
        "--trials", min=1, max=10_000, help="intent-swap: trials per direction [default: 1 smoke, 10 otherwise].",
        show_default=False)] = None,
    executor: Annotated[str, typer.Option("--executor", help="Where cells run: local or ray.")] = "local",
    ray_address: Annotated[Optional[str], typer.Option(
        "--ray-address", help="Join this Ray cluster (e.g. auto or HOST:6379) [default: start a local one].",
        show_default=False)] = None,
    jobs: Annotated[Optional[int], typer.Option(
        "--jobs", min=1, help="Cells run at once (local; a local Ray gets jobs x threads CPUs) "
                              "[default: cores / threads].", show_default=False)] = None,
    threads: Annotated[int, typer.Option(
        "--threads", min=1, help="Torch threads of each cell (its OMP_NUM_THREADS; its Ray CPUs).")] = 1,
    gpus: Annotated[float, typer.Option(
        "--gpus-per-cell", min=0,
        help="Ray: GPUs a training, eval or intent-swap cell asks for with --device cuda.")] = 1.0,
    retries: Annotated[int, typer.Option(
        "--retries", min=0, help="Reruns of a failed cell before it is reported (not for usage errors).")] = 1,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="List the cells and which are done; run nothing.")] = False,
    *,
    run: RunContext,
) -> None:
    """Run the experiment grid: make-track, train-humans, train-assistant per method and seed, eval,
    intent-swap, report; each cell is that subcommand in a subprocess, skipped when already done."""
    from d2a_core.artifacts import Store
    from d2a_core.pipelines.executors import RunOptions, absolute_store, make_executor, plan, run_grid
    from d2a_core.pipelines.grid import GridOptions, expand

    store_path = absolute_store(run.store_path)
    config_path = str(Path(config_file).absolute()) if config_file else None
    cells = expand(GridOptions(preset=preset, tracks=tracks or ["straightaway"], pairs=pairs or ["pass-stay"],
                               methods=methods, seeds=seeds, humans_seeds=humans_seeds or [0], overrides=overrides or [],
                               config_file=config_path, episodes=episodes, trials=trials))
    cores = _cores()
    jobs = jobs or max(1, cores // threads)
    if executor == "local" and jobs * threads > cores:
        err_console.print(f"warning: {jobs} cells x {threads} thread(s) on {cores} cores oversubscribes them",
                          highlight=False)

    if dry_run:
        outcomes = plan(cells, Store(store_path))
        listed = []
        for o in outcomes:
            listed.append({**o.as_dict(), "argv": o.argv or o.cell.argv_text(), "deps": list(o.cell.deps)})
            listed[-1].pop("seconds")
        report = next((o.id for o in outcomes if o.cell.kind == "report" and o.status == "done"), None)
        result: dict[str, Any] = {"report": report, "dry_run": True, "store": store_path, "cells": listed}
        run.emit(result, _render)
        return

    started = time.monotonic()
    ex = make_executor(executor, store_path, jobs, threads, retries, ray_address, gpus,
                       log=lambda s: err_console.print(s, highlight=False))
    bar = _Bar()
    try:
        outcomes = run_grid(cells, ex, RunOptions(store=store_path, threads=threads, device=run.device,
                                                  retries=retries), bar)
    finally:
        bar.stop()
    report = next((o.id for o in outcomes if o.cell.kind == "report" and o.status in ("done", "ran")), None)
    result = {"report": report, "store": store_path, "executor": executor, "jobs": jobs, "threads": threads,
              "seconds": round(time.monotonic() - started, 3), "cells": [o.as_dict() for o in outcomes]}
    run.emit(result, _render)
    bad = [o for o in outcomes if o.status in ("failed", "blocked")]
    if bad:
        raise typer.Exit(1)


def _render(r: dict[str, Any]) -> None:
    table = Table("cell", "status", "s", "artifact", title="d2a reproduce" + (" (dry run)" if r.get("dry_run") else ""))
    for c in r["cells"]:
        table.add_row(c["name"], c["status"], "" if "seconds" not in c else f"{c['seconds']:.1f}",
                      f"{c['artifact']} {c['id'][:12]}" if c.get("id") else c["artifact"])
    out_console.print(table)
    for c in r["cells"]:
        if c["status"] == "failed":
            out_console.print(f"failed: {c['name']}: {c.get('error', '')}", highlight=False, soft_wrap=True)
    if r.get("dry_run"):
        for c in r["cells"]:
            if c["status"] != "done":
                out_console.print(f"d2a {' '.join(c['argv'])}", highlight=False, soft_wrap=True)
    if r["report"]:
        out_console.print(f"report {r['report'][:12]} (report/latest): d2a artifacts export {r['report'][:12]} DIR",
                          highlight=False)
