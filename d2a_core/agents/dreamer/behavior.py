"""DreamerV3 actor-critic learned in imagination: lambda-returns over the imagined horizon from
replayed posterior states, percentile return normalisation, a two-hot critic regularised toward
its slow EMA copy, and an actor trained by backprop through the dynamics (continuous actions,
as DreamerV3's 2023 release) or REINFORCE (discrete actions), with an entropy bonus. REINFORCE for
continuous actions (DreamerV3's 2024 release) was measured and not kept: docs/benchmarks.md,
"Continuous actor gradient"."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .config import DreamerConfig
from .distributions import (
    TwoHot,
    bounded_normal_params,
    bounded_normal_sample,
    categorical_entropy,
    normal_entropy,
    sample_onehot,
    unimix_probs,
)
from .heads import latent_mlp
from .latent import Latent, Readout
from .nets import ema_update_
from .rssm import Imagined
from .world_model import WorldModel


# Time steps of imagined states are processed in groups whose largest activation stays below
# this many bytes (at 128 units the whole horizon is one group; at 512 units, two). Fewer groups
# mean fewer, larger ops; the bound keeps each tensor below glibc's mmap threshold (32 MiB, see
# d2a_core/training/allocator.py), above which every allocation would map and fault fresh pages.
CHUNK_BYTES = 16 << 20


def lambda_returns(rewards: Tensor, discounts: Tensor, values: Tensor, lam: float) -> Tensor:
    """TD(lambda) returns R_t = r_{t+1} + d_{t+1} ((1 - lam) v_{t+1} + lam R_{t+1}), R_H = v_H.

    rewards (H, N) and discounts (H, N) belong to the states after each step (r_{t+1}, d_{t+1} =
    discount * continue_{t+1}), values (H+1, N) to all states. Returns R_0 .. R_{H-1} (H, N)."""
    bootstrap = rewards + discounts * (1.0 - lam) * values[1:]
    scaled = discounts * lam
    ret = values[-1]
    out = []
    for t in range(rewards.shape[0] - 1, -1, -1):
        ret = bootstrap[t] + scaled[t] * ret
        out.append(ret)
    out.reverse()
    return torch.stack(out)


def percentiles(values: Tensor, quantiles: tuple[float, float]) -> tuple[Tensor, Tensor]:
    """Linearly interpolated quantiles of a 1-D tensor (as torch.quantile, which was much
    slower here inside the training step)."""
    ordered = values.sort().values
    out = []
    for q in quantiles:
        position = q * (ordered.numel() - 1)
        lower = int(position)
        upper = min(lower + 1, ordered.numel() - 1)
        out.append(torch.lerp(ordered[lower], ordered[upper], position - lower))
    return out[0], out[1]


class ReturnNormalizer(nn.Module):
    """EMA of the 5th and 95th return percentiles; returns are divided by max(limit, hi - lo).

    The first batch sets the statistics directly (no bias toward an arbitrary zero start). The
    scale is only > 1 when the return range exceeds `limit`, so small returns are not amplified.
    """

    def __init__(self, decay: float, low_percent: float, high_percent: float, limit: float) -> None:
        super().__init__()
        self.decay, self.limit = decay, limit
        self.quantiles = (low_percent / 100.0, high_percent / 100.0)
        self.register_buffer("low", torch.zeros(()))
        self.register_buffer("high", torch.zeros(()))
        self.register_buffer("initialized", torch.zeros((), dtype=torch.bool))

    def candidate(self, returns: Tensor) -> tuple[Tensor, Tensor]:
        """Statistics after seeing `returns` (not stored until `commit`)."""
        low, high = percentiles(returns.detach().float().flatten(), self.quantiles)
        if bool(self.initialized):
            low = self.decay * self.low + (1.0 - self.decay) * low
            high = self.decay * self.high + (1.0 - self.decay) * high
        return low, high

    def commit(self, low: Tensor, high: Tensor) -> None:
        """Store statistics produced by `candidate`."""
        self.low.copy_(low)
        self.high.copy_(high)
        self.initialized.fill_(True)

    def scale(self, low: Tensor, high: Tensor) -> Tensor:
        """Divisor of returns and advantages: max(limit, high - low)."""
        return torch.clamp(high - low, min=self.limit)


@contextmanager
def frozen(*modules: nn.Module) -> Iterator[None]:
    """Stop gradients into modules' parameters (gradients still flow through their ops), so
    backprop through the dynamics computes no weight gradients the actor does not use."""
    params = [p for module in modules for p in module.parameters() if p.requires_grad]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


@dataclass
class BehaviorOutput:
    """Losses of one behaviour update and what must be committed if they are finite."""

    actor_loss: Tensor
    critic_loss: Tensor
    metrics: dict[str, Tensor]
    norm_low: Tensor
    norm_high: Tensor


class Actor(nn.Module):
    """pi(a | s): bounded normal over [-1, 1]^A (continuous) or unimix categorical (discrete)."""

    def __init__(self, action_size: int, discrete: bool, config: DreamerConfig) -> None:
        super().__init__()
        self.discrete = discrete
        self.config = config
        self.action_size = action_size
        # Zero output layer: the untrained policy is centred (mean 0, wide std). A random
        # initial mean bias (e.g. steering hard one way) otherwise fills the first replay with
        # one kind of failure that the agent can then lock onto.
        self.net = latent_mlp(config, action_size if discrete else 2 * action_size, zero_output=True)

    def sample(self, feat: Latent, noise: Tensor) -> tuple[Tensor, Tensor]:
        """Action and entropy. `noise` is N(0, 1) of shape (..., A) for continuous actions and
        U[0, 1) of shape (..., 1) for discrete ones (whose actions are one-hot, no gradient)."""
        return self.sample_from_output(self.net(feat), noise)

    def sample_from_output(self, raw: Tensor, noise: Tensor) -> tuple[Tensor, Tensor]:
        """`sample` given the network's output."""
        if self.discrete:
            probs = unimix_probs(raw, self.config.unimix)
            return sample_onehot(probs, noise), categorical_entropy(probs)
        mean, std = bounded_normal_params(raw, self.config.actor_min_std, self.config.actor_max_std)
        return bounded_normal_sample(mean, std, noise), normal_entropy(std)

    def mode(self, feat: Latent) -> Tensor:
        """Most likely action (one-hot for discrete actions)."""
        raw = self.net(feat)
        if self.discrete:
            return torch.nn.functional.one_hot(raw.argmax(-1), raw.shape[-1]).float()
        mean, _ = bounded_normal_params(raw, self.config.actor_min_std, self.config.actor_max_std)
        return mean

    def log_prob_entropy(self, feat: Latent, action: Tensor) -> tuple[Tensor, Tensor]:
        """log pi(a | s) of one-hot actions and the entropy (discrete actions: REINFORCE)."""
        probs = unimix_probs(self.net(feat), self.config.unimix)
        return torch.log((probs * action).sum(-1)), categorical_entropy(probs)

    @property
    def reinforce(self) -> bool:
        """Whether the actor learns by REINFORCE (discrete actions) or by backprop through the
        dynamics (continuous ones)."""
        return self.discrete

    def noise(self, shape: tuple[int, ...], generator: torch.Generator | None, device: torch.device) -> Tensor:
        """Random numbers `sample` needs for a batch of leading shape `shape`."""
        if self.discrete:
            return torch.rand((*shape, 1), generator=generator, device=device)
        return torch.randn((*shape, self.action_size), generator=generator, device=device)


class Behavior(nn.Module):
    """Actor, critic, slow critic and return normaliser, with the imagination losses."""

    def __init__(self, action_size: int, discrete: bool, config: DreamerConfig) -> None:
        super().__init__()
        c = config
        self.config = c
        self.actor = Actor(action_size, discrete, c)
        self.critic = latent_mlp(c, c.bins, zero_output=True)
        self.slow_critic = copy.deepcopy(self.critic).requires_grad_(False)
        self.return_norm = ReturnNormalizer(
            c.return_norm_decay, c.return_norm_low, c.return_norm_high, c.return_norm_limit
        )
        self.twohot = TwoHot(c.bins, c.bin_range)

    def _apply(self, fn, recurse=True):  # keep the two-hot bins on the module's device
        result = super()._apply(fn, recurse)
        self.twohot = self.twohot.to(self.critic.out.weight.device)
        return result

    def _chunks(self, steps: int, rows_per_step: int) -> list[slice]:
        """Groups of consecutive time steps whose activations stay below `CHUNK_BYTES`."""
        c = self.config
        row_bytes = 4 * max(c.units, c.deter, c.bins)
        per_chunk = max(1, CHUNK_BYTES // (row_bytes * rows_per_step))
        return [slice(t, min(t + per_chunk, steps)) for t in range(0, steps, per_chunk)]

    def update_slow_critic(self) -> None:
        """One EMA step of the slow critic toward the critic."""
        ema_update_(self.slow_critic, self.critic, self.config.slow_critic_fraction)

    def _imagine(
        self, world_model: WorldModel, start: Latent, generator: torch.Generator | None
    ) -> tuple[Imagined, Tensor, Tensor, Tensor, list[tuple[slice, Latent, Tensor]]]:
        """Roll out the actor in the frozen world model; return the rollout, rewards and
        continue flags (0/1) of states 1..H (H, N), critic values of states 0..H (H+1, N) and,
        per group of time steps over 0..H, the steps, their detached states and the critic's
        logits there (for the critic's own loss).

        The critic is evaluated once: its first layer is read inside the imagination loop with
        frozen weights (gradient to the states, for the actor's returns), and
        `LatentMLP.with_weight_gradient` adds the path to its weights for the critic's own loss,
        as on detached states. Each loss is then differentiated with respect to its own
        parameters only (see `DreamerAgent.train_step`)."""
        c = self.config
        horizon, n = c.imag_horizon, start.h.shape[0]
        reinforce = self.actor.reinforce
        noise = iter(self.actor.noise((horizon, n), generator, start.h.device))
        actor_net = self.actor.net

        def policy(latent: Latent, first: Tensor | None) -> tuple[Tensor, dict[str, Tensor]]:
            # actor(sg(s)) as in DreamerV3: `first` is read from the stop-gradient state inside
            # the fused loop (RSSM.imagine), and the plain path detaches the state itself, so
            # the actor's objective never differentiates through its own later inputs.
            raw = actor_net.finish(first) if first is not None else actor_net(latent.detach())
            action, entropy = self.actor.sample_from_output(raw, next(noise))
            return action, {"entropy": entropy}

        reward_head, continue_head = world_model.reward_head, world_model.continue_head
        chunks = self._chunks(horizon + 1, n)
        with frozen(world_model):
            with frozen(self.critic.first):
                if reinforce:  # no gradient through the imagined states
                    with torch.no_grad():
                        imagined = world_model.rssm.imagine(policy, start, horizon, generator)
                    readout = Readout([reward_head, self.critic], None, [continue_head])
                    chunk_pres = [readout(Latent.cat([s.detach() for s in imagined.states[steps]])) for steps in chunks]
                else:  # heads read each state inside the loop, fused with the actor and the RSSM
                    imagined = world_model.rssm.imagine(
                        policy, start, horizon, generator, actor_net, [reward_head, self.critic], [continue_head]
                    )
                    chunk_pres = [
                        [torch.cat([p[k] for p in imagined.readouts[steps]]) for k in range(3)] for steps in chunks
                    ]
            rewards, conts, critic_chunks = [], [], []
            for steps, pres in zip(chunks, chunk_pres):
                rewards.append(world_model.twohot.mean(reward_head.finish(pres[0])))
                states = Latent.cat([s.detach() for s in imagined.states[steps]])
                logits = self.critic.finish(self.critic.with_weight_gradient(pres[1], states))
                critic_chunks.append((steps, states, logits))
                # The continue head's mode, without gradient (as DreamerV3's reference code): a
                # differentiable probability lets the actor lower its continuation wherever the
                # future looks negative, i.e. learn to end episodes without paying the penalty
                # that ends them in the real env (the penalty is in the reward, not in cont).
                with torch.no_grad():
                    conts.append((continue_head.finish(pres[2]).squeeze(-1) > 0).float())
        values = self.twohot.mean(torch.cat([logits for _, _, logits in critic_chunks])).view(horizon + 1, n)
        reward = torch.cat(rewards).view(horizon + 1, n)[1:]
        if c.action_cost:  # the known charge on each imagined action, exact (its gradient included)
            reward = reward - c.action_cost * torch.linalg.vector_norm(imagined.actions, dim=-1)
        cont = torch.cat(conts).view(horizon + 1, n)[1:]
        return imagined, reward, cont, values, critic_chunks

    def _critic_and_policy_terms(
        self, imagined: Imagined, critic_chunks: list[tuple[slice, Latent, Tensor]], target: Tensor
    ) -> tuple[Tensor, Tensor | None, Tensor]:
        """Per-step critic loss (two-hot NLL of the lambda-return `target` plus the regulariser
        toward the slow critic's prediction) from the critic's logits of states 0..H-1 (the
        groups `_imagine` returns, without state H), and the actor's log-probabilities (REINFORCE
        only) and entropies, each (H, N)."""
        c = self.config
        horizon, n = target.shape
        critic_losses, log_probs, entropies = [], [], []
        for chunk_steps, states, chunk_logits in critic_chunks:
            steps = slice(chunk_steps.start, min(chunk_steps.stop, horizon))
            rows = (steps.stop - steps.start) * n
            if rows <= 0:
                continue
            before, logits = states.select(slice(0, rows)), chunk_logits[:rows]
            with torch.no_grad():
                slow_values = self.twohot.mean(self.slow_critic(before))
            chunk_target = target[steps].reshape(-1)
            bins_log_probs = torch.log_softmax(logits.float(), dim=-1)
            critic_losses.append(
                self.twohot.loss_from_log_probs(bins_log_probs, chunk_target)
                + c.slow_critic_reg * self.twohot.loss_from_log_probs(bins_log_probs, slow_values)
            )
            if self.actor.reinforce:
                actions = imagined.actions[steps].reshape(-1, self.actor.action_size)
                log_prob, entropy = self.actor.log_prob_entropy(before, actions)
                log_probs.append(log_prob)
                entropies.append(entropy)
        critic_per_step = torch.cat(critic_losses).view(horizon, n)
        if self.actor.reinforce:
            return critic_per_step, torch.cat(log_probs).view(horizon, n), torch.cat(entropies).view(horizon, n)
        return critic_per_step, None, imagined.extras["entropy"]

    def losses(
        self,
        world_model: WorldModel,
        start: Latent,
        start_continue: Tensor,
        generator: torch.Generator | None,
    ) -> BehaviorOutput:
        """Imagine from `start` (leading shape (N,)) and return actor and critic losses.
        `start_continue` (N,) is 1 - is_terminal of the replayed start states."""
        c = self.config
        start, start_continue = start.detach(), start_continue.detach()
        n = start.h.shape[0]
        if c.imag_starts is not None and c.imag_starts < n:
            pick = torch.randperm(n, generator=generator, device=start.h.device)[: c.imag_starts]
            start, start_continue, n = start.select(pick), start_continue[pick], c.imag_starts
        imagined, reward, cont, values, critic_chunks = self._imagine(world_model, start, generator)

        discounts = c.discount * cont
        returns = lambda_returns(reward, discounts, values, c.return_lambda)
        # Weight of step t: probability that the episode is still running there (no gradient).
        weights = torch.cumprod(torch.cat((start_continue.unsqueeze(0), discounts[:-1].detach()), 0), 0)
        critic_per_step, log_prob, entropy = self._critic_and_policy_terms(imagined, critic_chunks, returns.detach())

        low, high = self.return_norm.candidate(returns)
        scale = self.return_norm.scale(low, high)
        advantage = (returns - values[:-1].detach()) / scale
        if self.actor.reinforce:
            actor_objective = log_prob * advantage.detach()
        else:  # backprop through the dynamics: the returns carry the gradient
            actor_objective = advantage
        actor_loss = -(weights * (actor_objective + c.actor_entropy * entropy)).mean()
        critic_loss = (weights * critic_per_step).mean()

        metrics = {
            "actor/loss": actor_loss.detach(),
            "actor/entropy": entropy.detach().mean(),
            "critic/loss": critic_loss.detach(),
            "critic/value": values.detach().mean(),
            "imag/return": returns.detach().mean(),
            "imag/reward": reward.detach().mean(),
            "imag/continue": cont.detach().mean(),
            "return_norm/low": low,
            "return_norm/high": high,
            "return_norm/scale": scale,
        }
        return BehaviorOutput(actor_loss, critic_loss, metrics, low, high)
