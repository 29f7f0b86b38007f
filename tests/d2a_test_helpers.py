"""Run the real `d2a` CLI in a child process and parse its --json output (shared by the tests)."""

from __future__ import annotations

import atexit
import fcntl
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

REPO = Path(__file__).resolve().parents[1]

# Environment variables read when the interpreter or torch starts: a call that sets one gets a
# process of its own, since a forked child would keep the zygote's values.
_STARTUP_ENV = ("PYTHON", "OMP_", "MKL_", "OPENBLAS_", "LD_", "MALLOC_", "KMP_", "D2A_MKL_AMD")


@dataclass
class CliResult:
    code: int
    stdout: str
    stderr: str

    @property
    def json(self) -> Any:
        return json.loads(self.stdout)


class _Zygote:
    """The parent's end of tests/cli_zygote.py: one per test process, started on first use."""

    def __init__(self) -> None:
        self.log = tempfile.NamedTemporaryFile(prefix="d2a-zygote-", suffix=".log", delete=False)
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("cli_zygote.py"))],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log,
                                     bufsize=0, cwd=REPO)
        self.buffer = b""
        self.dir = Path(tempfile.mkdtemp(prefix="d2a-cli-"))
        atexit.register(self.close)

    def _reply(self, deadline: float | None) -> dict:
        """The zygote's next answer; {} if `deadline` (monotonic) passes first."""
        fd = self.proc.stdout.fileno()
        while b"\n" not in self.buffer:  # unbuffered reads, so that select sees every byte
            if deadline is not None and not select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]:
                return {}
            chunk = os.read(fd, 65536)
            if not chunk:
                raise RuntimeError(f"the CLI zygote ended: {Path(self.log.name).read_text()[-2000:]}")
            self.buffer += chunk
        line, self.buffer = self.buffer.split(b"\n", 1)
        return json.loads(line)

    def run(self, argv: list[str], env: dict[str, str], timeout: float) -> CliResult:
        out, err = self.dir / "stdout", self.dir / "stderr"
        request = {"argv": argv, "env": env, "cwd": str(REPO), "stdout": str(out), "stderr": str(err)}
        self.proc.stdin.write(json.dumps(request).encode() + b"\n")
        started = time.monotonic()
        pid = self._reply(None)["pid"]
        reply = self._reply(started + timeout)
        if not reply:  # as subprocess.run does on a timeout: kill, wait, raise
            os.kill(pid, signal.SIGKILL)
            self._reply(None)
            raise subprocess.TimeoutExpired(["d2a", *argv], timeout)
        return CliResult(reply["code"], out.read_text(), err.read_text())

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()  # the zygote's loop ends at end of input
            self.proc.wait(timeout=30)
        shutil.rmtree(self.dir, ignore_errors=True)
        Path(self.log.name).unlink(missing_ok=True)


_zygote: _Zygote | None = None


def run_cli(*args: str, store: Path | None = None, timeout: float = 300, env: dict | None = None,
            fresh_process: bool = False) -> CliResult:
    """`d2a ARGS [--store STORE]` with the test process's environment plus `env`.

    By default the call runs in a child forked from a zygote that has imported torch & co. once
    (tests/cli_zygote.py): the same CLI, argv, environment and working directory as `python -m
    d2a_cli`, without ~5 s of imports per call on the CI machine. `fresh_process=True` (or
    D2A_TEST_FRESH_PROCESSES=1 for every call) starts a new interpreter instead: for what a
    fork shares, such as the string-hash seed (tests that compare two runs' results use it).
    """
    global _zygote
    argv = [*args, *(("--store", str(store)) if store is not None else ())]
    full_env = dict(os.environ, **(env or {}))
    fresh = (fresh_process or os.environ.get("D2A_TEST_FRESH_PROCESSES") == "1" or not hasattr(os, "fork")
             or any(k.startswith(_STARTUP_ENV) for k in (env or {})))
    if fresh:
        proc = subprocess.run([sys.executable, "-m", "d2a_cli", *argv], capture_output=True, text=True,
                              timeout=timeout, env=full_env, cwd=REPO)
        return CliResult(proc.returncode, proc.stdout, proc.stderr)
    if _zygote is None or _zygote.proc.poll() is not None:
        _zygote = _Zygote()
    return _zygote.run(argv, full_env, timeout)


def built_once(tmp_path_factory, name: str, build: Callable[[Path], Any]) -> Any:
    """`build(directory)`'s JSON-able result, computed once per test session even under
    pytest-xdist: the first worker to ask builds it in the session's shared temporary directory,
    the others wait for it (a file lock) and read the stored result. Users must not change what
    it built (copy it first)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return build(tmp_path_factory.mktemp(name))
    shared = tmp_path_factory.getbasetemp().parent  # the session's directory, above every worker's own
    result = shared / f"{name}.json"
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not result.exists():
            (shared / name).mkdir(exist_ok=True)  # a worker whose build failed may have left it
            value = build(shared / name)
            result.write_text(json.dumps(value))
        return json.loads(result.read_text())


def copy_store(store: Path, parent: Path) -> Path:
    """A copy of a whole store under `parent` (tests that change a shared store change a copy)."""
    target = parent / "store"
    shutil.copytree(store, target)
    return target


def kill_after_state_saved(args: list[str] | tuple[str, ...], store: Path, timeout: float = 240) -> Path:
    """Run `d2a ARGS --store STORE` (a training command) in a new interpreter, SIGKILL it once it
    has saved a run state, and return that state's path."""
    cmd = [sys.executable, "-m", "d2a_cli", *args, "--store", str(store)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout
    while not list((store / "runs").glob("*/state.pt")):
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return next((store / "runs").glob("*/state.pt"))
