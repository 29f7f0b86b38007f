"""The world model's filtering loop (posterior states of replayed sequences) with a hand-written
backward pass through time.

At the paper's batch of 16 sequences every op of the 64-step loop works on a few kilobytes, so
the loop costs per-op overhead, not arithmetic. With autograd it recorded ~40 nodes per step and
computed each weight's gradient 64 times in small pieces. Here the forward runs without
recording and keeps what the backward needs; the backward walks the steps in reverse computing
only the gradients that flow along the recurrence (deterministic state, latent probabilities),
and each weight's gradient is then one batched op over all steps. The arithmetic is the same as
`RSSM.observe_autograd`, which stays as the reference (and the path under autocast); the tests
compare the two.

One step, rows b, for the previous state (h', z' as index + probs') and the inputs projected for
the whole sequence beforehand (a_t = W_a action_{t-1}, e_t = W_e embed_t):

    x   = silu(LN_in(table[z'] summed + a_t))              RSSM input layer on (z', action)
    h   = LN-GRU(x, h')                                     sigmoid reset, tanh candidate, update bias -1
    l   = W_post silu(LN_o(W_h h + e_t)) + b_post           posterior logits
    p   = (1 - unimix) softmax(l) + unimix / classes        z sampled from p (straight-through)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from . import native
from .distributions import unimix_probs_backward, unimix_sample
from .latent import table_gradient

_nlb = torch.ops.aten.native_layer_norm_backward
_INPUT_ONLY = [True, False, False]
_PARAMS_ONLY = [False, True, True]


@dataclass
class FilterSetup:
    """What the loop needs besides differentiable tensors."""

    is_first: Tensor  # (B, T) bool: the state is reset to the initial one before the step
    initial_index: Tensor  # (stoch,) flat sample indices of the initial state
    uniform: Tensor  # (T, B, stoch, 1) random numbers for the samples
    offsets: Tensor  # (stoch,) = arange(stoch) * classes
    stoch: int
    classes: int
    unimix: float
    eps: float  # LayerNorm epsilon (all three norms)


class _Filter(torch.autograd.Function):
    @staticmethod
    def forward(  # type: ignore[override]
        ctx,
        setup: FilterSetup,
        initial_h: Tensor,  # (D,)
        action_pre: Tensor,  # (B, T, U)
        embed_pre: Tensor,  # (B, T, U)
        table: Tensor,  # (stoch * classes, U) input layer's z part
        w_in: Tensor,
        b_in: Tensor,  # input LayerNorm (U,)
        w_gru: Tensor,  # (3D, U + D)
        w_g: Tensor,
        b_g: Tensor,  # GRU LayerNorm (3D,)
        w_obs_h: Tensor,  # (U, D) posterior layer's h part
        w_o: Tensor,
        b_o: Tensor,  # posterior LayerNorm (U,)
        w_post: Tensor,  # (stoch * classes, U)
        b_post: Tensor,  # (stoch * classes,)
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        s = setup
        batch, length, units = action_pre.shape
        deter = initial_h.shape[0]
        resets = s.is_first.any(0).tolist()
        h_prev = initial_h.expand(batch, deter).contiguous()
        index_prev = s.initial_index.expand(batch, s.stoch)
        saved: list[list[Tensor]] = []
        hs, indices, probs_list, logits_list = [], [], [], []
        for t in range(length):
            if t > 0 and resets[t]:
                first = s.is_first[:, t : t + 1]
                h_prev = torch.where(first, initial_h, h_prev)
                index_prev = torch.where(first, s.initial_index, index_prev)
            a = F.embedding_bag(index_prev, table, mode="sum") + action_pre[:, t]
            u, mean_in, rstd_in = torch.native_layer_norm(a, (units,), w_in, b_in, s.eps)
            x = F.silu(u)
            joined = torch.cat((x, h_prev), -1)
            p = F.linear(joined, w_gru)
            h, mean_g, rstd_g = _gru(p, h_prev, w_g, b_g, s.eps)
            o = F.linear(h, w_obs_h) + embed_pre[:, t]
            v, mean_o, rstd_o = torch.native_layer_norm(o, (units,), w_o, b_o, s.eps)
            w = F.silu(v)
            logits = F.linear(w, w_post, b_post).view(batch, s.stoch, s.classes)
            probs, index = unimix_sample(logits, s.uniform[t], s.unimix, s.offsets)
            saved.append([index_prev, a, mean_in, rstd_in, u, joined, p, mean_g, rstd_g, h_prev, h, o, mean_o,
                          rstd_o, v, w, probs])
            hs.append(h)
            indices.append(index)
            probs_list.append(probs)
            logits_list.append(logits)
            h_prev, index_prev = h, index
        ctx.setup = s
        ctx.saved = saved
        ctx.resets = resets
        ctx.save_for_backward(table, w_in, b_in, w_gru, w_g, b_g, w_obs_h, w_o, b_o, w_post, b_post)
        index_out = torch.stack(indices, 1)
        ctx.mark_non_differentiable(index_out)
        return torch.stack(hs, 1), index_out, torch.stack(probs_list, 1), torch.stack(logits_list, 1)

    @staticmethod
    def backward(ctx, g_h, _g_index, g_probs, g_logits):  # type: ignore[override]
        s: FilterSetup = ctx.setup
        table, w_in, b_in, w_gru, w_g, b_g, w_obs_h, w_o, b_o, w_post, b_post = ctx.saved_tensors
        saved = ctx.saved
        length = len(saved)
        batch, units = saved[0][1].shape
        deter = w_obs_h.shape[1]
        flat = s.stoch * s.classes
        time_major = [None if g is None else g.transpose(0, 1) for g in (g_h, g_probs, g_logits)]
        g_h, g_probs, g_logits = time_major
        dh_next = None  # gradient reaching h_t from step t + 1
        dprobs_next = None  # gradient reaching probs_t from step t + 1's input layer
        d_initial = torch.zeros_like(saved[0][10][0])
        grads: list[list[Tensor]] = [[] for _ in range(7)]  # dlogits, dv, do, dq, dp, du, da per step
        for t in range(length - 1, -1, -1):
            (index_prev, a, mean_in, rstd_in, u, joined, p, mean_g, rstd_g, h_prev, h, o, mean_o,
             rstd_o, v, w, probs) = saved[t]
            dprobs = _add(None if g_probs is None else g_probs[t], dprobs_next)
            if dprobs is not None:
                dlogits = unimix_probs_backward(probs, dprobs.contiguous(), s.unimix)
                dlogits = _add(dlogits, None if g_logits is None else g_logits[t]).reshape(batch, flat)
            elif g_logits is not None:
                dlogits = g_logits[t].reshape(batch, flat)
            else:
                dlogits = probs.new_zeros(batch, flat)
            dv = torch.ops.aten.silu_backward(dlogits @ w_post, v)
            do = _nlb(dv, o, (units,), mean_o, rstd_o, w_o, b_o, _INPUT_ONLY)[0]
            dh = _add(_add(None if g_h is None else g_h[t], dh_next), do @ w_obs_h)
            dp, dh_prev, dq = _gru_backward(p, h_prev, w_g, b_g, mean_g, rstd_g, dh.contiguous())
            djoined = dp @ w_gru
            dh_prev = dh_prev + djoined[:, units:]
            du = torch.ops.aten.silu_backward(djoined[:, :units], u)
            da = _nlb(du, a, (units,), mean_in, rstd_in, w_in, b_in, _INPUT_ONLY)[0]
            dprobs_prev = (da @ table.t()).view(batch, s.stoch, s.classes)
            if t == 0 or ctx.resets[t]:  # rows that started from the initial state
                first = torch.ones(batch, 1, dtype=torch.bool, device=da.device) if t == 0 else s.is_first[:, t : t + 1]
                d_initial = d_initial + dh_prev.masked_fill(~first, 0.0).sum(0)
                dh_prev = dh_prev.masked_fill(first, 0.0)
                dprobs_prev = dprobs_prev.masked_fill(first.unsqueeze(-1), 0.0)
            dh_next, dprobs_next = dh_prev, dprobs_prev
            for bucket, g in zip(grads, (dlogits, dv, do, dq, dp, du, da)):
                bucket.append(g)
        for bucket in grads:
            bucket.reverse()
        dlogits, dv, do, dq, dp, du, da = (torch.cat(bucket) for bucket in grads)

        def cat(k: int) -> Tensor:
            return torch.cat([step[k] for step in saved])

        need = ctx.needs_input_grad
        d_table = table_gradient(cat(0), table.shape[0], da) if need[4] else None
        _, d_w_in, d_b_in = _nlb(du, cat(1), (units,), cat(2), cat(3), w_in, b_in, _PARAMS_ONLY)
        d_w_gru = dp.t() @ cat(5) if need[7] else None
        _, d_w_g, d_b_g = _nlb(dq, cat(6), (3 * deter,), cat(7), cat(8), w_g, b_g, _PARAMS_ONLY)
        d_w_obs_h = do.t() @ cat(10) if need[10] else None
        _, d_w_o, d_b_o = _nlb(dv, cat(11), (units,), cat(12), cat(13), w_o, b_o, _PARAMS_ONLY)
        d_w_post = dlogits.t() @ cat(15) if need[13] else None
        d_b_post = dlogits.sum(0) if need[14] else None
        d_action = da.view(length, batch, units).transpose(0, 1) if need[2] else None
        d_embed = do.view(length, batch, units).transpose(0, 1) if need[3] else None
        return (None, d_initial if need[1] else None, d_action, d_embed, d_table, d_w_in, d_b_in,
                d_w_gru, d_w_g, d_b_g, d_w_obs_h, d_w_o, d_b_o, d_w_post, d_b_post)


def _gru(p: Tensor, h_prev: Tensor, weight: Tensor, bias: Tensor, eps: float) -> tuple[Tensor, Tensor, Tensor]:
    """The LayerNorm GRU cell after its matmul (as `RSSM.gru`): h and the norm's mean and rstd."""
    if native.usable(p, h_prev, weight, bias):
        return native.ln_gru(p, h_prev, weight, bias, eps)
    q, mean, rstd = torch.native_layer_norm(p, (p.shape[-1],), weight, bias, eps)
    reset, cand, update = q.chunk(3, -1)
    new = torch.tanh(torch.sigmoid(reset) * cand)
    return torch.lerp(h_prev, new, torch.sigmoid(update - 1.0)), mean, rstd


def _gru_backward(
    p: Tensor, h_prev: Tensor, weight: Tensor, bias: Tensor, mean: Tensor, rstd: Tensor, dh: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Gradients of `_gru`'s p and h_prev given dh, and of the norm's output (for the norm's
    weight and bias). The gates are recomputed from p."""
    if native.usable(p, h_prev, weight, bias, dh):
        return native.ln_gru_backward(p, h_prev, weight, bias, mean, rstd, dh, True)  # type: ignore[return-value]
    q = (p - mean) * rstd * weight + bias
    reset, cand, update = q.chunk(3, -1)
    reset, update = torch.sigmoid(reset), torch.sigmoid(update - 1.0)
    new = torch.tanh(reset * cand)
    dnew = dh * update
    dpre = torch.ops.aten.tanh_backward(dnew, new)
    dq = torch.cat(
        (
            torch.ops.aten.sigmoid_backward(dpre * cand, reset),
            dpre * reset,
            torch.ops.aten.sigmoid_backward(dh * (new - h_prev), update),
        ),
        -1,
    )
    dp = _nlb(dq, p, (p.shape[-1],), mean, rstd, weight, bias, _INPUT_ONLY)[0]
    return dp, dh - dnew, dq


def _add(a: Tensor | None, b: Tensor | None) -> Tensor | None:
    if a is None:
        return b
    if b is None:
        return a
    return a + b


def filter_sequences(
    setup: FilterSetup,
    initial_h: Tensor,
    action_pre: Tensor,
    embed_pre: Tensor,
    table: Tensor,
    input_norm: torch.nn.LayerNorm,
    gru_weight: Tensor,
    gru_norm: torch.nn.LayerNorm,
    obs_h_weight: Tensor,
    obs_norm: torch.nn.LayerNorm,
    post_head: torch.nn.Linear,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Posterior states of whole sequences: h (B, T, D), sample indices (B, T, stoch), probs and
    logits (B, T, stoch, classes); differentiable in every tensor argument (see module docstring)."""
    return _Filter.apply(
        setup, initial_h, action_pre, embed_pre, table,
        input_norm.weight, input_norm.bias, gru_weight, gru_norm.weight, gru_norm.bias,
        obs_h_weight, obs_norm.weight, obs_norm.bias, post_head.weight, post_head.bias,
    )
