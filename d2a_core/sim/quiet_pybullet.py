"""Import pybullet without its banner on stdout.

pybullet prints its build time from C on import (to fd 1 or 2, depending on the build), which
would corrupt `--json` output or clutter every log. The import runs with fds 1 and 2 pointed at
/dev/null; an import failure is still raised as an exception.
"""

from __future__ import annotations

import os
import sys


def _import_quietly():
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    sink = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in saved:
            os.dup2(sink, fd)
        import pybullet
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
        os.close(sink)
    return pybullet


pb = _import_quietly()
