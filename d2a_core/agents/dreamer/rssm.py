"""Recurrent state-space model (DreamerV3): a LayerNorm GRU deterministic state `h` and a
stochastic state `z` of `stoch` categoricals with `classes` classes each (1 % unimix,
straight-through samples).

Speed notes: z is carried as sample indices plus probabilities (see `latent.py`); inputs that
do not depend on the recurrence (observation embeddings) are projected for the whole sequence
in one matmul before the time loop; random numbers are drawn once per call.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .config import DreamerConfig
from . import native
from .distributions import unimix_probs, unimix_sample
from .filtering import FilterSetup, filter_sequences
from .latent import Latent, LatentMLP, OneHotLinear, Readout
from .nets import NormLayer, init_linear_

ImaginationPolicy = Callable[[Latent, Tensor | None], tuple[Tensor, dict[str, Tensor]]]
"""Maps a state of leading shape (N,) and the first-layer output of the policy's MLP at that
state (None unless `RSSM.imagine` was given the MLP; computed on the stop-gradient state) to
(action (N, A), extras to stack over time). A policy that reads the state itself should read
`latent.detach()` (actor(sg(s)))."""


@dataclass
class Observed:
    """Result of filtering a batch of sequences: posterior states and both sets of logits."""

    latent: Latent  # leading shape (B, T)
    post_logits: Tensor  # (B, T, stoch, classes)
    prior_logits: Tensor  # (B, T, stoch, classes)


@dataclass
class Imagined:
    """A rollout of the prior: H+1 states (the start included), H actions and policy extras.
    States and readouts stay per step (not stacked): stacked tensors of this size would
    exceed the allocator's mmap threshold and pay page faults on every use (see behavior.py)."""

    states: list[Latent]  # H+1 states of leading shape (N,)
    actions: Tensor  # (H, N, A)
    extras: dict[str, Tensor]  # each (H, N, ...)
    readouts: list[list[Tensor]]  # per state: first-layer outputs (N, units) of the readouts, then the value readouts

    @property
    def latent(self) -> Latent:
        """All states stacked, leading shape (H+1, N)."""
        return Latent.stack(self.states)


class RSSM(nn.Module):
    """Sequence model h_t = f(h_{t-1}, z_{t-1}, a_{t-1}), prior p(z_t | h_t), posterior q(z_t | h_t, x_t)."""

    def __init__(self, config: DreamerConfig, embed_size: int, action_size: int) -> None:
        super().__init__()
        c = config
        self.stoch, self.classes, self.deter, self.unimix = c.stoch, c.classes, c.deter, c.unimix
        self.img_in = OneHotLinear(action_size, c.stoch_flat, c.units)
        self.img_in_norm = nn.LayerNorm(c.units, eps=c.norm_eps)
        self.gru_linear = init_linear_(nn.Linear(c.units + c.deter, 3 * c.deter, bias=False))
        self.gru_norm = nn.LayerNorm(3 * c.deter, eps=c.norm_eps)
        self.img_out = NormLayer(c.deter, c.units, c.norm_eps)
        self.prior_head = init_linear_(nn.Linear(c.units, c.stoch_flat))
        self.obs_out = NormLayer(c.deter + embed_size, c.units, c.norm_eps)
        self.post_head = init_linear_(nn.Linear(c.units, c.stoch_flat))
        # tanh(0) = 0: a learned initial state starts where a zero state would.
        self.initial_deter = nn.Parameter(torch.zeros(c.deter), requires_grad=c.learned_initial_state)
        self.register_buffer("offsets", torch.arange(c.stoch) * c.classes, persistent=False)

    # --- pieces

    def initial(self, batch_size: int) -> Latent:
        """Initial state: h = tanh(learned vector), z = mode of the prior at h (no gradient)."""
        h = torch.tanh(self.initial_deter).unsqueeze(0)
        probs = unimix_probs(self.prior_logits(h), self.unimix).detach()
        index = probs.argmax(-1) + self.offsets
        return Latent(
            h.expand(batch_size, -1), index.expand(batch_size, -1), probs.expand(batch_size, -1, -1)
        )

    def gru(self, x: Tensor, h: Tensor) -> Tensor:
        """LayerNorm GRU cell with DreamerV3's update-gate bias of -1 (favours keeping h); after
        its matmul, one compiled kernel on the CPU (native.py)."""
        p = F.linear(torch.cat((x, h), -1), self.gru_linear.weight)
        norm = self.gru_norm
        if native.usable(p, h, norm.weight, norm.bias):
            return native.LnGru.apply(p, h, norm.weight, norm.bias, norm.eps)
        reset, cand, update = norm(p).to(h.dtype).chunk(3, -1)
        cand = torch.tanh(torch.sigmoid(reset) * cand)
        update = torch.sigmoid(update - 1.0)
        return torch.lerp(h, cand, update)

    def step(
        self, prev: Latent, action: Tensor, z_part: Tensor | None = None, action_part: Tensor | None = None
    ) -> Tensor:
        """Next deterministic state from the previous state and the action taken there.
        `z_part` / `action_part` are the input layer's outputs for prev's z / the action when
        already computed (fused readout, whole-sequence action projection)."""
        if z_part is None:
            z_part = self.img_in.onehot_part(prev.index, prev.probs)
        if action_part is None:
            action_part = F.linear(action, self.img_in.dense_weight)
        return self.gru(F.silu(self.img_in_norm(z_part + action_part)), prev.h)

    def prior_logits(self, h: Tensor) -> Tensor:
        """Prior logits (..., stoch, classes) from the deterministic state."""
        return self.prior_head(self.img_out(h)).unflatten(-1, (self.stoch, self.classes))

    def posterior_logits(self, h: Tensor, embed: Tensor) -> Tensor:
        """Posterior logits (..., stoch, classes) from h and the observation embedding."""
        logits = self.post_head(self.obs_out(torch.cat((h, embed), -1)))
        return logits.unflatten(-1, (self.stoch, self.classes))

    def sample(self, h: Tensor, logits: Tensor, uniform: Tensor) -> Latent:
        """State with z sampled (straight-through) from `logits`."""
        probs, index = unimix_sample(logits.float(), uniform, self.unimix, self.offsets)
        return Latent(h, index, probs)

    def sample_prior(self, h: Tensor, uniform: Tensor) -> Latent:
        """State with z sampled from the prior at h (the prior head's bias is added by the
        sampling kernel, which saves a pass over the logits)."""
        logits = F.linear(self.img_out(h), self.prior_head.weight).unflatten(-1, (self.stoch, self.classes))
        bias = self.prior_head.bias.view(self.stoch, self.classes)
        probs, index = unimix_sample(logits.float(), uniform, self.unimix, self.offsets, bias.float())
        return Latent(h, index, probs)

    def uniform(self, shape: tuple[int, ...], generator: torch.Generator | None, device: torch.device) -> Tensor:
        """Random numbers for sampling states of leading shape `shape`."""
        return torch.rand((*shape, self.stoch, 1), generator=generator, device=device)

    # --- sequences

    def observe(self, embed: Tensor, prev_actions: Tensor, is_first: Tensor, generator: torch.Generator | None) -> Observed:
        """Filter sequences: embed (B, T, E), prev_actions (B, T, A) (the action before each
        observation), is_first (B, T) bool. Where is_first, the state and previous action are
        reset to the initial state and zero before the step.

        In float32 the loop runs with a hand-written backward pass (`filtering.py`); under
        autocast it runs with autograd (`observe_autograd`, the reference). Both draw the same
        random numbers."""
        if torch.is_autocast_enabled(embed.device.type) or embed.dtype != torch.float32:
            return self.observe_autograd(embed, prev_actions, is_first, generator)
        batch, length = embed.shape[:2]
        prev_actions = prev_actions.masked_fill(is_first.unsqueeze(-1), 0.0)
        w_obs = self.obs_out.linear.weight
        uniform = self.uniform((length, batch), generator, embed.device)
        setup = FilterSetup(
            is_first=is_first,
            initial_index=self.initial(1).index[0],
            uniform=uniform,
            offsets=self.offsets,
            stoch=self.stoch,
            classes=self.classes,
            unimix=self.unimix,
            eps=self.img_in_norm.eps,
        )
        h, index, probs, logits = filter_sequences(
            setup,
            torch.tanh(self.initial_deter),
            F.linear(prev_actions, self.img_in.dense_weight),
            F.linear(embed, w_obs[:, self.deter :]),
            self.img_in.table,
            self.img_in_norm,
            self.gru_linear.weight,
            self.gru_norm,
            w_obs[:, : self.deter],
            self.obs_out.norm,
            self.post_head,
        )
        return Observed(latent=Latent(h, index, probs), post_logits=logits, prior_logits=self.prior_logits(h))

    def observe_autograd(
        self, embed: Tensor, prev_actions: Tensor, is_first: Tensor, generator: torch.Generator | None
    ) -> Observed:
        """`observe` step by step with autograd: the reference for the hand-written backward
        pass, and the path under autocast."""
        batch, length = embed.shape[:2]
        initial = self.initial(batch)
        latent = initial
        prev_actions = prev_actions.masked_fill(is_first.unsqueeze(-1), 0.0)
        action_pre = F.linear(prev_actions, self.img_in.dense_weight)
        table = self.img_in.compute_table()
        w_obs = self.obs_out.linear.weight
        embed_pre = F.linear(embed, w_obs[:, self.deter :])
        w_obs_h = w_obs[:, : self.deter]
        uniform = self.uniform((length, batch), generator, embed.device)
        resets = is_first.any(0).tolist()
        states, logits_list = [], []
        for t in range(length):
            if resets[t]:
                latent = Latent.where(is_first[:, t], initial, latent)
            z_part = self.img_in.onehot_part(latent.index, latent.probs, table)
            h = self.step(latent, prev_actions[:, t], z_part, action_pre[:, t])
            hidden = self.obs_out.forward_preactivation(F.linear(h, w_obs_h) + embed_pre[:, t])
            logits = self.post_head(hidden).unflatten(-1, (self.stoch, self.classes))
            latent = self.sample(h, logits, uniform[t])
            states.append(latent)
            logits_list.append(logits)
        stacked = Latent.stack(states, 1)
        return Observed(
            latent=stacked,
            post_logits=torch.stack(logits_list, 1),
            prior_logits=self.prior_logits(stacked.h),
        )

    def imagine(
        self,
        policy: ImaginationPolicy,
        start: Latent,
        horizon: int,
        generator: torch.Generator | None,
        policy_readout: LatentMLP | None = None,
        readouts: list[LatentMLP] | None = None,
        value_readouts: list[LatentMLP] | None = None,
    ) -> Imagined:
        """Roll the prior forward `horizon` steps from `start` (leading shape (N,)) with actions
        from `policy`. Gradients flow through states, straight-through samples and actions,
        except into the policy's input: the policy reads each state through a stop-gradient
        (DreamerV3's actor(sg(s))), so `policy_readout`'s first layer sends gradient to its own
        weights only, and a `policy` that reads the state itself must detach it.

        MLPs that read imagined states have their first layers evaluated inside the loop, fused
        with each other and with the RSSM's input layer (one matmul per state for all of them,
        forward and backward, on tensors that stay in cache): `policy_readout` (the actor's MLP,
        read at states 0..H-1 and handed to `policy`), `readouts` (read at every state with
        gradient, e.g. reward and critic) and `value_readouts` (read at every state without
        gradient, e.g. the continue head's mode). The last two are returned per state for the
        caller to finish the MLPs."""
        readouts, value_readouts = readouts or [], value_readouts or []
        fused_mlps = ([policy_readout] if policy_readout is not None else []) + readouts
        # The actor reads the state through a stop-gradient, as in DreamerV1-V3 (actor(sg(s))):
        # without it the actor's objective would also differentiate through its own inputs at
        # every later step, moving h and the latent probabilities to change later actions. The
        # returns still reach each action through the dynamics (later states, rewards, values).
        stopped = 1 if policy_readout is not None else 0
        fused = Readout(fused_mlps, [self.img_in.table], value_readouts, input_stopped=stopped) if fused_mlps else None
        last = Readout(readouts, None, value_readouts) if readouts or value_readouts else None
        skip = len(fused_mlps) - len(readouts)  # the policy's output is not a returned readout
        uniform = self.uniform((horizon, start.h.shape[0]), generator, start.h.device)
        latent = start
        states, actions, extras, pres = [start], [], [], []
        for t in range(horizon):
            z_part, policy_pre = None, None
            if fused is not None:
                outs = fused(latent)
                z_part = outs[len(fused_mlps)]
                policy_pre = outs[0] if skip else None
                pres.append(outs[skip : len(fused_mlps)] + outs[len(fused_mlps) + 1 :])
            elif last is not None:
                pres.append(last(latent))
            action, extra = policy(latent, policy_pre)
            h = self.step(latent, action, z_part)
            latent = self.sample_prior(h, uniform[t])
            states.append(latent)
            actions.append(action)
            extras.append(extra)
        if last is not None:
            pres.append(last(latent))
        stacked_extras = {key: torch.stack([e[key] for e in extras]) for key in (extras[0] if extras else {})}
        return Imagined(states=states, actions=torch.stack(actions), extras=stacked_extras, readouts=pres)
