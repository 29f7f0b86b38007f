"""A process that imports the CLI's heavy third-party modules once, then forks one child per CLI
call (the test helpers' `run_cli` talks to it; see d2a_test_helpers.py).

Why: every `d2a` call that trains or evaluates spends ~5-6 s of a slow 2-core machine importing
torch (and torch._dynamo, which the first optimiser step imports), gymnasium and pybullet before
doing seconds of work; ~60 of the suite's ~180 CLI calls are such calls. A forked child starts with those modules
loaded and nothing of d2a's own: it imports `d2a_cli`, runs it like `python -m d2a_cli` (fresh
argv, environment, working directory, stdin/stdout/stderr), and exits with the CLI's code.

Protocol, one JSON object per line: the parent writes {"argv", "env", "cwd", "stdout",
"stderr"} (the last two: file paths); the zygote answers {"pid"} once the child runs and
{"code"} when it has ended (a negative code: killed by that signal). One call at a time.
"""

from __future__ import annotations

import atexit
import json
import os
import sys
import threading
import traceback

# MKL's kernels are chosen when torch loads, so the zygote does what `d2a_cli.main.main` does
# first, before importing torch (the child's call then finds it done): d2a_core/mkl_on_amd.py.
from d2a_core import mkl_on_amd

mkl_on_amd.enable()

# Otherwise third-party modules only: d2a's own modules (and anything they configure at import)
# load fresh in each child.
import gymnasium  # noqa: E402, F401
import numpy  # noqa: E402, F401
import pybullet  # noqa: E402, F401
import rich.console  # noqa: E402, F401
import torch  # noqa: E402, F401
import torch._dynamo  # noqa: E402, F401
import typer  # noqa: E402, F401
import yaml  # noqa: E402, F401

# Forking is safe while no Python thread runs and torch has started no thread pool (nothing here
# computes); numpy's BLAS pool, if any, re-forms itself in the child (pthread_atfork).
assert threading.active_count() == 1, "the zygote must not start threads"


def _child(request: dict) -> None:
    """Run the CLI in this forked child; never returns."""
    code = 1
    try:
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        for fd, path, flags in ((0, os.devnull, os.O_RDONLY),
                                (1, request["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC),
                                (2, request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)):
            opened = os.open(path, flags, 0o644)
            os.dup2(opened, fd)
            os.close(opened)
        sys.stdin = open(0, closefd=False)
        sys.stdout = open(1, "w", closefd=False)
        sys.stderr = open(2, "w", closefd=False)
        sys.argv = ["d2a", *request["argv"]]
        sys.path[0] = request["cwd"]  # as `python -m` puts the working directory first
        try:
            from d2a_cli.main import main

            main()
            code = 0
        except SystemExit as exc:  # the interpreter's rules: None is 0, a message is printed and 1
            if exc.code is None or isinstance(exc.code, int):
                code = exc.code or 0
            else:
                print(exc.code, file=sys.stderr)
        except BaseException:  # what the interpreter prints for an uncaught exception
            traceback.print_exc()
        atexit._run_exitfuncs()
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def serve() -> None:
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            _child(request)
        print(json.dumps({"pid": pid}), flush=True)
        _, status = os.waitpid(pid, 0)
        code = os.waitstatus_to_exitcode(status)
        print(json.dumps({"code": code}), flush=True)


if __name__ == "__main__":
    serve()
