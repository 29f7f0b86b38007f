"""What every subcommand shares: global options, output on stdout/stderr, and error reporting.

The global options (`--store`, `--json`, `--seed`, `--device`) are accepted both before the
subcommand (`d2a --json artifacts ls`) and after it (`d2a artifacts ls --json`); the value given
closest to the subcommand wins.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

DEFAULT_STORE = "artifacts"

# Progress bars, logs and human-readable errors go to stderr so stdout stays parseable with --json.
err_console = Console(stderr=True)
out_console = Console()


@dataclass
class RunContext:
    """The resolved global options of one invocation."""

    json: bool = False
    store_path: Path = field(default_factory=lambda: Path(os.environ.get("D2A_STORE", DEFAULT_STORE)))
    seed: int = 0
    device: str = "cpu"

    def store(self):
        from d2a_core.artifacts import Store

        return Store(self.store_path)

    def emit(self, result: Any, render: Callable[[Any], None] | None = None) -> None:
        """Print a command's result: JSON on stdout with --json, else a human rendering."""
        if self.json:
            text = json.dumps(_finite(result), indent=2, sort_keys=False, default=str, allow_nan=False)
            sys.stdout.write(text + "\n")
            sys.stdout.flush()
        elif render is not None:
            render(result)
        else:
            out_console.print_json(json.dumps(result, default=str))


def _finite(value: Any) -> Any:
    """JSON has no NaN or infinity: a non-finite number (a metric of no episodes) becomes null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


# One instance per process: the CLI runs one command per process, and the error handler in
# `main` needs to know whether to answer in JSON even when parsing failed half-way.
current = RunContext()

StoreOpt = Annotated[
    Optional[Path],
    typer.Option("--store", help="Artifact store directory [env: D2A_STORE; default: ./artifacts].",
                 show_default=False),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout (progress stays on stderr).")]
SeedOpt = Annotated[Optional[int], typer.Option("--seed", help="Random seed of the run [default: 0].", show_default=False)]
DeviceOpt = Annotated[
    Optional[str], typer.Option("--device", help="Torch device for training, e.g. cpu or cuda [default: cpu].",
                                show_default=False)
]


def apply_options(store: Path | None, json_out: bool, seed: int | None, device: str | None) -> RunContext:
    if store is not None:
        current.store_path = store
    if json_out:
        current.json = True
    if seed is not None:
        current.seed = seed
    if device is not None:
        current.device = device
    return current


_COMMON = [
    inspect.Parameter("store", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=StoreOpt),
    inspect.Parameter("json_out", inspect.Parameter.KEYWORD_ONLY, default=False, annotation=JsonOpt),
    inspect.Parameter("seed", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=SeedOpt),
    inspect.Parameter("device", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=DeviceOpt),
]


def with_common_options(func: Callable[..., Any] | None = None, *, seed: bool = True) -> Any:
    """Add the global options to a leaf command; the command receives `run: RunContext`.
    `seed=False` leaves `--seed` to the command itself (e.g. `eval`, whose `--seed` picks
    assistants by their training seed and repeats)."""
    if func is None:
        return functools.partial(with_common_options, seed=seed)
    common = [p for p in _COMMON if seed or p.name != "seed"]
    sig = inspect.signature(func, eval_str=True)  # resolve string annotations in func's module
    own = [p for p in sig.parameters.values() if p.name != "run"]

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        values = {p.name: kwargs.pop(p.name) for p in common}
        run = apply_options(values.get("store"), values.get("json_out", False), values.get("seed"),
                            values.get("device"))
        return func(*args, run=run, **kwargs)

    params = own + common
    wrapper.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params}
    del wrapper.__wrapped__  # typer must see the new signature, not the wrapped one
    return wrapper


# --- config options, for the subcommands whose work depends on a config ---------------------
PresetOpt = Annotated[str, typer.Option("--preset", help="Config preset: smoke, quick or paper.")]
ConfigFileOpt = Annotated[
    Optional[Path], typer.Option("--config", help="YAML file merged over the preset.", show_default=False)
]
SetOpt = Annotated[
    Optional[list[str]],
    typer.Option("--set", help="Override one value, e.g. --set reward.c_pass=5 (repeatable; applied last).",
                 show_default=False),
]


# --- options of the commands that work on a pair's stored assistants (eval, intent-swap) ------
TrackOpt = Annotated[str, typer.Option("--track", help="Track name, alias or artifact id.")]
PairOpt = Annotated[str, typer.Option("--pair", help="Intent pair: pass-stay or left-right.")]
MainMethodOpt = Annotated[str, typer.Option("--method", help="The main method.")]
BaselineOpt = Annotated[Optional[list[str]], typer.Option(
    "--baseline", help="A method compared with the main one (repeatable).", show_default=False)]
AssistantSeedsOpt = Annotated[Optional[list[int]], typer.Option(
    "--seed", help="Training seed of the assistants (repeatable) [default: every stored seed].", show_default=False)]
HumansOpt = Annotated[Optional[list[str]], typer.Option(
    "--humans", help="Population of each intent of the pair, in order (id, prefix or alias) "
                     "[default: humans/<track>/<intent>]; e.g. populations of another seed, which no assistant "
                     "has seen.", show_default=False)]
EnvsOpt = Annotated[int, typer.Option("--envs", min=1, max=64, help="Envs stepped together.")]


def print_stage(p: dict[str, Any]) -> None:
    """Progress of a staged pipeline (evaluation, intent swap): one line per stage on stderr."""
    err_console.print(f"[{p['done'] + 1}/{p['total']}] {p['stage']}", highlight=False)


class TrainingBars:
    """Rich progress bars on stderr, one per training run of a command (an intent, a method).

    A bar appears with its run's first progress report, so an argument error found while loading
    (no such track, an ambiguous prefix) is printed alone; where stderr is not a terminal (logs)
    a plain line is printed every 5 % instead."""

    def __init__(self, cleanup: contextlib.ExitStack, total: int, return_label: str = "return") -> None:
        self._bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                             TextColumn("{task.fields[stats]}"), TimeElapsedColumn(), console=err_console)
        self._cleanup, self.total, self.return_label = cleanup, total, return_label
        self._tasks: dict[str, Any] = {}
        self._next_line: dict[str, float] = {}
        self._started: dict[str, tuple[float, int]] = {}

    def reporter(self, name: str) -> Callable[[dict[str, Any]], None]:
        """The progress callback of run `name` (reports: env_steps, total, updates_per_s, recent_return
        and, optionally, recent_progress_m: the metres the recent episodes reached)."""
        def progress(p: dict[str, Any]) -> None:
            if not self._bar.live.is_started:
                self._bar.start()
                self._cleanup.callback(self._bar.stop)
            if name not in self._tasks:
                # a resumed run starts its bar where it resumed, so the rate (and the ETA) is this process's
                self._tasks[name] = self._bar.add_task(name, total=self.total, stats="", completed=p["env_steps"])
                self._next_line[name] = 0.0
                self._started[name] = (time.monotonic(), p["env_steps"])
            ret = p["recent_return"]
            reached = p.get("recent_progress_m")
            stats = (f"{p['updates_per_s']:.2f} upd/s" + (f"  {self.return_label} {ret:.1f}" if ret is not None else "")
                     + (f"  reached {reached:.0f} m" if reached is not None else "")
                     + f"  ETA {self._eta(name, p['env_steps'], p['total'])}")
            self._bar.update(self._tasks[name], completed=p["env_steps"], stats=stats)
            if not err_console.is_terminal and p["env_steps"] / p["total"] >= self._next_line[name]:
                err_console.print(f"{name}: {p['env_steps']}/{p['total']} env steps, {stats}")
                self._next_line[name] += 0.05
        return progress

    def _eta(self, name: str, done: int, total: int) -> str:
        """Time left at this process's mean rate so far (checkpoint evaluations included)."""
        started, first = self._started[name]
        elapsed, steps = time.monotonic() - started, done - first
        if steps <= 0 or elapsed < 1:
            return "-:--:--"
        left = int(round(elapsed / steps * max(total - done, 0)))
        return f"{left // 3600}:{left // 60 % 60:02d}:{left % 60:02d}"

    def finish(self, name: str, result: dict[str, Any], what: str) -> None:
        """Close run `name`'s bar; a result reused from the store says so, and which code made it."""
        if result["cached"]:
            made = result["cached_from"]
            commit = (made.get("git_commit") or "unknown commit")[:12]
            err_console.print(f"{name}: reusing stored {what} {result['id'][:12]} (same run key), trained "
                              f"{made.get('created')} by d2a {made.get('version')} at {commit}, "
                              f"training code version {made.get('training_code_version')}", soft_wrap=True)
        if name in self._tasks:
            self._bar.update(self._tasks[name], completed=self.total,
                             stats="(stored result)" if result["cached"] else "done")
        for moved in result.get("aliases_moved", []):
            err_console.print(f"{name}: alias {moved['alias']} now names {moved['now'][:12]} (it named "
                              f"{moved['previous'][:12]}, a run with another config, seed or code)", soft_wrap=True)


def report_error(message: str, code: int, kind: str, json_too: bool = True) -> None:
    """Tell the user what went wrong: on stderr, and as JSON on stdout when --json was asked for."""
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    if current.json and json_too:
        sys.stdout.write(json.dumps({"error": {"type": kind, "message": message, "exit_code": code}}) + "\n")


def wants_json(argv: list[str]) -> bool:
    """Whether --json is on the command line, for errors raised before options are parsed."""
    return "--json" in argv


def before_after(before: float | None, after: float | None, digits: int = 2) -> str:
    """`before→after` for a table cell ("-" for a value that is missing)."""
    return "→".join("-" if v is None else f"{v:.{digits}f}" for v in (before, after))
