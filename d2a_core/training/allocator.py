"""Keep freed memory in the process during training (glibc's malloc only).

A DreamerV3 update on the CPU allocates and frees hundreds of multi-MiB tensors (the imagined
latent distributions are 1024 x 32 x 32 floats, 4 MiB each). With glibc's defaults, freed memory
at the top of the heap is handed back to the kernel as soon as 2x the mmap threshold of it is
free, and the next update faults the same pages in again: on the 2-core benchmark machine that
was ~240,000 page faults and ~0.3 s of system time per 10 updates. Fixing the mmap threshold
(which also stops glibc's own dynamic adjustment) and a trim threshold above any working set
keeps the pages mapped, so steady-state updates fault no pages at all. The cost is that the
process keeps its peak heap size until it exits, which is what a training process wants.

The `MALLOC_MMAP_THRESHOLD_` / `MALLOC_TRIM_THRESHOLD_` environment variables do the same from
outside the process; this module sets them from inside, once, for the training entry points.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

# mallopt parameter numbers (glibc malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

# Allocations of at least this size still get their own mapping (glibc's maximum for the
# threshold on 64-bit systems, and the value its dynamic adjustment would reach anyway).
MMAP_THRESHOLD = 32 << 20
# Free memory at the top of the heap is returned only beyond this (mallopt's largest value).
TRIM_THRESHOLD = 2**31 - 1

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Tune glibc's malloc for a training process (idempotent). Returns whether it applied:
    False on other C libraries or platforms, where nothing is changed."""
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _applied
