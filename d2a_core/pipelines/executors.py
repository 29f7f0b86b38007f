"""Executors of the grid (`pipelines.grid`): run its cells in dependency order, locally or on Ray.

The driver (`run_grid`) walks the cells in grid order. A cell whose dependencies all succeeded
gets its placeholders filled with their artifact ids and its key computed; if its record says
it is done (`grid_run.read_done`) it is skipped without starting anything, otherwise it goes to
the executor. A failed cell (after its retries) is reported and its dependents are `blocked`;
every cell that does not depend on it still runs. Statuses: `done` (found done), `ran`,
`failed`, `blocked`.

- `LocalExecutor`: up to `jobs` cells at once, each a subprocess (`grid_run.run_cell` in a
  thread) with `OMP_NUM_THREADS=threads`; `jobs x threads` should not exceed the cores.
- `RayExecutor` (`pip install 'd2a[ray]'`): each cell is a Ray task asking for `threads` CPUs
  (and `gpus` GPUs for the cells that run on `--device`); the task runs the same
  `grid_run.run_cell`, so the same subprocess. `address` joins a running cluster (`ray start
  --head` / `ray start --address ...` on the nodes); without it a local Ray instance is started
  with `jobs x threads` CPUs. Every node must see the store at the same absolute path on a
  filesystem with atomic rename, hard links and coherent flock (`grid_run` says why and which
  filesystems do); before any cell runs, one probe task per node checks this and the run stops
  with the problems named if one fails. Failures of a cell's subcommand are retried by
  `run_cell`; a Ray worker or node lost under a task is retried by Ray (`max_retries`).
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from d2a_core.errors import StoreError, UsageError
from d2a_core.pipelines import grid_run
from d2a_core.pipelines.grid import Cell, DepId, DepIds
from d2a_core.pipelines.grid_run import CellSpec


class Executor(Protocol):
    def submit(self, spec: CellSpec) -> None: ...

    def capacity(self) -> int: ...

    def wait(self, timeout: float) -> list[tuple[str, dict[str, Any]]]: ...

    def close(self, abort: bool = False) -> None: ...


class GridProgress(Protocol):
    """What the driver reports (the CLI draws it)."""

    def begin(self, cells: Sequence[Cell]) -> None: ...

    def started(self, cell: Cell, key: str) -> None: ...

    def finished(self, cell: Cell, outcome: dict[str, Any]) -> None: ...

    def tick(self, running: dict[str, str]) -> None: ...


@dataclass
class CellOutcome:
    cell: Cell
    status: str = "pending"
    seconds: float = 0.0
    ids: dict[str, str] = field(default_factory=dict)
    id: str | None = None
    key: str | None = None
    error: str | None = None
    attempts: int = 0
    exit_code: int | None = None
    argv: list[str] | None = None
    """The argv with its placeholders filled, once its dependencies have finished."""

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.cell.name, "kind": self.cell.kind, "artifact": self.cell.artifact,
                               "status": self.status, "seconds": round(self.seconds, 3)}
        if self.id:
            out["id"] = self.id
        if self.ids:
            out["ids"] = dict(self.ids)
        if self.error:
            out["error"] = self.error
        if self.attempts > 1:
            out["attempts"] = self.attempts
        return out


# --------------------------------------------------------------------------- local
class LocalExecutor:
    """Up to `jobs` cells at once on this machine."""

    def __init__(self, jobs: int) -> None:
        self.jobs = max(1, jobs)
        self._pool = ThreadPoolExecutor(max_workers=self.jobs, thread_name_prefix="d2a-cell")
        self._done: queue.Queue[tuple[str, dict[str, Any]]] = queue.Queue()
        self._running = 0
        self._lock = threading.Lock()

    def capacity(self) -> int:
        with self._lock:
            return self.jobs - self._running

    def submit(self, spec: CellSpec) -> None:
        with self._lock:
            self._running += 1

        def work() -> None:
            try:
                outcome = grid_run.run_cell(spec)
            except Exception as exc:  # noqa: BLE001 - a bug or an OS error in one cell must not stop the grid
                outcome = {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "attempts": 1}
            with self._lock:
                self._running -= 1
            self._done.put((spec.name, outcome))

        self._pool.submit(work)

    def wait(self, timeout: float) -> list[tuple[str, dict[str, Any]]]:
        out = []
        try:
            out.append(self._done.get(timeout=timeout))
            while True:
                out.append(self._done.get_nowait())
        except queue.Empty:
            pass
        return out

    def close(self, abort: bool = False) -> None:
        if abort:
            grid_run.terminate_cells()
        self._pool.shutdown(wait=True, cancel_futures=True)


def check_local_store(store: str) -> None:
    problems = grid_run.probe_filesystem(str(grid_run.grid_dir(store) / "probe"))
    if problems:
        raise StoreError(f"the store {store} cannot hold a grid: " + "; ".join(problems))


# --------------------------------------------------------------------------- Ray
def _import_ray():
    try:
        import ray
    except ImportError:
        raise UsageError("--executor ray needs Ray: pip install 'd2a[ray]' (or pip install 'ray>=2.9')") from None
    return ray


class RayExecutor:
    """Cells as Ray tasks; see the module docstring."""

    def __init__(self, store: str, address: str | None, jobs: int, threads: int, gpus: float,
                 retries: int, log: Callable[[str], None] = lambda s: None) -> None:
        ray = _import_ray()
        self.ray = ray
        self.threads = threads
        self.gpus = gpus
        self._started = False
        if not ray.is_initialized():
            if address:
                ray.init(address=address, log_to_driver=False)
            else:
                ray.init(num_cpus=max(1, jobs) * threads, include_dashboard=False, log_to_driver=False)
                self._started = True
        self._remote = ray.remote(grid_run.run_cell)
        self.retries = retries
        self._pending: dict[Any, str] = {}
        self._check_nodes(store, log)

    def _check_nodes(self, store: str, log: Callable[[str], None]) -> None:
        """One probe per live node: the store visible at the same path, rename, link, coherent flock."""
        ray = self.ray
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        probe = ray.remote(grid_run.probe_filesystem)
        nodes = [n for n in ray.nodes() if n.get("Alive")]
        with grid_run.held_probe_lock(store) as held:
            refs = {n.get("NodeManagerAddress", n["NodeID"][:12]): probe.options(
                num_cpus=0, scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False)).remote(
                    str(grid_run.grid_dir(store) / "probe"), held) for n in nodes}
            problems = []
            for where, ref in refs.items():
                try:
                    found = ray.get(ref, timeout=300)
                except Exception as exc:  # noqa: BLE001 - a node that cannot run the probe is a problem too
                    found = [f"the probe did not run ({type(exc).__name__}: {exc})"]
                problems += [f"node {where}: {p}" for p in found]
        if problems:
            raise StoreError(f"the store {store} is not usable from every Ray node (it must be one shared "
                             "filesystem path with atomic rename, hard links and flock): " + "; ".join(problems))
        log(f"store {store} checked on {len(nodes)} Ray node(s)")

    def capacity(self) -> int:
        return 1 << 30  # Ray queues tasks by their resources

    def submit(self, spec: CellSpec) -> None:
        gpus = self.gpus if spec.device and spec.device.startswith("cuda") else 0
        ref = self._remote.options(num_cpus=spec.threads, num_gpus=gpus, max_retries=self.retries,
                                   name=spec.name).remote(spec)
        self._pending[ref] = spec.name

    def wait(self, timeout: float) -> list[tuple[str, dict[str, Any]]]:
        if not self._pending:
            time.sleep(timeout)
            return []
        ready, _ = self.ray.wait(list(self._pending), num_returns=len(self._pending), timeout=timeout)
        out = []
        for ref in ready:
            name = self._pending.pop(ref)
            try:
                outcome = self.ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - the task died (worker or node lost after its retries)
                outcome = {"status": "failed", "error": f"Ray task failed: {type(exc).__name__}: {exc}"}
            out.append((name, outcome))
        return out

    def close(self, abort: bool = False) -> None:
        for ref in list(self._pending):
            self.ray.cancel(ref, force=True)
        self._pending.clear()
        if self._started:
            self.ray.shutdown()


# --------------------------------------------------------------------------- driver
@dataclass
class RunOptions:
    store: str
    threads: int = 1
    device: str | None = None
    retries: int = 1
    poll_s: float = 0.5


def _dep_id(ref: DepId, outcomes: dict[str, CellOutcome]) -> str:
    done = outcomes[ref.cell]
    art_id = done.ids[ref.alias] if ref.alias is not None else done.id
    if art_id is None:
        raise AssertionError(f"grid cell {ref.cell} finished without an artifact id")
    return art_id


def _fill(cell: Cell, outcomes: dict[str, CellOutcome]) -> list[str]:
    def one(a) -> str:
        if isinstance(a, DepId):
            return _dep_id(a, outcomes)
        if isinstance(a, DepIds):
            return ",".join(_dep_id(r, outcomes) for r in a.refs)
        return a
    return [one(a) for a in cell.argv]


def prepare(cell: Cell, outcomes: dict[str, CellOutcome],
            fingerprints: dict[Any, str]) -> tuple[list[str], dict[str, str], str]:
    """(argv, expected aliases, key) of a cell whose dependencies have finished."""
    argv = _fill(cell, outcomes)
    expects = {alias: _dep_id(ref, outcomes) for alias, ref in cell.expects}
    fingerprint = None
    if cell.config is not None:
        if cell.config not in fingerprints:
            fingerprints[cell.config] = grid_run.config_fingerprint(*cell.config)
        fingerprint = fingerprints[cell.config]
    # what the dependencies yielded: a retrained assistant makes its eval cell a new one, even though
    # the eval's argv (aliases and seeds) is the same
    inputs = {alias: art_id for d in cell.deps for alias, art_id in sorted(outcomes[d].ids.items())}
    return argv, expects, grid_run.cell_key(argv, fingerprint, expects, inputs)


def plan(cells: Sequence[Cell], store) -> list[CellOutcome]:
    """What a run would do, without running anything: each cell `done` (its record holds) or
    `pending` (to run, or waiting for a cell that is)."""
    outcomes = {c.name: CellOutcome(c) for c in cells}
    fingerprints: dict[Any, str] = {}
    for cell in cells:
        out = outcomes[cell.name]
        if all(outcomes[d].status == "done" for d in cell.deps):
            out.argv, _, out.key = prepare(cell, outcomes, fingerprints)
            record = grid_run.read_done(store, out.key)
            if record is not None:
                out.status, out.ids, out.id = "done", record["ids"], record.get("id")
    return list(outcomes.values())


def run_grid(cells: Sequence[Cell], executor: Executor, opts: RunOptions,
             progress: GridProgress | None = None) -> list[CellOutcome]:
    """Run the grid on `executor`; returns every cell's outcome, in grid order."""
    from d2a_core.artifacts import Store

    store = Store(opts.store)
    grid_run._STOPPING.clear()
    outcomes = {c.name: CellOutcome(c) for c in cells}
    fingerprints: dict[Any, str] = {}
    running: dict[str, tuple[float, str]] = {}  # name -> (start, key)
    if progress:
        progress.begin(cells)

    def finish(cell: Cell, outcome: dict[str, Any]) -> None:
        out = outcomes[cell.name]
        out.status = outcome["status"]
        out.ids = outcome.get("ids") or {}
        out.id = outcome.get("id")
        out.error = outcome.get("error")
        out.attempts = outcome.get("attempts", 0)
        out.exit_code = outcome.get("exit_code")
        if cell.name in running:
            out.seconds = time.monotonic() - running.pop(cell.name)[0]
        if progress:
            progress.finished(cell, out.as_dict())

    try:
        while True:
            for cell in cells:
                out = outcomes[cell.name]
                if out.status != "pending":
                    continue
                states = [outcomes[d].status for d in cell.deps]
                if any(s in ("failed", "blocked") for s in states):
                    bad = [d for d in cell.deps if outcomes[d].status in ("failed", "blocked")]
                    finish(cell, {"status": "blocked", "error": f"blocked by {', '.join(bad)}"})
                    continue
                if not all(s in ("done", "ran") for s in states):
                    continue
                argv, expects, key = prepare(cell, outcomes, fingerprints)
                out.argv, out.key = argv, key
                record = grid_run.read_done(store, key)
                if record is not None:
                    finish(cell, {"status": "done", "ids": record["ids"], "id": record.get("id")})
                    continue
                if executor.capacity() <= 0:
                    continue
                out.status = "running"
                running[cell.name] = (time.monotonic(), key)
                if progress:
                    progress.started(cell, key)
                executor.submit(CellSpec(name=cell.name, kind=cell.kind, argv=argv, key=key, store=opts.store,
                                         threads=opts.threads, device=opts.device if cell.uses_device else None,
                                         retries=opts.retries, expects=expects))
            if not running and all(o.status != "pending" for o in outcomes.values()):
                break
            if not running:  # nothing runs and nothing can start: cannot happen for a valid grid
                stuck = [n for n, o in outcomes.items() if o.status == "pending"]
                raise AssertionError(f"grid stuck with cells {stuck} pending")
            for name, outcome in executor.wait(opts.poll_s):
                finish(outcomes[name].cell, outcome)
            if progress:
                progress.tick({n: grid_run.last_log_line(opts.store, key) for n, (_, key) in running.items()})
    except BaseException:
        executor.close(abort=True)
        raise
    executor.close()
    return list(outcomes.values())


def make_executor(kind: str, store: str, jobs: int, threads: int, retries: int, address: str | None = None,
                  gpus: float = 1.0, log: Callable[[str], None] = lambda s: None) -> Executor:
    """The executor asked for, after checking the store's filesystem from where cells will run."""
    if kind == "local":
        if address:
            raise UsageError("--ray-address needs --executor ray")
        check_local_store(store)
        return LocalExecutor(jobs)
    if kind == "ray":
        check_local_store(store)
        return RayExecutor(store, address, jobs, threads, gpus, retries, log)
    raise UsageError(f"unknown executor {kind!r}; choose local or ray")


def absolute_store(path: str | os.PathLike[str]) -> str:
    """Cells run in other processes (and on other machines): they get the store's absolute path."""
    p = Path(path).expanduser().absolute()
    if p.exists() and not p.is_dir():
        raise StoreError(f"store {p} is not a directory")
    return str(p)
