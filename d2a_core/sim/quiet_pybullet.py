"""Import pybullet without its banner on stdout.

pybullet prints its build time from C on import, straight to file descriptor 1, which would
corrupt `--json` output. The import runs with fd 1 pointed at stderr.
"""

from __future__ import annotations

import os
import sys


def _import_quietly():
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        import pybullet
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
    return pybullet


pb = _import_quietly()
