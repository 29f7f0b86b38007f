"""Symlog, two-hot regression, unimix categoricals, straight-through samples, the bounded actor
distribution, and the one-hot linear layer that replaces a dense matmul over samples."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from d2a_core.agents.dreamer.distributions import (
    TwoHot,
    bounded_normal_params,
    bounded_normal_sample,
    normal_entropy,
    sample_onehot,
    straight_through,
    symexp,
    symlog,
    sample_index,
    unimix_probs,
)
from d2a_core.agents.dreamer.latent import Latent, LatentMLP, Readout


def test_symlog_symexp_are_inverse_and_compress():
    x = torch.tensor([-1e4, -100.0, -1.0, -1e-3, 0.0, 1e-3, 1.0, 100.0, 1e4], dtype=torch.float64)
    assert torch.allclose(symexp(symlog(x)), x, rtol=1e-12, atol=1e-12)
    assert symlog(torch.tensor(1e4)).item() == pytest.approx(math.log(1e4 + 1))
    assert torch.equal(torch.sign(symlog(x)), torch.sign(x))


def test_twohot_encode_round_trip_and_weights():
    twohot = TwoHot(255, 20.0)
    targets = torch.tensor([-3000.0, -7.3, -0.25, 0.0, 0.013, 1.0, 42.0, 1e5])
    weights = twohot.encode(targets)
    assert torch.allclose(weights.sum(-1), torch.ones(len(targets)))
    assert ((weights > 0).sum(-1) <= 2).all()
    decoded = symexp(weights @ twohot.bins)
    assert torch.allclose(decoded, targets, rtol=1e-4, atol=1e-5)
    # Logits that reproduce the code decode to the target through the predicted mean.
    assert torch.allclose(twohot.mean(torch.log(weights + 1e-12)), targets, rtol=1e-3, atol=1e-4)


def test_twohot_loss_is_minimised_at_the_right_bin_mix():
    twohot = TwoHot(11, 5.0)  # bins every 1.0 in symlog space
    target = torch.tensor([symexp(torch.tensor(1.3)).item()])  # 30 % of the way from bin 6 to 7
    logits = torch.zeros(1, 11, requires_grad=True)
    optimizer = torch.optim.Adam([logits], lr=0.1)
    for _ in range(600):
        optimizer.zero_grad()
        twohot.loss(logits, target).sum().backward()
        optimizer.step()
    probs = torch.softmax(logits.detach(), -1)[0]
    assert probs[6].item() == pytest.approx(0.7, abs=0.02)
    assert probs[7].item() == pytest.approx(0.3, abs=0.02)
    assert twohot.mean(logits.detach()).item() == pytest.approx(target.item(), rel=0.02)
    # The optimum's loss is the code's entropy, lower than for a one-hot on the nearest bin.
    entropy = -(0.7 * math.log(0.7) + 0.3 * math.log(0.3))
    assert twohot.loss(logits.detach(), target).item() == pytest.approx(entropy, abs=0.02)


def test_unimix_puts_at_least_one_percent_on_every_class():
    logits = torch.tensor([[[50.0] + [-50.0] * 31]]).repeat(4, 32, 1)
    probs = unimix_probs(logits, 0.01)
    assert torch.allclose(probs.sum(-1), torch.ones(4, 32))
    assert probs.min().item() >= 0.01 / 32 * (1 - 1e-6)
    assert probs.max().item() == pytest.approx(0.99 + 0.01 / 32, abs=1e-6)


def test_inverse_cdf_sampling_matches_probabilities():
    probs = torch.tensor([0.1, 0.6, 0.3]).expand(20000, 1, 3)
    uniform = torch.rand(20000, 1, 1, generator=torch.Generator().manual_seed(0))
    onehot = sample_onehot(probs, uniform)
    frequencies = onehot.mean((0, 1))
    assert torch.allclose(frequencies, torch.tensor([0.1, 0.6, 0.3]), atol=0.015)
    index = sample_index(probs, uniform, torch.tensor([0]))
    assert torch.equal(index[:, 0], onehot[:, 0].argmax(-1))


def test_straight_through_has_sample_value_and_probability_gradient():
    logits = torch.randn(5, 4, 6, requires_grad=True)
    probs = unimix_probs(logits, 0.01)
    onehot = sample_onehot(probs, torch.rand(5, 4, 1))
    sample = straight_through(onehot, probs)
    assert torch.equal(sample.detach(), onehot)
    weights = torch.randn(6)
    (sample * weights).sum().backward()
    expected = torch.autograd.grad((unimix_probs(logits, 0.01) * weights).sum(), logits)[0]
    assert logits.grad is not None and logits.grad.abs().sum() > 0
    assert torch.allclose(logits.grad, expected, atol=1e-6)


def test_bounded_normal_stays_in_bounds_and_passes_gradients():
    raw = torch.tensor([[2.0, -2.0, -10.0, 10.0]], requires_grad=True)  # mean ~(0.96, -0.96), std (min, max)
    mean, std = bounded_normal_params(raw, 0.1, 1.0)
    assert std[0, 0].item() == pytest.approx(0.1, abs=1e-3)
    assert std[0, 1].item() == pytest.approx(1.0, abs=1e-3)
    action = bounded_normal_sample(mean, std, torch.tensor([[3.0, -3.0]]))
    assert action.detach().abs().max().item() <= 1.0
    action.sum().backward()
    assert raw.grad[0, :2].abs().sum() > 0  # straight through the clip to the mean
    entropy = normal_entropy(torch.tensor([[0.5, 2.0]]))
    assert entropy.item() == pytest.approx(2 * 0.5 * math.log(2 * math.pi * math.e) + math.log(1.0))


def _random_latent(n: int, deter: int, stoch: int, classes: int, seed: int) -> Latent:
    generator = torch.Generator().manual_seed(seed)
    h = torch.randn(n, deter, generator=generator, requires_grad=True)
    logits = torch.randn(n, stoch, classes, generator=generator, requires_grad=True)
    probs = unimix_probs(logits, 0.01)
    uniform = torch.rand(n, stoch, 1, generator=generator)
    return Latent(h, sample_index(probs, uniform, torch.arange(stoch) * classes), probs)


def test_onehot_linear_equals_dense_linear_on_straight_through_samples():
    """The embedding-bag layer must give the dense formulation's outputs and gradients."""
    torch.manual_seed(0)
    deter, stoch, classes = 5, 3, 4
    mlps = [LatentMLP(deter, stoch * classes, 8, 1, 1e-3, out_size=3) for _ in range(2)]
    latent = _random_latent(7, deter, stoch, classes, seed=1)

    fused = Readout(mlps)(latent)
    loss = sum((mlp.finish(pre) ** 2).sum() for mlp, pre in zip(mlps, fused))
    params = [latent.h, latent.probs] + [p for mlp in mlps for p in (mlp.first.dense_weight, mlp.first.table)]
    grads = torch.autograd.grad(loss, params)

    feat = latent.dense()
    dense_loss = 0
    for mlp in mlps:
        weight = torch.cat((mlp.first.dense_weight, mlp.first.table.t()), 1)
        dense_loss = dense_loss + (mlp.finish(F.linear(feat, weight)) ** 2).sum()
    dense_grads = torch.autograd.grad(dense_loss, params)
    assert torch.allclose(loss, dense_loss, rtol=1e-5)
    for fast, slow in zip(grads, dense_grads):
        assert torch.allclose(fast, slow, rtol=1e-4, atol=1e-5)
    # Single-module forward (few rows: the dense one-hot path) agrees with the fused one.
    assert torch.allclose(mlps[1](latent), mlps[1].finish(fused[1]), atol=1e-6)
    single = torch.autograd.grad((mlps[1](latent) ** 2).sum(), [latent.h, latent.probs, mlps[1].first.table])
    fused_single = torch.autograd.grad((mlps[1].finish(Readout(mlps[1:])(latent)[0]) ** 2).sum(),
                                       [latent.h, latent.probs, mlps[1].first.table])
    for a, b in zip(single, fused_single):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("rows", [7, 100])
def test_readout_with_input_stopped_mlps_equals_dense_layers_on_detached_states(rows):
    """`Readout(..., input_stopped=k)`: the first k MLPs read sg(state) (the actor in
    imagination), the others the state itself; outputs and every gradient (states and first
    layer weights) match dense layers where the first k get explicitly detached features."""
    torch.manual_seed(0)
    deter, stoch, classes = 5, 3, 4
    mlps = [LatentMLP(deter, stoch * classes, 8, 1, 1e-3, out_size=3) for _ in range(3)]
    extra = torch.randn(stoch * classes, 6, requires_grad=True)
    latent = _random_latent(rows, deter, stoch, classes, seed=1)
    probe = torch.randn(rows, 6)

    outs = Readout(mlps, [extra], input_stopped=1)(latent)
    loss = sum((mlp.finish(pre) ** 2).sum() for mlp, pre in zip(mlps, outs)) + (outs[3] * probe).sum()
    params = [latent.h, latent.probs, extra] + [p for mlp in mlps for p in (mlp.first.dense_weight, mlp.first.table)]
    grads = torch.autograd.grad(loss, params)

    feat = latent.dense()
    dense_loss = (feat[:, deter:] @ extra * probe).sum()
    for k, mlp in enumerate(mlps):
        weight = torch.cat((mlp.first.dense_weight, mlp.first.table.t()), 1)
        dense_loss = dense_loss + (mlp.finish(F.linear(feat.detach() if k < 1 else feat, weight)) ** 2).sum()
    dense_grads = torch.autograd.grad(dense_loss, params)
    assert torch.allclose(loss, dense_loss, rtol=1e-5)
    for fast, slow in zip(grads, dense_grads):
        assert slow.abs().sum() > 0
        assert torch.allclose(fast, slow, rtol=1e-4, atol=1e-5)
    # The stopped MLP alone sends nothing to the states, only to its own weights.
    alone = Readout(mlps[:1], [extra], input_stopped=1)(latent)[0]
    assert torch.allclose(alone, outs[0])
    h_grad, probs_grad, table_grad = torch.autograd.grad(
        (mlps[0].finish(alone) ** 2).sum(), [latent.h, latent.probs, mlps[0].first.table], allow_unused=True
    )
    assert h_grad is None and torch.count_nonzero(probs_grad) == 0 and table_grad.abs().sum() > 0


def test_table_gradient_paths_agree_for_small_and_large_batches():
    from d2a_core.agents.dreamer.latent import table_gradient

    generator = torch.Generator().manual_seed(0)
    for rows_in_batch in (3, 5000):
        index = torch.randint(0, 4, (rows_in_batch, 8), generator=generator) + torch.arange(8) * 4
        grad = torch.randn(rows_in_batch, 16, generator=generator)
        onehot = torch.zeros(rows_in_batch, 32).scatter_(1, index, 1.0)
        assert torch.allclose(table_gradient(index, 32, grad), onehot.t() @ grad, atol=1e-3)
