"""The model state (h, z) with z kept as sample indices plus probabilities, and the linear layer
that reads it.

A straight-through one-hot sample z = onehot + probs - sg(probs) has the value of the one-hot
and the gradient of the probabilities. A linear layer applied to it therefore only needs to sum
`stoch` rows of its weight table in the forward pass (an embedding-bag, ~30x fewer operations
than the dense matmul over stoch*classes inputs), while the backward pass sends the dense
gradient to the probabilities, exactly as the dense formulation does. No one-hot tensor is
built in the hot loops.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from . import native
from .distributions import straight_through
from .nets import NormLayer, init_linear_

# Above this many repeated gradient elements, table_gradient loops over latents instead.
_REPEAT_MAX_ELEMENTS = 1 << 18
# Up to this many rows, OneHotLinear uses a dense one-hot matmul instead of the embedding-bag.
DENSE_MAX_ROWS = 64


class Latent(NamedTuple):
    """Model state of any leading shape: h (..., deter), index (..., stoch) flat indices
    latent * classes + class of the sampled classes, and probs (..., stoch, classes), the
    straight-through gradient path of the sample, or None for states without gradient history
    (saves storing large probability tensors nobody differentiates)."""

    h: Tensor
    index: Tensor
    probs: Tensor | None

    def dense(self, classes: int | None = None) -> Tensor:
        """concat(h, one-hot z) (..., deter + stoch * classes), straight-through if probs exist."""
        classes = self.probs.shape[-1] if self.probs is not None else classes
        if classes is None:
            raise ValueError("dense() of a state without probs needs the number of classes")
        local = self.index - torch.arange(self.index.shape[-1], device=self.index.device) * classes
        onehot = F.one_hot(local, classes).to(self.h.dtype)
        if self.probs is not None:
            onehot = straight_through(onehot, self.probs)
        return torch.cat((self.h, onehot.flatten(-2)), -1)

    def reshape(self, *shape: int) -> Latent:
        """Same state with leading shape `shape`."""
        return Latent(
            self.h.reshape(*shape, self.h.shape[-1]),
            self.index.reshape(*shape, self.index.shape[-1]),
            None if self.probs is None else self.probs.reshape(*shape, *self.probs.shape[-2:]),
        )

    def detach(self) -> Latent:
        """Same state without gradient history (and without probs)."""
        return Latent(self.h.detach(), self.index, None)

    def select(self, key: int | slice | Tensor) -> Latent:
        """Index the leading axis."""
        return Latent(self.h[key], self.index[key], None if self.probs is None else self.probs[key])

    @staticmethod
    def stack(states: list[Latent], dim: int = 0) -> Latent:
        """Stack states along a new leading-side axis."""
        probs = None if any(s.probs is None for s in states) else torch.stack([s.probs for s in states], dim)
        return Latent(torch.stack([s.h for s in states], dim), torch.stack([s.index for s in states], dim), probs)

    @staticmethod
    def cat(states: list[Latent]) -> Latent:
        """Concatenate states along the first axis."""
        probs = None if any(s.probs is None for s in states) else torch.cat([s.probs for s in states])
        return Latent(torch.cat([s.h for s in states]), torch.cat([s.index for s in states]), probs)

    @staticmethod
    def where(condition: Tensor, a: Latent, b: Latent) -> Latent:
        """Per-row choice between two states with probs; condition (N,) bool."""
        c = condition.reshape(-1, 1)
        return Latent(
            torch.where(c, a.h, b.h),
            torch.where(c, a.index, b.index),
            torch.where(c.unsqueeze(-1), a.probs, b.probs),
        )


class _OneHotMatmul(torch.autograd.Function):
    """out = onehot(index) @ joined, where `joined` is the detached column-concatenation of
    `tables`: the forward is one embedding-bag, the gradient of the one-hot goes to `probs`
    through one matmul, and each table that needs one gets its own gradient. The first
    `stopped` columns read the one-hot through a stop-gradient: their gradient reaches their
    tables only, never `probs` (they are left out of the backward matmul)."""

    @staticmethod
    def forward(ctx, index: Tensor, probs: Tensor, joined: Tensor, stopped: int, *tables: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(index, joined)
        ctx.sizes = [table.shape[1] for table in tables]
        ctx.probs_dtype = probs.dtype
        ctx.stopped = stopped
        return F.embedding_bag(index, joined, mode="sum")

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        index, joined = ctx.saved_tensors
        grad = grad.to(joined.dtype)
        grad_probs = None
        if ctx.needs_input_grad[1]:
            s = ctx.stopped
            if s >= joined.shape[1]:
                grad_probs = grad.new_zeros(grad.shape[0], joined.shape[0]).to(ctx.probs_dtype)
            else:
                grad_probs = (grad[:, s:] @ joined[:, s:].t()).to(ctx.probs_dtype)
        grad_tables: list[Tensor | None] = []
        for k, piece in enumerate(grad.split(ctx.sizes, 1)):
            grad_tables.append(table_gradient(index, joined.shape[0], piece) if ctx.needs_input_grad[4 + k] else None)
        return (None, grad_probs, None, None, *grad_tables)


class _FirstLayerWeightGradient(torch.autograd.Function):
    """A zero of a first layer's output shape whose backward is the layer's weight gradient on
    detached inputs (h, index). Added to the same layer's output computed with frozen weights
    (e.g. inside the fused imagination readout), it lets one forward pass serve a loss that
    trains the weights and another that trains the inputs (see `LatentMLP.with_weight_gradient`)."""

    @staticmethod
    def forward(ctx, h: Tensor, index: Tensor, dense_weight: Tensor, table: Tensor, dtype: torch.dtype) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(h, index)
        ctx.rows = table.shape[0]
        return h.new_zeros((), dtype=dtype).expand(h.shape[0], dense_weight.shape[0])

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        h, index = ctx.saved_tensors
        grad = grad.float()
        grad_weight = grad.t() @ h.float() if ctx.needs_input_grad[2] else None
        grad_table = table_gradient(index, ctx.rows, grad) if ctx.needs_input_grad[3] else None
        return None, None, grad_weight, grad_table, None


def table_gradient(index: Tensor, rows: int, grad: Tensor) -> Tensor:
    """Gradient of an embedding-bag's table: each row of `grad` (M, out) summed into the `stoch`
    table rows its bag used (index (M, stoch)). On the CPU a compiled kernel (native.py, ~8x
    faster); otherwise small batches use one index_add over repeated rows and large ones one
    index_add per latent, which beat both the embedding-bag backward and a dense one-hot
    matmul on a 2-core AVX-512 CPU."""
    grad, index = grad.float().contiguous(), index.contiguous()
    if native.usable(index, grad):
        return native.table_gradient(index, rows, grad)
    out = torch.zeros(rows, grad.shape[1], dtype=torch.float32, device=grad.device)
    stoch = index.shape[1]
    if grad.numel() * stoch <= _REPEAT_MAX_ELEMENTS:
        return out.index_add_(0, index.reshape(-1), grad.repeat_interleave(stoch, 0))
    for k in range(stoch):
        out.index_add_(0, index[:, k], grad)
    return out


class Readout:
    """First layers of several LatentMLPs (plus the z parts of other OneHotLinears, e.g. the
    RSSM's input layer) evaluated together on the same states: one matmul for all h parts and
    one embedding-bag for all z parts (one backward matmul to the probabilities). Weights are
    joined once at construction, so build one per use (weights change every update).

    `value_only` MLPs are read in a separate pass without gradient: their outputs are used as
    values only (e.g. the continue head's mode), and keeping their columns out of the fused
    layer keeps them out of its backward matmul.

    The first `input_stopped` of `mlps` read the states through a stop-gradient: their outputs
    carry gradient to their own first-layer weights only, never into h or the latent
    probabilities (the actor in imagination, DreamerV3's actor(sg(s)); see `RSSM.imagine`).
    Their z columns stay in the fused forward but out of the backward matmul to the
    probabilities."""

    def __init__(
        self,
        mlps: list[LatentMLP],
        extra_tables: list[Tensor] | None = None,
        value_only: list[LatentMLP] | None = None,
        input_stopped: int = 0,
    ) -> None:
        if not 0 <= input_stopped <= len(mlps):
            raise ValueError(f"input_stopped={input_stopped} outside 0..{len(mlps)}")
        self.count = len(mlps)
        self.stopped_columns = sum(mlp.first.table.shape[1] for mlp in mlps[:input_stopped])
        self.tables = [mlp.first.table for mlp in mlps] + (extra_tables or [])
        self.table_sizes = [table.shape[1] for table in self.tables]
        device = (self.tables or [m.first.table for m in value_only or []])[0].device
        self.joined = _compute_dtype(_join([t.detach() for t in self.tables], 1), device) if self.tables else None
        # The h parts are joined separately for weights that need gradients and those that do
        # not (e.g. the frozen world model's heads in imagination): one joined weight would get
        # a full weight gradient, most of it thrown away.
        # Input-stopped MLPs form their own groups, read from a detached h.
        weights = [mlp.first.dense_weight for mlp in mlps]
        self.groups = []
        for stopped in (True, False):
            for wanted in (True, False):
                members = [
                    k for k, w in enumerate(weights) if w.requires_grad == wanted and (k < input_stopped) == stopped
                ]
                if members:
                    joined = _join([weights[k] for k in members], 0)
                    self.groups.append((members, joined, [weights[k].shape[0] for k in members], stopped))
        self.value_sizes = [mlp.first.table.shape[1] for mlp in value_only or []]
        if value_only:
            with torch.no_grad():
                self.value_table = _compute_dtype(_join([m.first.table for m in value_only], 1), device)
                self.value_weight = _join([m.first.dense_weight for m in value_only], 0)

    def __call__(self, latent: Latent) -> list[Tensor]:
        """Outputs for each MLP's first layer (..., units), then each extra table's z part, then
        each value-only MLP's first layer (without gradient)."""
        lead = latent.index.shape[:-1]
        index = latent.index.reshape(-1, latent.index.shape[-1])
        outputs: list[Tensor] = []
        if self.tables:
            probs = _flat_probs(latent.probs, index)
            sparse = _OneHotMatmul.apply(index, probs, self.joined, self.stopped_columns, *self.tables)
            sparse = sparse.reshape(*lead, sparse.shape[-1]).split(self.table_sizes, -1)
            dense: list[Tensor | None] = [None] * self.count
            for members, weight, sizes, stopped in self.groups:
                h = latent.h.detach() if stopped else latent.h
                for k, part in zip(members, F.linear(h, weight).split(sizes, -1)):
                    dense[k] = part
            outputs = [d + s for d, s in zip(dense, sparse)] + list(sparse[self.count :])
        if self.value_sizes:
            with torch.no_grad():
                values = F.embedding_bag(index, self.value_table, mode="sum").reshape(*lead, -1)
                values = values + F.linear(latent.h, self.value_weight)
            outputs += list(values.split(self.value_sizes, -1))
        return outputs


def _join(tensors: list[Tensor], dim: int) -> Tensor:
    return torch.cat(tensors, dim) if len(tensors) > 1 else tensors[0]


def _flat_probs(probs: Tensor | None, flat_index: Tensor) -> Tensor:
    """Probabilities as (rows, stoch*classes), or an empty stand-in when there are none."""
    if probs is None:
        return flat_index.new_empty((0,), dtype=torch.float32)
    return probs.reshape(flat_index.shape[0], -1)


def _compute_dtype(table: Tensor, device: torch.device) -> Tensor:
    if torch.is_autocast_enabled(device.type):
        return table.to(torch.get_autocast_dtype(device.type))
    return table


class OneHotLinear(nn.Module):
    """Linear layer (no bias) on concat(dense, one-hot z) where z is given as (index, probs).

    The dense part is a normal weight; the one-hot part is a table of stoch*classes rows.
    Initialised like one dense layer of the full input size."""

    def __init__(self, dense_size: int, onehot_size: int, out_size: int) -> None:
        super().__init__()
        fan_in = dense_size + onehot_size
        std = math.sqrt(2.0 / (fan_in + out_size)) / 0.87962566103423978
        self.dense_weight = nn.Parameter(torch.empty(out_size, dense_size))
        self.table = nn.Parameter(torch.empty(onehot_size, out_size))
        for weight in (self.dense_weight, self.table):
            nn.init.trunc_normal_(weight, std=std, a=-2.0 * std, b=2.0 * std)

    def forward(self, dense: Tensor, index: Tensor, probs: Tensor | None) -> Tensor:
        return F.linear(dense, self.dense_weight) + self.onehot_part(index, probs)

    def compute_table(self) -> Tensor:
        """The detached table in the compute dtype, for repeated `onehot_part` calls."""
        return _compute_dtype(self.table.detach(), self.table.device)

    def onehot_part(self, index: Tensor, probs: Tensor | None, table: Tensor | None = None) -> Tensor:
        """The z part of the layer's output; `table` from `compute_table` saves re-casting it."""
        lead = index.shape[:-1]
        flat_index = index.reshape(-1, index.shape[-1])
        if flat_index.shape[0] <= DENSE_MAX_ROWS:
            # Few rows (acting, the autograd filtering loop): the dense straight-through
            # matmul costs less than the custom function's Python forward and backward.
            onehot = torch.zeros(flat_index.shape[0], self.table.shape[0], device=index.device, dtype=self.table.dtype)
            onehot.scatter_(1, flat_index, 1.0)
            if probs is not None:
                onehot = straight_through(onehot, probs.reshape(onehot.shape).to(onehot.dtype))
            return (onehot @ self.table).reshape(*lead, self.table.shape[1])
        joined = self.compute_table() if table is None else table
        sparse = _OneHotMatmul.apply(flat_index, _flat_probs(probs, flat_index), joined, 0, self.table)
        return sparse.reshape(*lead, sparse.shape[-1])


class LatentMLP(nn.Module):
    """DreamerV3 MLP (Linear -> LayerNorm -> SiLU, `layers` times, then a linear output) that
    reads a `Latent`: the first layer is a OneHotLinear over (h, z)."""

    def __init__(
        self,
        deter: int,
        stoch_flat: int,
        units: int,
        layers: int,
        eps: float,
        out_size: int,
        zero_output: bool = False,
    ) -> None:
        super().__init__()
        self.first = OneHotLinear(deter, stoch_flat, units)
        self.first_norm = nn.LayerNorm(units, eps=eps)
        self.hidden = nn.Sequential(*(NormLayer(units, units, eps) for _ in range(layers - 1)))
        self.out = init_linear_(nn.Linear(units, out_size), zero=zero_output)

    def forward(self, latent: Latent) -> Tensor:
        return self.finish(self.first(latent.h, latent.index, latent.probs))

    def finish(self, first_pre: Tensor) -> Tensor:
        """The rest of the MLP from the first layer's linear output."""
        return self.out(self.hidden(F.silu(self.first_norm(first_pre))))

    def with_weight_gradient(self, first_pre: Tensor, latent: Latent) -> Tensor:
        """`first_pre`, this MLP's first-layer output on `latent` computed with the layer frozen,
        made to carry the layer's weight gradient as well: the gradient reaching the result goes
        on to `first_pre`'s inputs (the states) and to the weights, computed as for detached
        states. Callers keep the two apart by differentiating each loss only with respect to its
        own parameters (`torch.autograd.backward(..., inputs=...)`)."""
        zero = _FirstLayerWeightGradient.apply(
            latent.h.detach().reshape(-1, latent.h.shape[-1]),
            latent.index.reshape(-1, latent.index.shape[-1]),
            self.first.dense_weight,
            self.first.table,
            first_pre.dtype,
        )
        return first_pre + zero.reshape(first_pre.shape)


def first_layers(latent: Latent, mlps: list[LatentMLP]) -> list[Tensor]:
    """First-layer outputs of several LatentMLPs on the same states (see `Readout`)."""
    return Readout(mlps)(latent)
