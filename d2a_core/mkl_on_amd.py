"""MKL's fast matrix-multiply code paths on AMD CPUs (torch-free; must run before `import torch`).

PyTorch's x86 wheels do their float32 matmuls in Intel's MKL, linked into `libtorch_cpu.so`.
MKL picks its kernels by asking `mkl_serv_intel_cpu_true()` whether the CPU is Intel's, and on
any other vendor falls back to generic code paths whatever the CPU supports. On the 2-core AMD
EPYC (AVX-512) development machine that made the matmuls of a `quick` update run at 70-140
GFLOP/s instead of 165-190 (a 256 x 384 x 768 product: 1.39 -> 0.80 ms; docs/benchmarks.md).

The symbol is exported by `libtorch_cpu.so` and bound when torch is loaded, so a library that
defines it and is loaded into the process's global scope first takes its place: MKL then chooses
by the CPU's feature flags (AVX-512, AVX2, ...) as it does on Intel. `enable()` compiles that
one-line library with the system C compiler into the kernel cache (as `agents.dreamer.native`
does, once per machine) and loads it with RTLD_GLOBAL. It has to run before torch is imported;
the `d2a` command line calls it first thing, training records `status()` in its runtime.

Results differ from a run without it in float rounding only (another kernel sums in another
order), like a different thread count. `D2A_MKL_AMD=0` turns it off.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

_SOURCE = b"/* d2a: MKL's vendor check, answered yes (d2a_core/mkl_on_amd.py) */\n" \
          b"int mkl_serv_intel_cpu_true(void) { return 1; }\n"
SYMBOL = "mkl_serv_intel_cpu_true"
_state: dict[str, object] = {"status": None, "library": None}


def kernel_cache_dir() -> Path:
    """Where d2a's compiled libraries live: `$D2A_KERNEL_CACHE`, else `~/.cache/d2a/kernels`."""
    configured = os.environ.get("D2A_KERNEL_CACHE")
    if configured:
        return Path(configured)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "d2a" / "kernels"


def cpu_vendor(cpuinfo: str | None = None) -> str | None:
    """The `vendor_id` of /proc/cpuinfo (or of the given text), None where there is none."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return None
    for line in cpuinfo.splitlines():
        if line.startswith("vendor_id"):
            return line.partition(":")[2].strip()
    return None


def not_applicable(vendor: str | None, system: str, machine: str, torch_loaded: bool,
                   setting: str) -> str | None:
    """Why `enable` would do nothing here, or None where it applies."""
    if setting == "0":
        return "disabled by D2A_MKL_AMD=0"
    if system != "Linux" or machine != "x86_64":
        return f"not needed on {system} {machine}"
    if vendor != "AuthenticAMD":
        return f"not needed on a {vendor or 'unknown'} CPU"
    if torch_loaded:
        return "not applied: torch was imported before d2a_core.mkl_on_amd.enable()"
    return None


def enable() -> str:
    """Load the vendor-check library if this is an AMD CPU and torch is not loaded yet
    (idempotent). Returns `status()`."""
    if _state["status"] is not None:
        return str(_state["status"])
    reason = not_applicable(cpu_vendor(), platform.system(), platform.machine(), "torch" in sys.modules,
                            os.environ.get("D2A_MKL_AMD", "1"))
    if reason is not None:
        _state["status"] = reason
        return reason
    # Every `d2a` call passes here: a library built before is loaded without running a compiler
    # (one function returning 1 does not depend on the compiler's version).
    path = kernel_cache_dir() / f"mkl_vendor-{hashlib.sha256(_SOURCE).hexdigest()[:20]}.so"
    compiler = shutil.which(os.environ.get("CC", "cc"))
    if not path.exists() and compiler is None:
        _state["status"] = "not applied: needs a C compiler ($CC or cc)"
        return str(_state["status"])
    try:
        if not path.exists():
            _compile(str(compiler), path)
        _state["library"] = ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except (OSError, RuntimeError, subprocess.SubprocessError) as error:
        _state["status"] = f"not applied ({error})"
        return str(_state["status"])
    _state["status"] = "MKL vendor check answered by d2a: MKL uses the CPU's own instruction set"
    return str(_state["status"])


def status() -> str:
    """What `enable` did in this process ("not tried" before it ran)."""
    return str(_state["status"] or "not tried")


def _compile(compiler: str, target: Path) -> None:
    """Compile the library to `target` under a temporary name and rename it (a killed compile
    leaves no half library)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, source = tempfile.mkstemp(dir=target.parent, suffix=".c")
    with os.fdopen(handle, "wb") as file:
        file.write(_SOURCE)
    partial = source[:-2] + ".so.partial"
    try:
        result = subprocess.run([compiler, "-O2", "-fPIC", "-shared", source, "-o", partial],
                                capture_output=True, text=True, timeout=60)
        if result.returncode != 0:
            raise RuntimeError(f"compiling the MKL vendor check failed: {result.stderr.strip()[-300:]}")
        os.replace(partial, target)
    finally:
        for leftover in (source, partial):
            if os.path.exists(leftover):
                os.unlink(leftover)
