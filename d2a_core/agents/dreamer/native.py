"""Compiled CPU kernels for the categorical latents (`cpu_kernels.c`), with PyTorch fallbacks.

On first use the C file is compiled with the system C compiler (`$CC`, else `cc`) for this
CPU (-O3 -march=native, OpenMP sharing PyTorch's runtime) into a cache directory
(`$D2A_KERNEL_CACHE`, else `~/.cache/d2a/kernels`), keyed by the source, the flags, the compiler
and the CPU, and loaded with ctypes. Where that is impossible (no compiler, read-only cache,
another OS) or `D2A_NATIVE_KERNELS=0`, callers use PyTorch ops that compute the same thing;
`status()` says which. The kernels are only used for contiguous float32 CPU tensors.

Why: on CPU these ops are bound by memory passes and per-op overhead, not arithmetic. Sampling
a latent state (softmax, uniform mix, cumulative sum, search) took five passes over a
1024 x 32 x 32 tensor in every imagination step, the table gradient of an embedding-bag (the
one-hot latent's weight gradient) one index_add per latent, and the LayerNorm-GRU cell after its
matmul eight ops; each kernel makes one pass.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import torch
from torch import Tensor

from d2a_core.mkl_on_amd import kernel_cache_dir

log = logging.getLogger(__name__)

_SOURCE = Path(__file__).with_name("cpu_kernels.c")
_FLAGS = ["-O3", "-march=native", "-fno-math-errno", "-fno-trapping-math", "-fPIC", "-shared"]
if platform.machine() == "x86_64":
    _FLAGS.append("-mprefer-vector-width=512")  # AVX-512 where the CPU has it (GCC prefers 256)
_lock = threading.Lock()
_state: dict[str, object] = {"lib": None, "tried": False, "reason": "not loaded yet"}

_p = ctypes.c_void_p
_i64 = ctypes.c_int64
_SIGNATURES = {
    "d2a_table_gradient": [_p, _p, _p, _i64, _i64, _i64, _i64, ctypes.c_int],
    "d2a_unimix_sample": [_p, _p, _p, _p, _p, _i64, _i64, _i64, ctypes.c_float, ctypes.c_int],
    "d2a_unimix_backward": [_p, _p, _p, _i64, _i64, ctypes.c_float, ctypes.c_int],
    "d2a_ln_gru": [_p, _p, _p, _p, ctypes.c_float, _p, _p, _p, _i64, _i64, ctypes.c_int],
    "d2a_ln_gru_backward": [_p, _p, _p, _p, _p, _p, _p, _p, _p, _p, _i64, _i64, ctypes.c_int],
}


def _cpu_signature() -> str:
    """What -march=native depends on: the CPU's model and feature flags."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        return "\n".join(line for line in lines if line.startswith(("model name", "flags")))[:20000]
    except OSError:
        return platform.processor()


def _compile(compiler: str) -> Path:
    source = _SOURCE.read_bytes()
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    cpu = _cpu_signature().encode()
    variants = []  # with OpenMP first; without it the kernels run on one thread
    for openmp in (["-fopenmp"], []):
        flags = _FLAGS + openmp
        key = hashlib.sha256(b"\0".join([source, " ".join(flags).encode(), version.encode(), cpu])).hexdigest()[:20]
        variants.append((flags, kernel_cache_dir() / f"cpu_kernels-{key}.so"))
    # A library built before is used without compiling again (also where OpenMP failed to link).
    for _, target in variants:
        if target.exists():
            return target
    last_error = ""
    for flags, target in variants:
        target.parent.mkdir(parents=True, exist_ok=True)
        # Compile to a temporary name and rename: a killed compile never leaves a half library.
        handle, partial = tempfile.mkstemp(dir=target.parent, suffix=".so.partial")
        os.close(handle)
        try:
            libraries = ["-lmvec", "-lm"] if platform.machine() == "x86_64" else ["-lm"]
            result = subprocess.run([compiler, *flags, str(_SOURCE), "-o", partial, *libraries],
                                    capture_output=True, text=True, timeout=120)
            if result.returncode == 0:
                os.replace(partial, target)
                return target
            last_error = result.stderr.strip()[-500:]
        finally:
            if os.path.exists(partial):
                os.unlink(partial)
    raise RuntimeError(f"compiling {_SOURCE.name} failed: {last_error}")


def _load() -> ctypes.CDLL | None:
    if _state["tried"]:
        return _state["lib"]  # type: ignore[return-value]
    with _lock:
        if _state["tried"]:
            return _state["lib"]  # type: ignore[return-value]
        _state["tried"] = True
        if os.environ.get("D2A_NATIVE_KERNELS", "1") == "0":
            _state["reason"] = "disabled by D2A_NATIVE_KERNELS=0"
            return None
        compiler = shutil.which(os.environ.get("CC", "cc"))
        if platform.system() != "Linux" or compiler is None:
            _state["reason"] = "needs Linux and a C compiler ($CC or cc)"
            return None
        try:
            lib = ctypes.CDLL(str(_compile(compiler)))
            for name, argtypes in _SIGNATURES.items():
                getattr(lib, name).argtypes = argtypes
                getattr(lib, name).restype = None
        except (OSError, RuntimeError, subprocess.SubprocessError) as error:
            _state["reason"] = f"unavailable ({error}); using PyTorch ops"
            log.warning("d2a CPU kernels %s", _state["reason"])
            return None
        _state["lib"], _state["reason"] = lib, "compiled CPU kernels in use"
        return lib


def status() -> str:
    """Whether the compiled kernels are in use, and if not, why (loads them if not tried yet)."""
    _load()
    return str(_state["reason"])


def usable(*tensors: Tensor) -> bool:
    """Whether the kernels can take these tensors (contiguous, on the CPU, float32 or int64)."""
    if not all(t.device.type == "cpu" and t.is_contiguous() and t.dtype in (torch.float32, torch.int64) for t in tensors):
        return False
    return _load() is not None


def _threads(work: int, parallel_from: int) -> int:
    """PyTorch's thread count for work of at least `parallel_from` elements (measured: below
    that, starting a parallel region costs more than it saves), else one."""
    return torch.get_num_threads() if work >= parallel_from else 1


def table_gradient(index: Tensor, rows: int, grad: Tensor) -> Tensor:
    """(rows, width) gradient of an embedding-bag table: each row of grad (M, width) summed into
    the rows its bag index (M, stoch) used. Callers check `usable` first; the indices are the
    ones the forward embedding-bag already range-checked."""
    samples, stoch = index.shape
    width = grad.shape[1]
    out = torch.empty(rows, width, dtype=torch.float32)
    _state["lib"].d2a_table_gradient(  # type: ignore[union-attr]
        index.data_ptr(), grad.data_ptr(), out.data_ptr(), samples, stoch, rows, width,
        _threads(samples * stoch * width, 1 << 20),
    )
    return out


def unimix_backward(probs: Tensor, grad: Tensor, mix: float) -> Tensor:
    """Gradient of the logits given the gradient of `UnimixSample`'s probs (both contiguous)."""
    classes = probs.shape[-1]
    out = torch.empty_like(probs)
    _state["lib"].d2a_unimix_backward(  # type: ignore[union-attr]
        probs.data_ptr(), grad.data_ptr(), out.data_ptr(), probs.numel() // classes, classes, mix,
        _threads(probs.numel(), 1 << 13),
    )
    return out


class UnimixSample(torch.autograd.Function):
    """probs = (1 - mix) softmax(logits + bias) + mix / classes over the last axis of logits
    (..., stoch, classes) (bias (stoch, classes) or None), and flat sample indices (..., stoch)
    by inverse CDF with uniform (..., stoch, 1). Differentiable in logits and bias through
    probs; callers check `usable` first. Adding the bias here saves a pass over the logits."""

    @staticmethod
    def forward(ctx, logits: Tensor, uniform: Tensor, mix: float, bias: Tensor | None = None) -> tuple[Tensor, Tensor]:  # type: ignore[override]
        stoch, classes = logits.shape[-2:]
        groups = logits.numel() // classes
        probs = torch.empty_like(logits)
        index = torch.empty(logits.shape[:-1], dtype=torch.int64)
        _state["lib"].d2a_unimix_sample(  # type: ignore[union-attr]
            logits.data_ptr(), None if bias is None else bias.data_ptr(), uniform.data_ptr(),
            probs.data_ptr(), index.data_ptr(), groups, stoch, classes, mix, _threads(logits.numel(), 1 << 12),
        )
        ctx.save_for_backward(probs)
        ctx.mix = mix
        ctx.mark_non_differentiable(index)
        return probs, index

    @staticmethod
    def backward(ctx, grad_probs: Tensor, _grad_index: Tensor):  # type: ignore[override]
        (probs,) = ctx.saved_tensors
        grad_logits = unimix_backward(probs, grad_probs.float().contiguous(), ctx.mix)
        grad_bias = None
        if ctx.needs_input_grad[3]:
            grad_bias = grad_logits.reshape(-1, *probs.shape[-2:]).sum(0)
        return grad_logits, None, None, grad_bias


def ln_gru(p: Tensor, h_prev: Tensor, weight: Tensor, bias: Tensor, eps: float) -> tuple[Tensor, Tensor, Tensor]:
    """The LayerNorm GRU cell after its matmul (see `RSSM.gru`), without autograd: new state
    (rows, deter) and the norm's per-row mean and 1 / std. All arguments contiguous float32."""
    rows, deter = h_prev.shape
    h = torch.empty_like(h_prev)
    mean, rstd = torch.empty(rows, 1), torch.empty(rows, 1)
    _state["lib"].d2a_ln_gru(  # type: ignore[union-attr]
        p.data_ptr(), h_prev.data_ptr(), weight.data_ptr(), bias.data_ptr(), eps, h.data_ptr(),
        mean.data_ptr(), rstd.data_ptr(), rows, deter, _threads(p.numel(), 1 << 15),
    )
    return h, mean, rstd


def ln_gru_backward(
    p: Tensor, h_prev: Tensor, weight: Tensor, bias: Tensor, mean: Tensor, rstd: Tensor, dh: Tensor, want_dq: bool
) -> tuple[Tensor, Tensor, Tensor | None]:
    """Gradients of `ln_gru`'s p and h_prev given dh, and of the norm's output if `want_dq`."""
    rows, deter = h_prev.shape
    dp, dh_prev = torch.empty_like(p), torch.empty_like(h_prev)
    dq = torch.empty_like(p) if want_dq else None
    _state["lib"].d2a_ln_gru_backward(  # type: ignore[union-attr]
        p.data_ptr(), h_prev.data_ptr(), weight.data_ptr(), bias.data_ptr(), mean.data_ptr(),
        rstd.data_ptr(), dh.data_ptr(), dp.data_ptr(), dh_prev.data_ptr(),
        None if dq is None else dq.data_ptr(), rows, deter, _threads(p.numel(), 1 << 15),
    )
    return dp, dh_prev, dq


class LnGru(torch.autograd.Function):
    """`ln_gru` with autograd; callers check `usable` first."""

    @staticmethod
    def forward(ctx, p: Tensor, h_prev: Tensor, weight: Tensor, bias: Tensor, eps: float) -> Tensor:  # type: ignore[override]
        h, mean, rstd = ln_gru(p, h_prev, weight, bias, eps)
        ctx.save_for_backward(p, h_prev, weight, bias, mean, rstd)
        return h

    @staticmethod
    def backward(ctx, dh: Tensor):  # type: ignore[override]
        p, h_prev, weight, bias, mean, rstd = ctx.saved_tensors
        want_params = ctx.needs_input_grad[2] or ctx.needs_input_grad[3]
        dp, dh_prev, dq = ln_gru_backward(p, h_prev, weight, bias, mean, rstd, dh.contiguous(), want_params)
        d_weight = d_bias = None
        if want_params:
            _, d_weight, d_bias = torch.ops.aten.native_layer_norm_backward(
                dq, p, (p.shape[-1],), mean, rstd, weight, bias, [False, True, True]
            )
        return dp, dh_prev, d_weight, d_bias, None
