"""Import pybullet without its banner on stdout.

pybullet prints its build time from C on import, straight to file descriptor 1, which would
corrupt `--json` output and clutters every log. The import runs with fd 1 pointed at /dev/null.
"""

from __future__ import annotations

import os
import sys


def _import_quietly():
    sys.stdout.flush()
    saved = os.dup(1)
    sink = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(sink, 1)
        import pybullet
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
        os.close(sink)
    return pybullet


pb = _import_quietly()
