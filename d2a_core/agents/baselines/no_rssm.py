"""No-RSSM: the paper's model-free baseline assistant. No world model; the actor, the critic and
an auxiliary intent classifier read the last `window` (16) observations, and the classifier's
probabilities are the assistant's inferred intent y_hat.

Learner: PPO (clipped ratio, GAE advantages) on the records the runner feeds to `observe`, in the
record protocol of `d2a_core.agents.protocol` (the same as DreamerAgent's): record t holds the
observation o_t, the reward for arriving at o_t, `is_first`, `is_terminal` and the action taken at
o_t. The transition of record t therefore ends at record t + 1, which brings its reward and says
whether it ended the episode:

* `is_terminal[t + 1]`: the episode ended there; no bootstrap from V(o_{t+1}).
* `is_first[t + 1]`: record t was its episode's last one and its action was never executed, so it
  is no training sample. A time-limit cut (last record not terminal) bootstraps from the critic's
  value of that last record.

`observe` fills a buffer of `rollout_length + 1` records per env; when it is full `updates_due`
says 1 and `train_step` runs `epochs` x `minibatches` updates on records 0..T-1 (record T only
closes record T-1's transition and is kept as record 0 of the next rollout, with the W-1 frames
before it, so neither transitions nor window history are lost between rollouts).

Scales: observations are standardised by running statistics (updated after each update, so a
rollout is collected by one fixed policy), clipped to +-10. Rewards are divided by the running
std of the per-env discounted return (as in PPO's reference implementations), which keeps the
critic's targets near unit scale whether the rewards are +-100 events or ~1 per-step terms;
advantages are then normalised per rollout. The actor is a Gaussian squashed by tanh into the
action box, with a state-independent std; the ratio needs only the Gaussian density of
atanh(action), since the tanh Jacobian is the same under the old and new policy.

The intent label (`observe`'s optional `intent` field, the label's index in `intents`; absent or
< 0: unlabelled) is only a cross-entropy target of the classifier. No network ever reads it;
with `policy_reads_intent` the actor and critic read the classifier's (detached) output instead.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from d2a_core.agents.dreamer.nets import MLP
from d2a_core.config.section import record, stored_dump
from d2a_core.errors import ConfigError, TrainingError, UsageError

from .no_rssm_config import NoRSSMConfig

__all__ = ["NoRSSMAgent", "NoRSSMConfig", "NoRSSMState", "build_assistant", "gae_advantages"]

_FIELDS = ("obs", "action", "reward", "is_first", "is_terminal")
_SHAPE_FIELDS = ("window", "units", "layers", "policy_reads_intent")
_ACTION_EDGE = 1.0 - 1e-6  # |tanh| is clipped below 1 before atanh (a saturated float32 tanh is exactly 1)
_OBS_CLIP = 10.0
_VAR_EPS = 1e-8
_NORM_EPS = 1e-3  # LayerNorm epsilon (DreamerV3's)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def gae_advantages(rewards: Tensor, values: Tensor, is_first: Tensor, is_terminal: Tensor,
                   discount: float, lam: float) -> tuple[Tensor, Tensor]:
    """GAE(lambda) advantages of records 0..T-1 of a rollout of records 0..T, in the record
    protocol (see the module docstring). All inputs are (N, T + 1), per record.

    Returns advantages (N, T) and the mask (N, T) of records that are samples (their action was
    executed: the next record is not an episode's first); advantages are 0 elsewhere. The last
    record's advantage is cut off (bootstrapped by V of record T)."""
    cont = 1.0 - is_terminal[:, 1:].float()
    sample = ~is_first[:, 1:].bool()
    delta = rewards[:, 1:] + discount * cont * values[:, 1:] - values[:, :-1]
    advantages = torch.zeros_like(delta)
    last = torch.zeros_like(delta[:, 0])
    for t in reversed(range(delta.shape[1])):
        # `last` is record t+1's advantage, already 0 if t+1 is an episode's last record (then
        # V(o_{t+1}) alone bootstraps) or terminal (then cont is 0 as well).
        last = torch.where(sample[:, t], delta[:, t] + discount * lam * cont[:, t] * last, 0.0)
        advantages[:, t] = last
    return advantages, sample


class RunningMoments:
    """Mean and variance of a stream of batches (Chan et al.'s parallel update, float64)."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.mean = np.zeros(shape)
        self.var = np.ones(shape)
        self.count = 0.0

    def update(self, batch: np.ndarray) -> None:
        batch = np.asarray(batch, np.float64)
        size = batch.shape[0]
        if size == 0:
            return
        total = self.count + size
        delta = batch.mean(0) - self.mean
        self.mean = self.mean + delta * size / total
        self.var = (self.var * self.count + batch.var(0) * size + delta**2 * self.count * size / total) / total
        self.count = total

    def std(self) -> np.ndarray:
        return np.sqrt(self.var + _VAR_EPS)

    def state_dict(self) -> dict[str, Any]:
        return {"mean": np.array(self.mean), "var": np.array(self.var), "count": self.count}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.mean, self.var = np.array(state["mean"], np.float64), np.array(state["var"], np.float64)
        self.count = float(state["count"])


class _Rollout:
    """The current rollout's records per env, after the W-1 frames that precede it.

    Time axis: W-1 context frames (the previous rollout's last ones, so the first records' windows
    see their past; `frame_valid` is False where there was none), then up to T+1 records."""

    def __init__(self, window: int, length: int) -> None:
        self.context, self.length = window - 1, length
        self.data: dict[str, np.ndarray] = {}
        self.count = 0  # records stored

    @property
    def full(self) -> bool:
        return self.count == self.length + 1

    def add(self, step: Mapping[str, np.ndarray]) -> None:
        n = step["obs"].shape[0]
        if not self.data:
            size = self.context + self.length + 1
            self.data = {key: np.zeros((n, size, *value.shape[1:]), value.dtype) for key, value in step.items()}
            self.data["intent"][:] = -1
        if self.full:
            raise UsageError("observe: the rollout is full; run the due train_step first")
        if n != self.data["obs"].shape[0]:
            raise UsageError(f"observe: {n} environments, but this rollout has {self.data['obs'].shape[0]}")
        position = self.context + self.count
        for key, value in step.items():
            self.data[key][:, position] = value
        self.count += 1

    def roll(self) -> None:
        """Keep record T and the W-1 frames before it as the next rollout's context and record 0."""
        keep = self.context + 1
        for value in self.data.values():
            value[:, :keep] = value[:, -keep:].copy()
        self.count = 1

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "data": {key: value.copy() for key, value in self.data.items()}}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.count = int(state["count"])
        self.data = {key: np.array(value) for key, value in state["data"].items()}


class _Nets(nn.Module):
    """Actor (Gaussian mean, state-independent log std), critic and intent classifier: separate
    MLPs, so no loss moves another's parameters."""

    def __init__(self, in_size: int, action_size: int, num_intents: int, config: NoRSSMConfig) -> None:
        super().__init__()
        c = config
        policy_in = in_size + (num_intents if c.policy_reads_intent else 0)
        self.actor = MLP(policy_in, c.units, c.layers, _NORM_EPS, action_size)
        with torch.no_grad():  # start near the box's middle, so early exploration is not saturated
            self.actor.out.weight.mul_(0.01)
        self.log_std = nn.Parameter(torch.full((action_size,), math.log(c.init_std)))
        self.critic = MLP(policy_in, c.units, c.layers, _NORM_EPS, 1, zero_output=True)
        self.classifier = MLP(in_size, c.units, c.layers, _NORM_EPS, num_intents, zero_output=True)

    def actor_params(self) -> list[nn.Parameter]:
        return [*self.actor.parameters(), self.log_std]


@dataclass
class NoRSSMState:
    """Per-env state while acting: the window and what the classifier makes of it."""

    window: Tensor  # (N, W, D) raw observations, oldest first; frames before the episode are 0
    valid: Tensor  # (N, W) bool: the frame belongs to the current episode
    probs: Tensor  # (N, K) the classifier's p(y_hat | window)


class NoRSSMAgent:
    """PPO actor-critic with an auxiliary intent classifier over a window of observations;
    satisfies `d2a_core.agents.protocol.AssistantAgent`."""

    def __init__(self, obs_space: gym.spaces.Box, act_space: gym.spaces.Box, config: NoRSSMConfig,
                 intents: Sequence[str], seed: int = 0, device: str = "cpu") -> None:
        if not isinstance(obs_space, gym.spaces.Box):
            raise ConfigError(f"NoRSSMAgent needs a Box observation space, got {obs_space}")
        if not isinstance(act_space, gym.spaces.Box):
            raise ConfigError(f"NoRSSMAgent needs a Box action space, got {act_space}")
        low, high = np.broadcast_arrays(act_space.low, act_space.high)
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
            raise ConfigError("NoRSSMAgent needs a bounded Box action space")
        self.intents = tuple(intents)
        if len(self.intents) < 2 or len(set(self.intents)) != len(self.intents):
            raise UsageError(f"NoRSSMAgent needs at least two distinct intents, got {list(self.intents)}")
        self.config = config
        self.device = torch.device(device)
        self.obs_size = int(np.prod(obs_space.shape))
        self.action_size = int(np.prod(act_space.shape))
        self._action_low = low.reshape(-1).astype(np.float64)
        self._action_span = (high - low).reshape(-1).astype(np.float64)
        self._action_shape = act_space.shape
        c = config
        with torch.random.fork_rng(devices=[]):  # weights from `seed`, the caller's RNG untouched
            torch.manual_seed(seed)
            self.nets = _Nets(c.window * (self.obs_size + 1), self.action_size, len(self.intents), c).to(self.device)
        self.optimizer = torch.optim.Adam(
            [
                {"params": self.nets.actor_params(), "lr": c.actor_lr},
                {"params": list(self.nets.critic.parameters()), "lr": c.critic_lr},
                {"params": list(self.nets.classifier.parameters()), "lr": c.intent_lr},
            ],
            eps=c.adam_eps,
        )
        self.train_generator = torch.Generator(self.device).manual_seed(seed * 3 + 1)
        self.act_generator = torch.Generator(self.device).manual_seed(seed * 3 + 2)
        self.obs_moments = RunningMoments((self.obs_size,))
        self.return_moments = RunningMoments(())
        self._return_acc: np.ndarray | None = None  # per-env discounted return so far (for its std)
        self.rollout = _Rollout(c.window, c.rollout_length)
        self.updates_done = 0
        self._refresh_normaliser()

    # --- networks on windows

    def _refresh_normaliser(self) -> None:
        self._obs_mean = torch.as_tensor(self.obs_moments.mean, dtype=torch.float32, device=self.device)
        self._obs_std = torch.as_tensor(self.obs_moments.std(), dtype=torch.float32, device=self.device)

    def _features(self, window: Tensor, valid: Tensor) -> Tensor:
        """(..., W, D) raw frames and (..., W) validity -> the (..., W * (D + 1)) input of every
        net: standardised frames, zero outside the episode, and the validity flags (so a padded
        frame differs from an average one)."""
        x = ((window - self._obs_mean) / self._obs_std).clamp(-_OBS_CLIP, _OBS_CLIP) * valid.unsqueeze(-1)
        return torch.cat([x.flatten(-2), valid.float()], -1)

    def _policy_input(self, features: Tensor, probs: Tensor) -> Tensor:
        return torch.cat([features, probs], -1) if self.config.policy_reads_intent else features

    def _actor(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and log std (pre-tanh) of the action distribution."""
        log_std = self.nets.log_std.clamp(math.log(self.config.min_std), math.log(self.config.max_std))
        return self.nets.actor(x), log_std

    @staticmethod
    def _log_prob(u: Tensor, mean: Tensor, log_std: Tensor) -> Tensor:
        return (-0.5 * ((u - mean) / log_std.exp()) ** 2 - log_std - _HALF_LOG_2PI).sum(-1)

    # --- acting

    @torch.no_grad()
    def initial_state(self, batch_size: int) -> NoRSSMState:
        """Empty windows of `batch_size` environments."""
        window = torch.zeros(batch_size, self.config.window, self.obs_size, device=self.device)
        valid = torch.zeros(batch_size, self.config.window, dtype=torch.bool, device=self.device)
        probs = self.nets.classifier(self._features(window, valid)).softmax(-1)
        return NoRSSMState(window, valid, probs)

    @torch.no_grad()
    def policy(self, obs_batch: Mapping[str, np.ndarray], state: NoRSSMState | None = None,
               explore: bool = True) -> tuple[np.ndarray, NoRSSMState]:
        """Actions (N, A) in the action box for a batch: `obs_batch["obs"]` (N, D) is appended to
        each env's window, after emptying the windows where `obs_batch["is_first"]` (all when
        `state` is None). Samples when `explore` (from the agent's acting generator), else takes
        tanh of the mean. Reads no other field of `obs_batch` (never an intent label)."""
        obs = torch.as_tensor(np.asarray(obs_batch["obs"]), dtype=torch.float32, device=self.device)
        obs = obs.reshape(-1, self.obs_size)
        n = obs.shape[0]
        state = self.initial_state(n) if state is None else state
        window, valid = state.window, state.valid
        if "is_first" in obs_batch:
            first = torch.as_tensor(np.asarray(obs_batch["is_first"]), dtype=torch.bool, device=self.device).reshape(n)
            window = torch.where(first[:, None, None], 0.0, window)
            valid = valid & ~first[:, None]
        window = torch.cat([window[:, 1:], obs[:, None]], 1)
        valid = torch.cat([valid[:, 1:], torch.ones(n, 1, dtype=torch.bool, device=self.device)], 1)
        features = self._features(window, valid)
        probs = self.nets.classifier(features).softmax(-1)
        mean, log_std = self._actor(self._policy_input(features, probs))
        if explore:
            noise = torch.randn(mean.shape, generator=self.act_generator, device=self.device)
            mean = mean + log_std.exp() * noise
        return self._to_env_action(torch.tanh(mean)), NoRSSMState(window, valid, probs)

    def intent_probs(self, state: NoRSSMState | None) -> np.ndarray | None:
        """The classifier's p(y_hat | window) (N, K) over `intents` at `state` (None: no state yet)."""
        return None if state is None else state.probs.float().cpu().numpy()

    # --- data

    def observe(self, transition: Mapping[str, np.ndarray]) -> None:
        """Store one record of every env: obs, action (taken at obs, env units), reward (for
        arriving at obs), is_first, is_terminal and optionally `intent` (label index, < 0 or
        absent: unlabelled). Other fields are ignored."""
        missing = [key for key in _FIELDS if key not in transition]
        if missing:
            raise UsageError(f"observe: transition lacks fields {missing}")
        obs = np.asarray(transition["obs"], np.float32)
        n = obs.shape[0]
        internal = 2.0 * (np.asarray(transition["action"], np.float64).reshape(n, -1) - self._action_low)
        internal = np.clip(internal / self._action_span - 1.0, -_ACTION_EDGE, _ACTION_EDGE)
        labels = transition.get("intent")
        labels = np.full(n, -1, np.int64) if labels is None else np.asarray(labels, np.int64).reshape(n)
        if np.any(labels >= len(self.intents)):
            raise UsageError(f"observe: intent labels must be indices below {len(self.intents)}, got {labels}")
        self.rollout.add({
            "obs": obs.reshape(n, self.obs_size),
            "action": np.arctanh(internal).astype(np.float32),  # the pre-tanh Gaussian sample
            "reward": np.asarray(transition["reward"], np.float32).reshape(n),
            "is_first": np.asarray(transition["is_first"], bool).reshape(n),
            "is_terminal": np.asarray(transition["is_terminal"], bool).reshape(n),
            "intent": labels,
            "frame_valid": np.ones(n, bool),
        })

    def updates_due(self, env_steps: int) -> int:
        """1 when the rollout holds `rollout_length + 1` records per env, else 0 (on-policy: the
        schedule follows the buffer, not `env_steps`)."""
        return int(self.rollout.full)

    # --- training

    def train_step(self) -> dict[str, float]:
        """One PPO update on the full rollout, then start the next rollout.

        Raises TrainingError if a loss or gradient norm is not finite; everything the update had
        changed (weights, optimiser, statistics, RNG) is restored first, and the rollout kept."""
        if not self.rollout.full:
            raise TrainingError(
                f"the rollout holds {self.rollout.count} of {self.rollout.length + 1} records per env; "
                "train_step is due only when updates_due says so"
            )
        snapshot = copy.deepcopy(self._learner_state())
        try:
            metrics = self._update()
        except TrainingError:
            self._load_learner_state(snapshot)
            raise
        self.rollout.roll()
        self.updates_done += 1
        return metrics

    def _rollout_windows(self) -> tuple[Tensor, Tensor]:
        """Raw windows (N, R, W, D) and their validity (N, R, W) of the R stored records: the
        same windows `policy` saw (frames of an earlier episode or before the data are invalid)."""
        d, end = self.rollout.data, self.rollout.context + self.rollout.count
        w = self.config.window
        view = np.lib.stride_tricks.sliding_window_view
        frames = view(d["obs"][:, :end], w, axis=1).swapaxes(-1, -2)  # (N, R, W, D)
        episode = view(np.cumsum(d["is_first"][:, :end], axis=1), w, axis=1)
        valid = view(d["frame_valid"][:, :end], w, axis=1) & (episode == episode[..., -1:])
        return (torch.as_tensor(np.ascontiguousarray(frames), device=self.device),
                torch.as_tensor(np.ascontiguousarray(valid), device=self.device))

    def _update(self) -> dict[str, float]:
        c, nets = self.config, self.nets
        started = time.perf_counter()
        d, T = self.rollout.data, c.rollout_length
        records = slice(self.rollout.context, None)  # records 0..T
        reward, first, terminal = (d[key][:, records] for key in ("reward", "is_first", "is_terminal"))
        n = reward.shape[0]

        # Reward scale: the running std of the per-env discounted return over records 0..T-1
        # (record T is record 0 of the next rollout, so every reward is counted once).
        acc = np.zeros(n) if self._return_acc is None else self._return_acc
        discounted = np.empty((n, T))
        for t in range(T):
            acc = np.where(first[:, t], 0.0, c.discount * acc) + reward[:, t]
            discounted[:, t] = acc
        self._return_acc = acc
        self.return_moments.update(discounted.reshape(-1))
        return_std = float(self.return_moments.std())

        window, valid = self._rollout_windows()
        features = self._features(window, valid)  # (N, T+1, F)
        with torch.no_grad():
            # The classifier's output enters actor and critic as a fixed input for the whole update
            # (as it was when acting), so the PPO ratio compares policies on the same inputs.
            logits = nets.classifier(features)
            x = self._policy_input(features, logits.softmax(-1))
            values = nets.critic(x).squeeze(-1)
            u = torch.as_tensor(d["action"][:, records], device=self.device)
            old_log_prob = self._log_prob(u, *self._actor(x))[:, :T].reshape(-1)

            tensor = lambda a: torch.as_tensor(a, device=self.device)  # noqa: E731
            advantages, sample = gae_advantages(tensor(reward / return_std), values, tensor(first),
                                                tensor(terminal), c.discount, c.gae_lambda)
            returns = (advantages + values[:, :T]).reshape(-1)
            samples = sample.reshape(-1).nonzero().squeeze(-1)
            adv = advantages.reshape(-1)
            if samples.numel() > 1:
                picked = adv[samples]
                adv = (adv - picked.mean()) / (picked.std(unbiased=False) + 1e-8)
            labels = tensor(d["intent"][:, records][:, :T]).reshape(-1)
            labelled = (labels >= 0).nonzero().squeeze(-1)
            head = logits[:, :T].reshape(-1, logits.shape[-1])
            accuracy = (head[labelled].argmax(-1) == labels[labelled]).float().mean()  # before training on them

        x = x[:, :T].reshape(-1, x.shape[-1])
        u = u[:, :T].reshape(-1, self.action_size)
        features = features[:, :T].reshape(-1, features.shape[-1])
        groups = (self.nets.actor_params(), list(nets.critic.parameters()), list(nets.classifier.parameters()))
        log: dict[str, list[Tensor]] = {}

        def record(**values: Tensor) -> None:
            for key, value in values.items():
                log.setdefault(key, []).append(value.detach().float().reshape(()))

        zero = torch.zeros((), device=self.device)
        for _ in range(c.epochs):
            order = samples[torch.randperm(samples.numel(), generator=self.train_generator, device=self.device)]
            label_order = labelled[torch.randperm(labelled.numel(), generator=self.train_generator, device=self.device)]
            for batch, label_batch in zip(order.tensor_split(c.minibatches), label_order.tensor_split(c.minibatches)):
                actor_loss = critic_loss = intent_loss = zero
                if batch.numel():
                    mean, log_std = self._actor(x[batch])
                    log_ratio = self._log_prob(u[batch], mean, log_std) - old_log_prob[batch]
                    ratio = log_ratio.exp()
                    a = adv[batch]
                    policy_loss = -torch.min(ratio * a, ratio.clamp(1 - c.clip, 1 + c.clip) * a).mean()
                    entropy = (log_std + _HALF_LOG_2PI + 0.5).sum()
                    actor_loss = policy_loss - c.entropy * entropy
                    critic_loss = 0.5 * (nets.critic(x[batch]).squeeze(-1) - returns[batch]).square().mean()
                    record(**{"actor/loss": policy_loss, "actor/entropy": entropy, "critic/loss": critic_loss,
                              "actor/clip_fraction": ((ratio - 1).abs() > c.clip).float().mean(),
                              "actor/approx_kl": (ratio - 1 - log_ratio).mean()})
                if label_batch.numel():
                    intent_loss = F.cross_entropy(nets.classifier(features[label_batch]), labels[label_batch])
                    record(**{"intent/loss": intent_loss})
                losses = {"actor/loss": actor_loss, "critic/loss": critic_loss, "intent/loss": intent_loss}
                bad = [name for name, value in losses.items() if not bool(torch.isfinite(value))]
                if bad:
                    raise TrainingError(f"non-finite loss {bad} in update {self.updates_done + 1}; no update applied")
                total = actor_loss + critic_loss + intent_loss
                if not total.requires_grad:
                    continue
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                norms = [nn.utils.clip_grad_norm_(group, c.grad_clip) for group in groups]
                if not all(bool(torch.isfinite(norm)) for norm in norms):
                    raise TrainingError(
                        f"non-finite gradient norm in update {self.updates_done + 1}; no update applied")
                self.optimizer.step()
                record(**{"actor/grad_norm": norms[0], "critic/grad_norm": norms[1]})
                if label_batch.numel():
                    record(**{"intent/grad_norm": norms[2]})

        # Observation statistics move only between rollouts (each rollout has one fixed policy).
        self.obs_moments.update(d["obs"][:, records][:, :T].reshape(-1, self.obs_size))
        self._refresh_normaliser()

        names = list(log)
        summary = torch.stack([torch.stack(log[name]).mean() for name in names]).tolist() if names else []
        metrics = dict(zip(names, summary))
        if labelled.numel():
            metrics["intent/accuracy"] = float(accuracy)
        metrics.update({
            "actor/std": float(self.nets.log_std.detach().clamp(math.log(c.min_std), math.log(c.max_std)).exp().mean()),
            "critic/value": float(values.mean()) * return_std,  # in reward units
            "return/std": return_std,
            "rollout/reward": float(reward[:, 1:].mean()),
            "rollout/samples": float(samples.numel()),
            "time/update_s": time.perf_counter() - started,
        })
        return metrics

    # --- checkpoint state

    def _learner_state(self) -> dict[str, Any]:
        """What an update changes (the rollout aside)."""
        return {
            "nets": self.nets.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "obs_moments": self.obs_moments.state_dict(),
            "return_moments": self.return_moments.state_dict(),
            "return_acc": None if self._return_acc is None else self._return_acc.copy(),
            "train_rng": self.train_generator.get_state(),
        }

    def _load_learner_state(self, state: Mapping[str, Any]) -> None:
        self.nets.load_state_dict(state["nets"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.obs_moments.load_state_dict(state["obs_moments"])
        self.return_moments.load_state_dict(state["return_moments"])
        acc = state["return_acc"]
        self._return_acc = None if acc is None else np.array(acc, np.float64)
        self.train_generator.set_state(state["train_rng"])
        self._refresh_normaliser()

    def state_dict(self, include_replay: bool = False) -> dict[str, Any]:
        """Everything needed to resume exactly: networks, optimiser, observation and return
        statistics, RNG states, the update count; the rollout buffer only when asked."""
        state = {
            "format": 1,
            "config": record(self.config),  # as DreamerAgent's: knobs added or retired leave it unchanged
            "intents": list(self.intents),
            **self._learner_state(),
            "act_rng": self.act_generator.get_state(),
            "updates_done": self.updates_done,
        }
        if include_replay:
            state["rollout"] = self.rollout.state_dict()
        return state

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore a `state_dict` (same network settings and intents). Without a saved rollout the
        next rollout starts empty."""
        saved = stored_dump(type(self.config), state["config"], "checkpoint")
        current = self.config.model_dump(mode="json")
        differing = [key for key in _SHAPE_FIELDS if saved.get(key) != current.get(key)]
        if differing:
            raise ConfigError(
                "checkpoint was made with different network settings: "
                + ", ".join(f"{k}: {saved.get(k)!r} != {current.get(k)!r}" for k in differing)
            )
        if list(state["intents"]) != list(self.intents):
            raise ConfigError(f"checkpoint intents {list(state['intents'])} differ from {list(self.intents)}")
        self._load_learner_state(state)
        self.act_generator.set_state(state["act_rng"])
        self.updates_done = int(state["updates_done"])
        self.rollout = _Rollout(self.config.window, self.config.rollout_length)
        if "rollout" in state:
            self.rollout.load_state_dict(state["rollout"])

    # --- conversions

    def _to_env_action(self, squashed: Tensor) -> np.ndarray:
        values = squashed.float().cpu().numpy().astype(np.float64)
        env = self._action_low + (values + 1.0) * 0.5 * self._action_span
        env = np.clip(env, self._action_low, self._action_low + self._action_span)  # rounding
        return env.reshape(values.shape[0], *self._action_shape).astype(np.float32)


def build_assistant(config: NoRSSMConfig, obs_space: gym.spaces.Box, act_space: gym.spaces.Box,
                    intents: Sequence[str], seed: int = 0, device: str = "cpu") -> NoRSSMAgent:
    """The method registry's entry point for `no-rssm`."""
    return NoRSSMAgent(obs_space, act_space, config, intents, seed=seed, device=device)
