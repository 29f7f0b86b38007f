"""The compiled CPU kernels (native.py) against the PyTorch ops they replace, and the fallback
when they cannot be built."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
import torch

from d2a_core.agents.dreamer import DreamerConfig, native
from d2a_core.agents.dreamer.distributions import unimix_probs_backward, unimix_sample
from d2a_core.agents.dreamer.latent import table_gradient
from d2a_core.agents.dreamer.rssm import RSSM

needs_kernels = pytest.mark.skipif(
    not native.usable(torch.zeros(1)), reason=f"compiled kernels unavailable: {native.status()}"
)


def test_kernels_are_built_where_a_c_compiler_exists():
    """On Linux with a compiler the kernels must load: a silent fallback would only show as a
    slower training run."""
    if sys.platform != "linux" or shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no C compiler here")
    if os.environ.get("D2A_NATIVE_KERNELS") == "0":
        pytest.skip("disabled by D2A_NATIVE_KERNELS=0")
    assert native.status() == "compiled CPU kernels in use"


def _torch_only(monkeypatch):
    monkeypatch.setattr(native, "usable", lambda *tensors: False)


@needs_kernels
@pytest.mark.parametrize("samples", [16, 1024, 5000])
def test_table_gradient_kernel_equals_index_add(monkeypatch, samples):
    stoch, classes, width = 32, 32, 96
    generator = torch.Generator().manual_seed(samples)
    index = torch.randint(0, classes, (samples, stoch), generator=generator) + torch.arange(stoch) * classes
    grad = torch.randn(samples, width, generator=generator)
    fast = table_gradient(index, stoch * classes, grad)
    _torch_only(monkeypatch)
    reference = table_gradient(index, stoch * classes, grad)
    assert torch.allclose(fast, reference, atol=1e-4)
    assert fast.abs().sum() > 0


@needs_kernels
@pytest.mark.parametrize(("rows", "unimix", "with_bias"), [(16, 0.01, False), (1024, 0.01, True), (300, 0.0, False)])
def test_unimix_sample_kernel_equals_torch_ops(monkeypatch, rows, unimix, with_bias):
    stoch, classes = 32, 32
    generator = torch.Generator().manual_seed(rows)
    logits = (3 * torch.randn(rows, stoch, classes, generator=generator)).requires_grad_()
    bias = torch.randn(stoch, classes, generator=generator).requires_grad_() if with_bias else None
    uniform = torch.rand(rows, stoch, 1, generator=generator)
    offsets = torch.arange(stoch) * classes
    cotangent = torch.randn(rows, stoch, classes, generator=generator)
    results = []
    for torch_only in (False, True):
        if torch_only:
            _torch_only(monkeypatch)
        probs, index = unimix_sample(logits, uniform, unimix, offsets, bias)
        inputs = (logits,) if bias is None else (logits, bias)
        grads = torch.autograd.grad((probs * cotangent).sum(), inputs)
        by_hand = unimix_probs_backward(probs.detach(), cotangent, unimix)
        results.append((probs.detach(), index, grads, by_hand))
    (probs, index, grads, by_hand), (probs_ref, index_ref, grads_ref, by_hand_ref) = results
    grad, grad_ref = grads[0], grads_ref[0]
    if bias is not None:
        assert torch.allclose(grads[1], grads_ref[1], atol=1e-5 * grads_ref[1].abs().max())
    assert torch.allclose(probs, probs_ref, atol=1e-6)
    assert probs.min() >= unimix / classes * 0.999
    # exp differs by an ulp between the two, so a uniform number right on a boundary may pick
    # the neighbouring class; anything more is a bug
    assert (index != index_ref).float().mean() < 1e-3
    assert ((index - offsets) >= 0).all() and ((index - offsets) < classes).all()
    scale = grad_ref.abs().max()
    assert (grad - grad_ref).abs().max() / scale < 1e-5
    assert (by_hand - grad_ref).abs().max() / scale < 1e-5
    assert (by_hand_ref - grad_ref).abs().max() / scale < 1e-5


@needs_kernels
@pytest.mark.parametrize("rows", [16, 1024])
def test_layer_norm_gru_kernel_equals_torch_ops(monkeypatch, rows):
    """RSSM.gru through the kernel and through PyTorch ops: same state, same gradients for the
    inputs, the previous state and every weight."""
    config = DreamerConfig(units=48, deter=40, stoch=4, classes=4)
    torch.manual_seed(rows)
    rssm = RSSM(config, embed_size=8, action_size=2)
    with torch.no_grad():  # non-trivial norm parameters
        rssm.gru_norm.weight.normal_(1.0, 0.3)
        rssm.gru_norm.bias.normal_(0.0, 0.3)
    x = torch.randn(rows, 48, requires_grad=True)
    h = torch.randn(rows, 40, requires_grad=True)
    cotangent = torch.randn(rows, 40)
    params = [x, h, rssm.gru_linear.weight, rssm.gru_norm.weight, rssm.gru_norm.bias]
    results = []
    for torch_only in (False, True):
        if torch_only:
            _torch_only(monkeypatch)
        out = rssm.gru(x, h)
        results.append((out.detach(), torch.autograd.grad((out * cotangent).sum(), params)))
    (out, grads), (out_ref, grads_ref) = results
    assert torch.allclose(out, out_ref, atol=1e-5)
    for grad, grad_ref in zip(grads, grads_ref):
        assert (grad - grad_ref).abs().max() <= 1e-4 * grad_ref.abs().max()


@needs_kernels
def test_unimix_sample_kernel_propagates_nan():
    """A diverged model must still produce a non-finite loss (the trainer stops on it)."""
    logits = torch.randn(4, 2, 8)
    logits[1, 0, 3] = float("nan")
    probs, _ = unimix_sample(logits, torch.rand(4, 2, 1), 0.01, torch.arange(2) * 8)
    assert torch.isnan(probs[1, 0]).all()
    assert torch.isfinite(probs[0]).all() and torch.isfinite(probs[1, 1]).all()


_PROBE = """
import json, torch
from d2a_core.agents.dreamer import DreamerConfig, native
from d2a_core.agents.dreamer.distributions import unimix_sample
probs, index = unimix_sample(torch.zeros(2, 3, 4), torch.full((2, 3, 1), 0.6), 0.01, torch.arange(3) * 4)
print(json.dumps({"status": native.status(), "index": index.tolist()}))
"""


def _probe(tmp_path, **env) -> dict:
    result = subprocess.run(
        [sys.executable, "-c", _PROBE],
        env={**os.environ, "D2A_KERNEL_CACHE": str(tmp_path / "cache"), **env},
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_without_a_working_compiler_the_torch_ops_are_used(tmp_path):
    broken = _probe(tmp_path, CC="false")
    assert "PyTorch ops" in broken["status"] or "needs" in broken["status"]
    disabled = _probe(tmp_path, D2A_NATIVE_KERNELS="0")
    assert "disabled" in disabled["status"]
    # uniform classes: the cumulative probabilities are 0.25, 0.5, 0.75, 1 -> class 2 at u = 0.6
    assert broken["index"] == disabled["index"] == [[2, 6, 10], [2, 6, 10]]
    assert not list((tmp_path / "cache").glob("*.partial"))


@needs_kernels
def test_compiled_library_is_cached(tmp_path):
    first = _probe(tmp_path)
    built = list((tmp_path / "cache").glob("cpu_kernels-*.so"))
    assert first["status"] == "compiled CPU kernels in use" and len(built) == 1
    stamp = built[0].stat().st_mtime_ns
    second = _probe(tmp_path)
    assert second == first
    assert built[0].stat().st_mtime_ns == stamp
