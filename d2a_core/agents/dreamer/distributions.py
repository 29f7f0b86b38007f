"""The distributions DreamerV3 uses, as plain tensor functions (no distribution objects, which
cost more Python time than the arithmetic in the per-step loops).

- symlog / symexp squashing,
- two-hot discrete regression over bins that are uniform in symlog space,
- categorical latents with a uniform mixture and straight-through one-hot samples,
- the continuous actor's bounded normal and the discrete actor's categorical.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from . import native


def symlog(x: Tensor) -> Tensor:
    """sign(x) * ln(|x| + 1): compresses large magnitudes, identity-like near zero."""
    return torch.sign(x) * torch.log1p(torch.abs(x))


def symexp(x: Tensor) -> Tensor:
    """Inverse of `symlog`: sign(x) * (exp(|x|) - 1)."""
    return torch.sign(x) * torch.expm1(torch.abs(x))


class TwoHot:
    """Two-hot regression over `num_bins` bins spaced uniformly in symlog space on [-limit, limit].

    A scalar target y is encoded as weights on the two bins around symlog(y) (linear
    interpolation), the loss is the cross-entropy of the predicted softmax against them, and the
    prediction is symexp of the softmax-weighted bin position.
    """

    def __init__(self, num_bins: int, limit: float, device: torch.device | str = "cpu") -> None:
        self.num_bins = num_bins
        self.limit = limit
        self.step = 2.0 * limit / (num_bins - 1)
        self.bins = torch.linspace(-limit, limit, num_bins, device=device)

    def to(self, device: torch.device | str) -> TwoHot:
        """Return a copy whose bins live on `device`."""
        return TwoHot(self.num_bins, self.limit, device)

    def _position(self, target: Tensor) -> tuple[Tensor, Tensor]:
        """Lower bin index and the weight of the upper bin for raw-space targets. A NaN target
        gives a valid index but a NaN weight, so the loss reports it instead of crashing."""
        position = (symlog(target).clamp(-self.limit, self.limit) + self.limit) / self.step
        lower = torch.nan_to_num(position, nan=0.0).floor().clamp(0, self.num_bins - 2)
        return lower.long(), position - lower

    def encode(self, target: Tensor) -> Tensor:
        """Dense two-hot weights (..., num_bins) of raw-space targets (..., )."""
        lower, upper_weight = self._position(target)
        weights = torch.zeros(*target.shape, self.num_bins, device=target.device, dtype=torch.float32)
        weights.scatter_(-1, lower.unsqueeze(-1), (1.0 - upper_weight).unsqueeze(-1).float())
        weights.scatter_add_(-1, (lower + 1).unsqueeze(-1), upper_weight.unsqueeze(-1).float())
        return weights

    def loss(self, logits: Tensor, target: Tensor) -> Tensor:
        """Cross-entropy of `logits` (..., num_bins) against the two-hot code of `target` (...)."""
        return self.loss_from_log_probs(torch.log_softmax(logits.float(), dim=-1), target)

    def loss_from_log_probs(self, log_probs: Tensor, target: Tensor) -> Tensor:
        """`loss` given log_softmax(logits): several targets of the same prediction (the critic's
        return and slow-critic targets) share one log-softmax."""
        lower, upper_weight = self._position(target.detach().float())
        both = torch.stack((lower, lower + 1), dim=-1)
        picked = log_probs.gather(-1, both)
        return -(picked[..., 0] * (1.0 - upper_weight) + picked[..., 1] * upper_weight)

    def mean(self, logits: Tensor) -> Tensor:
        """Predicted value in raw space: symexp of the expected bin position."""
        probs = torch.softmax(logits.float(), dim=-1)
        return symexp(probs @ self.bins)


def unimix_probs(logits: Tensor, unimix: float) -> Tensor:
    """Softmax over the last axis mixed with `unimix` of the uniform distribution."""
    probs = torch.softmax(logits.float(), dim=-1)
    if unimix > 0:  # the product is a fresh tensor nothing saved, so the add can be in place
        probs = probs.mul(1.0 - unimix).add_(unimix / logits.shape[-1])
    return probs


def sample_index(probs: Tensor, uniform: Tensor, offsets: Tensor) -> Tensor:
    """Flat sample indices (..., stoch) of categoricals probs (..., stoch, classes) by inverse
    CDF with uniform (..., stoch, 1); `offsets` = arange(stoch) * classes."""
    cdf = probs.detach().cumsum(-1)
    local = torch.searchsorted(cdf, uniform).squeeze(-1).clamp_(max=probs.shape[-1] - 1)
    return local + offsets


def unimix_sample(
    logits: Tensor, uniform: Tensor, unimix: float, offsets: Tensor, bias: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """`unimix_probs` of logits (..., stoch, classes) plus `bias` (stoch, classes) if given
    (differentiable in both) and their `sample_index` samples, in one pass of a compiled kernel
    on the CPU (see native.py)."""
    if native.usable(logits, uniform, *([] if bias is None else [bias])):
        return native.UnimixSample.apply(logits, uniform, unimix, bias)
    probs = unimix_probs(logits if bias is None else logits + bias, unimix)
    return probs, sample_index(probs, uniform, offsets)


def unimix_probs_backward(probs: Tensor, grad: Tensor, unimix: float) -> Tensor:
    """Gradient of the logits given the gradient of `unimix_probs`' output `probs`, for callers
    that differentiate by hand (see filtering.py)."""
    if native.usable(probs, grad):
        return native.unimix_backward(probs, grad, unimix)
    mixed = probs - unimix / probs.shape[-1]  # (1 - unimix) * softmax
    dot = (mixed * grad).sum(-1, keepdim=True) / (1.0 - unimix)
    return mixed * (grad - dot)


def sample_onehot(probs: Tensor, uniform: Tensor) -> Tensor:
    """One-hot samples of categoricals `probs` (..., C) by inverse CDF from `uniform` (..., 1) in [0, 1)."""
    cdf = probs.detach().cumsum(-1)
    index = (cdf < uniform).sum(-1).clamp(max=probs.shape[-1] - 1)
    return F.one_hot(index, probs.shape[-1]).to(probs.dtype)


def straight_through(onehot: Tensor, probs: Tensor) -> Tensor:
    """Value of the one-hot sample, gradient of the probabilities."""
    return onehot + (probs - probs.detach())


def categorical_kl(log_p: Tensor, log_q: Tensor) -> Tensor:
    """KL(p || q) of categoricals (..., latents, classes), summed over classes and latents."""
    return (log_p.exp() * (log_p - log_q)).sum((-2, -1))


def onehot_mode(logits: Tensor) -> Tensor:
    """One-hot of the most likely class."""
    return F.one_hot(logits.argmax(-1), logits.shape[-1]).to(logits.dtype)


# --- continuous actor: normal with tanh-bounded mean and sigmoid-bounded std, samples clipped
#     to [-1, 1] with a straight-through gradient (the environment clips the same way).

_HALF_LOG_2PI_E = 0.5 * math.log(2.0 * math.pi * math.e)


def bounded_normal_params(raw: Tensor, min_std: float, max_std: float) -> tuple[Tensor, Tensor]:
    """Split actor output (..., 2A) into mean in (-1, 1) and std in [min_std, max_std]."""
    raw_mean, raw_std = raw.float().chunk(2, dim=-1)
    mean = torch.tanh(raw_mean)
    std = (max_std - min_std) * torch.sigmoid(raw_std + 2.0) + min_std
    return mean, std


def bounded_normal_sample(mean: Tensor, std: Tensor, noise: Tensor) -> Tensor:
    """Reparameterised sample clipped to [-1, 1]; the clip passes gradients straight through."""
    action = mean + std * noise
    return action + (action.clamp(-1.0, 1.0) - action).detach()


def normal_entropy(std: Tensor) -> Tensor:
    """Entropy of a diagonal normal, summed over the last axis."""
    return (torch.log(std) + _HALF_LOG_2PI_E).sum(-1)


def categorical_entropy(probs: Tensor) -> Tensor:
    """Entropy of categoricals over the last axis."""
    return -(probs * torch.log(probs)).sum(-1)
