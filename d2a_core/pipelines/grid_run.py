"""Running one grid cell: its subprocess, its lock, its record, and what the store's filesystem must do.

A cell runs as `python -m d2a_cli <argv> --store STORE --json [--device D]`, the subcommand's own
code path, in a subprocess whose stderr goes to `STORE/reproduce/logs/<key>.log` (the driver shows
its last line as the cell's progress, from any node). `run_cell` is what both executors call: the
local one in a thread per running cell, the Ray one as a Ray task (so it must stay importable
and picklable).

Skip-if-done: when a cell succeeds, a record `STORE/reproduce/cells/<key>.json` keeps the aliases
it yielded and their artifact ids. The key hashes the cell's argv with its placeholders filled in,
the ids its dependencies yielded (a retrained assistant makes its eval cell a new cell), the
fingerprint of the config it resolves and the training-code version; a cell is done when its
record exists, every artifact it names is still in the store and every alias still points at it.
A record only saves starting a process: every subcommand is idempotent by its own run key, so a
cell rerun without one returns the stored result.

A cell holds `flock` on `STORE/reproduce/locks/<key>.lock` while it runs, so two drivers (or a
driver and its rerun) never run the same cell at once; the second waits, then finds it done.
The subprocess is killed with the process that started it (Linux `PR_SET_PDEATHSIG`), so a
driver killed with SIGKILL leaves no orphan training; its rerun resumes each run from its last
checkpoint.

What the store's filesystem must provide (`probe_filesystem` tests each on the store, and the
Ray executor from every node): the same absolute path on every machine that runs cells; atomic
`rename` within a directory (every store write is a temp file renamed into place); hard links
(`link` installs blobs and manifests); and `flock` that is coherent between processes and, on a
cluster, between machines (the store's writer/gc lock and the cell locks rely on it). Local
disks, NFSv4 (Linux emulates flock with byte-range locks), Lustre mounted with `-o flock`,
CephFS and GPFS provide these; NFS mounted `nolock` or `local_lock=flock` and object-store
mounts (s3fs, gcsfuse) do not.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import json
import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

RECORD_FORMAT = 1
GRID_DIR = "reproduce"
NO_RETRY_CODES = (2, 130)
"""Exit codes not worth a retry: usage and config errors fail the same way every time; 130 is an
interrupt (Ctrl-C reaches the cells too)."""


@dataclass
class CellSpec:
    """Everything a worker needs to run one cell (picklable; no placeholders left)."""

    name: str
    kind: str
    argv: list[str]
    key: str
    store: str
    threads: int = 1
    device: str | None = None
    retries: int = 0
    expects: dict[str, str] = field(default_factory=dict)
    python: str | None = None
    """The interpreter to run d2a with [default: the one running `run_cell`, on its node]."""


def grid_dir(store: str | os.PathLike[str]) -> Path:
    return Path(store) / GRID_DIR


def record_path(store: str | os.PathLike[str], key: str) -> Path:
    return grid_dir(store) / "cells" / f"{key}.json"


def log_path(store: str | os.PathLike[str], key: str) -> Path:
    return grid_dir(store) / "logs" / f"{key}.log"


def cell_key(argv: list[str], config_fingerprint: str | None, expects: dict[str, str],
             inputs: dict[str, str]) -> str:
    """The cell's identity: argv (placeholders filled), resolved config, the aliases it expects,
    what its dependencies yielded (alias -> id) and the training-code version."""
    from d2a_core.artifacts.manifest import content_key
    from d2a_core.training.code_version import TRAINING_CODE_VERSION

    identity = {"format": RECORD_FORMAT, "argv": argv, "config": config_fingerprint, "expects": expects,
                "inputs": inputs, "code": TRAINING_CODE_VERSION}
    return content_key(identity)


def config_fingerprint(preset: str, config_file: str | None, overrides: tuple[str, ...],
                       pair: str | None = None) -> str:
    """The sha256 of the resolved config, for `pair`'s runs when given (so an edited preset or
    config file is a new key); a config that does not resolve gets its error instead, and the cell
    fails with it when it runs."""
    from d2a_core import config as config_mod
    from d2a_core.artifacts.manifest import content_key
    from d2a_core.errors import D2AError

    try:
        resolved = config_mod.load(preset, Path(config_file) if config_file else None, list(overrides), pair=pair)
    except D2AError as exc:
        return f"invalid: {exc}"
    return content_key(resolved.record())


def read_done(store, key: str) -> dict[str, Any] | None:
    """The cell's record if it is done (every artifact it names exists whole, with its lineage,
    and every alias points at it), else None: a cell whose output lost a blob to `verify
    --repair` runs again and rebuilds it. `store` is a `d2a_core.artifacts.Store`."""
    from d2a_core.errors import D2AError

    path = record_path(store.root, key)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if record.get("format") != RECORD_FORMAT or record.get("key") != key:
        return None
    try:
        for alias, art_id in record["ids"].items():
            if store.resolve(alias) != art_id or not store.is_whole(art_id):
                return None
    except (D2AError, OSError, KeyError, AttributeError):
        return None
    return record


def produced(kind: str, result: dict[str, Any]) -> tuple[dict[str, str], str | None]:
    """(alias -> id, the cell's main id) from a subcommand's --json result."""
    ids: dict[str, str] = {}
    main = None
    if kind == "make-track" or kind == "report":
        ids[result["alias"]] = main = result["id"]
    elif kind == "train-humans":
        for p in result["populations"]:
            # the intent's aliases, or a side population's own (`--no-alias`)
            ids.update(p["aliases"])
            main = p["id"]
    elif kind == "train-assistant":
        for a in result["assistants"]:
            name = f"{a['track']}/{a['pair']}/{a['method']}/seed{a['seed']}"
            ids[f"assistants/{name}"] = main = a["id"]
            ids[f"assistant-runs/{name}"] = a["run_id"]
    elif kind == "eval":
        for e in result["evaluations"]:
            ids[f"eval/{e['track']}/{e['pair']}/{e['method']}/seed{e['seed']}"] = e["id"]
    elif kind == "intent-swap":
        for s in result["intent_swaps"]:
            ids[f"intent-swap/{s['track']}/{s['pair']}/{s['method']}/seed{s['seed']}"] = s["id"]
    else:
        raise ValueError(f"unknown cell kind {kind!r}")
    return ids, main


def _write_json_atomic(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1, sort_keys=True)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


@contextlib.contextmanager
def _cell_lock(store: str, key: str):
    path = grid_dir(store) / "locks" / f"{key}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


try:  # resolved here, not in the child: between fork and exec the child must not import or load
    import ctypes

    _PRCTL = ctypes.CDLL(None, use_errno=True).prctl
except (OSError, AttributeError):  # not Linux: a killed driver may leave its cells running
    _PRCTL = None


def _die_with_parent(parent: int) -> None:
    """In the child before exec: get SIGKILL when the thread that started it dies (Linux)."""
    if _PRCTL is not None:
        _PRCTL(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(137)


_LIVE: set[subprocess.Popen] = set()
_LIVE_LOCK = threading.Lock()
_STOPPING = threading.Event()


def terminate_cells() -> None:
    """SIGTERM every cell subprocess this process started that still runs, and start no more
    (the driver is stopping: each run keeps its last checkpoint and resumes on the next run)."""
    _STOPPING.set()
    with _LIVE_LOCK:
        procs = list(_LIVE)
    for proc in procs:
        with contextlib.suppress(OSError):
            proc.terminate()


def cell_env(threads: int) -> dict[str, str]:
    """The cell's environment: torch and BLAS limited to `threads` threads."""
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[var] = str(threads)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _last_line(path: Path, limit: int = 4096) -> str:
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - limit))
            lines = [ln for ln in fh.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1].strip() if lines else ""


def last_log_line(store: str, key: str) -> str:
    return _last_line(log_path(store, key))


def run_cell(spec: CellSpec) -> dict[str, Any]:
    """Run one cell (or find it done): {"status": "done"|"ran"|"failed", "ids", "id", "seconds",
    "attempts", "error", "exit_code"}. Never raises for a failing subcommand."""
    from d2a_core.artifacts import Store

    started = time.monotonic()
    store = Store(spec.store)
    with _cell_lock(spec.store, spec.key):
        record = read_done(store, spec.key)
        if record is not None:  # another driver finished it while this one waited
            return {"status": "done", "ids": record["ids"], "id": record.get("id"), "seconds": 0.0, "attempts": 0}
        problem = _expectations(store, spec.expects)
        if problem:
            return {"status": "failed", "error": problem, "exit_code": 2, "attempts": 0,
                    "seconds": round(time.monotonic() - started, 3)}
        log = log_path(spec.store, spec.key)
        log.parent.mkdir(parents=True, exist_ok=True)
        cmd = [spec.python or sys.executable, "-m", "d2a_cli", *spec.argv, "--store", spec.store, "--json"]
        if spec.device:
            cmd += ["--device", spec.device]
        attempts, outcome = 0, {}
        stopped = {"status": "failed", "exit_code": 130, "error": "the grid was stopped"}
        while True:
            if _STOPPING.is_set():
                outcome = stopped
                break
            attempts += 1
            with open(log, "ab") as err:
                err.write(f"--- {datetime.now(timezone.utc).isoformat(timespec='seconds')} attempt {attempts}: "
                          f"{' '.join(cmd)}\n".encode())
                err.flush()
                # launched and registered under the lock that terminate_cells takes after setting
                # _STOPPING: a stop either finds this cell in _LIVE or is seen here before launch
                with _LIVE_LOCK:
                    if _STOPPING.is_set():
                        outcome = stopped
                        break
                    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL,
                                            env=cell_env(spec.threads),
                                            preexec_fn=functools.partial(_die_with_parent, os.getpid()))
                    _LIVE.add(proc)
                try:
                    out, _ = proc.communicate()
                finally:
                    with _LIVE_LOCK:
                        _LIVE.discard(proc)
            outcome = _outcome(spec, proc.returncode, out, log)
            if outcome["status"] == "ran" or proc.returncode in NO_RETRY_CODES or attempts > spec.retries \
                    or _STOPPING.is_set():
                break
        outcome["attempts"] = attempts
        outcome["seconds"] = round(time.monotonic() - started, 3)
        if outcome["status"] == "ran":
            _write_json_atomic(record_path(spec.store, spec.key), {
                "format": RECORD_FORMAT, "key": spec.key, "name": spec.name, "kind": spec.kind, "argv": spec.argv,
                "ids": outcome["ids"], "id": outcome["id"], "seconds": outcome["seconds"],
                "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"), "result": outcome.pop("result")})
        return outcome


def _expectations(store, expects: dict[str, str]) -> str | None:
    from d2a_core.errors import D2AError

    for alias, want in expects.items():
        try:
            got = store.resolve(alias)
        except D2AError as exc:
            got = f"nothing ({exc})"
        if got != want:
            return (f"alias {alias} points at {got[:12]}, not at the grid's {want[:12]}: another command moved it "
                    f"after the grid's train-humans cell; rerun d2a reproduce (that cell points it back)")
    return None


def _outcome(spec: CellSpec, code: int, out: bytes, log: Path) -> dict[str, Any]:
    text = out.decode("utf-8", "replace")
    try:
        result = json.loads(text) if text.strip() else None
    except ValueError:
        result = None
    if code == 0 and isinstance(result, dict):
        try:
            ids, main = produced(spec.kind, result)
        except (KeyError, TypeError, ValueError) as exc:
            return {"status": "failed", "exit_code": code, "error": f"unexpected --json result ({exc!r})"}
        # every alias at what the cell produced, even where the subcommand answered from the
        # store without re-tagging (an alias moved since would otherwise stay where it was)
        from d2a_core.artifacts import Store

        Store(spec.store).point_aliases(ids)
        return {"status": "ran", "ids": ids, "id": main, "result": result, "exit_code": 0}
    if isinstance(result, dict) and isinstance(result.get("error"), dict):
        message = result["error"].get("message", "")
    elif code < 0:
        message = f"killed by signal {-code}" + ("" if code != -signal.SIGKILL else " (out of memory?)")
    else:
        message = _last_line(log) or f"exit code {code}"
    return {"status": "failed", "exit_code": code, "error": f"{message} (log: {log})"}


# --------------------------------------------------------------------------- filesystem checks
def probe_filesystem(directory: str, held_lock: str | None = None) -> list[str]:
    """What this process finds wrong with `directory` for a store: rename, link, flock. With
    `held_lock`, a file another process holds an exclusive flock on: taking it must fail here
    (flock coherent between processes, and between machines when run on another node)."""
    problems: list[str] = []
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
        token = secrets.token_hex(6)
        a, b, c = d / f"probe-{token}-a", d / f"probe-{token}-b", d / f"probe-{token}-c"
        a.write_bytes(b"d2a")
        os.replace(a, b)
        if a.exists() or b.read_bytes() != b"d2a":
            problems.append("rename within a directory is not atomic (the source is still there)")
        try:
            os.link(b, c)
            c.unlink()
        except OSError as exc:
            problems.append(f"hard links fail ({exc.strerror or exc}); the store installs files with link()")
        b.unlink(missing_ok=True)
    except OSError as exc:
        return [f"cannot write in {d}: {exc.strerror or exc}"]
    lock = d / f"probe-{token}.lock"
    try:
        fd1 = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        fd2 = os.open(lock, os.O_RDWR)
        try:
            fcntl.flock(fd1, fcntl.LOCK_EX | fcntl.LOCK_NB)
            try:
                fcntl.flock(fd2, fcntl.LOCK_EX | fcntl.LOCK_NB)
                problems.append("flock does not exclude: a second exclusive lock on the same file was granted")
            except BlockingIOError:
                pass
        finally:
            os.close(fd2)
            os.close(fd1)
            lock.unlink(missing_ok=True)
    except OSError as exc:
        problems.append(f"flock fails ({exc.strerror or exc})")
    if held_lock:
        try:
            fd = os.open(held_lock, os.O_RDWR)
        except OSError as exc:
            problems.append(f"cannot open {held_lock} ({exc.strerror or exc}): the store is not the same "
                            "directory here")
        else:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.flock(fd, fcntl.LOCK_UN)
                problems.append("flock is not shared between machines: a lock held by the driver was granted "
                                "here too (NFS mounted nolock or local_lock=flock?)")
            except BlockingIOError:
                pass
            except OSError as exc:
                problems.append(f"flock fails ({exc.strerror or exc})")
            finally:
                os.close(fd)
    return problems


@contextlib.contextmanager
def held_probe_lock(store: str):
    """A file under the store held with an exclusive flock, and a token written beside it, for
    workers to check they see the same directory and the same locks."""
    d = grid_dir(store) / "probe"
    d.mkdir(parents=True, exist_ok=True)
    token = secrets.token_hex(8)
    path = d / f"held-{token}.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield str(path)
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
        path.unlink(missing_ok=True)
