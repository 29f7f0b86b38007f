"""Building blocks: DreamerV3's Linear -> LayerNorm -> SiLU MLPs and their initialisation."""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn


def init_linear_(layer: nn.Linear, zero: bool = False) -> nn.Linear:
    """Truncated-normal fan-average init (DreamerV3's), or all zeros for output layers that
    must start predicting nothing (reward and critic heads)."""
    if zero:
        nn.init.zeros_(layer.weight)
    else:
        fan_out, fan_in = layer.weight.shape
        # 0.8796 is the std of a unit normal truncated at +-2: it restores the intended variance.
        std = math.sqrt(2.0 / (fan_in + fan_out)) / 0.87962566103423978
        nn.init.trunc_normal_(layer.weight, std=std, a=-2.0 * std, b=2.0 * std)
    if layer.bias is not None:
        nn.init.zeros_(layer.bias)
    return layer


class NormLayer(nn.Module):
    """Linear (no bias: the norm's shift replaces it) -> LayerNorm -> SiLU."""

    def __init__(self, in_size: int, out_size: int, eps: float) -> None:
        super().__init__()
        self.linear = init_linear_(nn.Linear(in_size, out_size, bias=False))
        self.norm = nn.LayerNorm(out_size, eps=eps)

    def forward(self, x: Tensor) -> Tensor:
        return nn.functional.silu(self.norm(self.linear(x)))

    def forward_preactivation(self, pre: Tensor) -> Tensor:
        """Finish the layer from an already computed linear output (used when the matmul is split)."""
        return nn.functional.silu(self.norm(pre))


class MLP(nn.Module):
    """`layers` NormLayers of `units`, then an optional linear output layer."""

    def __init__(
        self,
        in_size: int,
        units: int,
        layers: int,
        eps: float,
        out_size: int | None = None,
        zero_output: bool = False,
    ) -> None:
        super().__init__()
        sizes = [in_size] + [units] * layers
        self.hidden = nn.Sequential(*(NormLayer(a, b, eps) for a, b in zip(sizes[:-1], sizes[1:])))
        self.out = init_linear_(nn.Linear(units, out_size), zero=zero_output) if out_size else None

    @property
    def first(self) -> NormLayer:
        """The first hidden layer (its input weight may be applied in pieces by callers)."""
        return self.hidden[0]

    def forward(self, x: Tensor) -> Tensor:
        x = self.hidden(x)
        return self.out(x) if self.out is not None else x

    def forward_from_first(self, first_pre: Tensor) -> Tensor:
        """Forward given the first layer's linear output (pre-norm) computed elsewhere."""
        x = self.hidden[0].forward_preactivation(first_pre)
        for layer in self.hidden[1:]:
            x = layer(x)
        return self.out(x) if self.out is not None else x


@torch.no_grad()
def ema_update_(target: nn.Module, source: nn.Module, fraction: float) -> None:
    """target <- (1 - fraction) * target + fraction * source, parameter by parameter."""
    target_params = list(target.parameters())
    source_params = list(source.parameters())
    torch._foreach_lerp_(target_params, source_params, fraction)
