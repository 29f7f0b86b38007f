"""Dreamer-AIL: the paper's imitation baseline. A residual assistant trained by adversarial
imitation of the experts' driving, beside the same Dreamer humans as every other method.

The paper (section 4, "Baselines") takes the AIL assistant of BeTAIL (Weaver et al. 2024) and
pairs it with a Dreamer human in place of BeTAIL's behaviour transformer: the human's action is
the base, the assistant adds a residual, and the residual is trained by GAIL (Ho & Ermon 2016)
to make the car's driving look like the experts'. It asks whether a world model is needed at all.

What is built here, and why:

* **The residual** is the assistant's action `a_A`, added to the human's as for every method
  (`clip(a_H + a_A, -1, 1)`), bounded to [-b, b] on each control (`residual_bound`, 0.5: the
  human's own input keeps at least half of the car). BeTAIL bounds its residual; the paper gives
  no value, and its Dreamer-AIL's intervention of 1.4 says it used the whole range.
* **The discriminator** `D(s, b)` tells the experts' (observation, action) pairs from the assisted
  car's (observation, executed action `b`). The observation is the env's without the partner slot
  (an expert driving alone has none); the executed action is the one the car received, read back
  from the human's action in the next record's partner slot. One discriminator for the pair's
  experts together: the baseline is not told the intent, which is what lets it collapse onto one
  mode, as the paper reports it does.
* **The reward** is `log D - log(1 - D)` alone (clipped), the AIL reward of the assisted pairs;
  the env's task and intervention terms are not added. The paper calls the baseline "purely
  data-driven" (behaviour cloning and inverse RL), so nothing of the task reward enters; its
  Dreamer-AIL intervenes at 1.4, the whole range, which an intervention charge would not allow.
* **The learner** is the no-rssm PPO learner (`no_rssm.py`: 16-frame window, GAE, clipped
  ratio), with the rollout's rewards replaced by the discriminator's before each update. Why not
  `imitation`'s GAIL on Stable-Baselines3: its trainer owns the environment loop (a vectorised
  env it steps itself), while here the human acts outside the env and the shared training loop
  steps both; a GAIL discriminator is ~60 lines on the learner we already test.

Each PPO update first trains the discriminator (`disc_steps` minibatches of `disc_batch` pairs per
side), then pays the rollout with it. The demonstrations come from the store (`demonstrations`
artifact, `d2a_core.training.demonstrations`) through `set_demonstrations`; evaluation needs none.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F

from d2a_core.agents.dreamer.nets import MLP
from d2a_core.errors import ConfigError, TrainingError, UsageError

from .dreamer_ail_config import DreamerAILConfig
from .no_rssm import NoRSSMAgent

__all__ = ["DreamerAILAgent", "DreamerAILConfig", "build_assistant"]

PARTNER_SLOT = 2  # the env observation's last two entries: the other driver's last action
_OBS_CLIP = 10.0
_NORM_EPS = 1e-3


class DreamerAILAgent(NoRSSMAgent):
    """The no-rssm PPO learner paid by a GAIL discriminator; no intent estimate. Satisfies
    `d2a_core.agents.protocol.AssistantAgent`, plus `set_demonstrations` for training."""

    def __init__(self, obs_space: gym.spaces.Box, act_space: gym.spaces.Box, config: DreamerAILConfig,
                 intents: Sequence[str], seed: int = 0, device: str = "cpu") -> None:
        super().__init__(obs_space, act_space, config, intents, seed=seed, device=device)
        self._disc_seed = seed * 3 + 3
        self.discriminator: MLP | None = None  # built once the demonstrations' width is known
        self.disc_optimizer: torch.optim.Optimizer | None = None
        self.demo_width: int | None = None
        self._demos: tuple[Tensor, Tensor] | None = None
        self._demo_mean = self._demo_std = None

    # --- the demonstrations and the discriminator

    def _build_discriminator(self, width: int) -> None:
        if width + PARTNER_SLOT > self.obs_size:
            raise UsageError(f"demonstrations of {width} observation features do not fit the assistant's "
                             f"{self.obs_size} (the env's observation and its partner slot)")
        c = self.config
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self._disc_seed)
            self.discriminator = MLP(width + self.action_size, c.disc_units, c.disc_layers, _NORM_EPS, 1,
                                     zero_output=True).to(self.device)
        self.disc_optimizer = torch.optim.Adam(self.discriminator.parameters(), lr=c.disc_lr, eps=c.adam_eps)
        self.demo_width = width

    def set_demonstrations(self, obs: np.ndarray, action: np.ndarray) -> None:
        """The experts' pairs: `obs` (M, D) their observations without the partner slot, `action`
        (M, A) what they did (env units). Needed before training; not stored in checkpoints."""
        obs = np.asarray(obs, np.float32)
        action = np.asarray(action, np.float32)
        if obs.ndim != 2 or action.shape != (obs.shape[0], self.action_size) or obs.shape[0] < 2:
            raise UsageError(f"demonstrations: need obs (M, D) and actions (M, {self.action_size}) with M >= 2, "
                             f"got {obs.shape} and {action.shape}")
        if self.discriminator is None:
            self._build_discriminator(obs.shape[1])
        elif obs.shape[1] != self.demo_width:
            raise UsageError(f"demonstrations have {obs.shape[1]} observation features; this agent's "
                             f"discriminator reads {self.demo_width}")
        self._demo_mean = torch.as_tensor(obs.mean(0), device=self.device)
        self._demo_std = torch.as_tensor(np.sqrt(obs.var(0) + 1e-8), device=self.device)
        self._demos = (torch.as_tensor(obs, device=self.device), torch.as_tensor(action, device=self.device))

    def discriminator_logits(self, obs: Tensor, action: Tensor) -> Tensor:
        """logit D(s, b) for observations (..., demo_width) and actions (..., A); > 0 reads as expert."""
        assert self.discriminator is not None and self._demo_mean is not None
        x = ((obs - self._demo_mean) / self._demo_std).clamp(-_OBS_CLIP, _OBS_CLIP)
        return self.discriminator(torch.cat([x, action], -1)).squeeze(-1)

    def _assisted_pairs(self) -> tuple[Tensor, Tensor, Tensor]:
        """(observation, executed action) of records 0..T-1 of the rollout, and which are samples
        (their action was executed: the next record is not an episode's first)."""
        d, T, width = self.rollout.data, self.config.rollout_length, self.demo_width
        records = slice(self.rollout.context, self.rollout.context + T + 1)
        obs, first = d["obs"][:, records], d["is_first"][:, records]
        assistant = self._to_env_action(torch.tanh(torch.as_tensor(d["action"][:, records][:, :T]))
                                        .reshape(-1, self.action_size)).reshape(obs.shape[0], T, -1)
        human = obs[:, 1:, width:width + PARTNER_SLOT]  # the next record's partner slot: a_H of this step
        executed = np.clip(human + assistant, -1.0, 1.0)
        tensor = lambda a: torch.as_tensor(np.ascontiguousarray(a), device=self.device)  # noqa: E731
        return tensor(obs[:, :T, :width]), tensor(executed.astype(np.float32)), tensor(~first[:, 1:])

    def _train_discriminator(self, obs: Tensor, action: Tensor) -> dict[str, float]:
        c = self.config
        assert self._demos is not None and self.discriminator is not None and self.disc_optimizer is not None
        demo_obs, demo_action = self._demos
        losses, expert_right, policy_right = [], [], []
        for _ in range(c.disc_steps):
            pick = torch.randint(obs.shape[0], (c.disc_batch,), generator=self.train_generator, device=self.device)
            demo = torch.randint(demo_obs.shape[0], (c.disc_batch,), generator=self.train_generator,
                                 device=self.device)
            expert = self.discriminator_logits(demo_obs[demo], demo_action[demo])
            assisted = self.discriminator_logits(obs[pick], action[pick])
            loss = (F.binary_cross_entropy_with_logits(expert, torch.ones_like(expert))
                    + F.binary_cross_entropy_with_logits(assisted, torch.zeros_like(assisted)))
            if not bool(torch.isfinite(loss)):
                raise TrainingError(f"non-finite discriminator loss in update {self.updates_done + 1}; no update applied")
            self.disc_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(self.discriminator.parameters(), c.grad_clip)
            self.disc_optimizer.step()
            losses.append(float(loss.detach()))
            expert_right.append(float((expert > 0).float().mean()))
            policy_right.append(float((assisted < 0).float().mean()))
        return {"ail/disc_loss": float(np.mean(losses)), "ail/expert_accuracy": float(np.mean(expert_right)),
                "ail/assisted_accuracy": float(np.mean(policy_right))}

    # --- training: the discriminator, then PPO on its reward

    def _update(self) -> dict[str, float]:
        if self._demos is None:
            raise UsageError("Dreamer-AIL trains only with demonstrations: call set_demonstrations first")
        c, d, T = self.config, self.rollout.data, self.config.rollout_length
        obs, executed, sample = self._assisted_pairs()
        flat_obs, flat_action = obs.reshape(-1, obs.shape[-1]), executed.reshape(-1, self.action_size)
        chosen = sample.reshape(-1).nonzero().squeeze(-1)
        metrics = self._train_discriminator(flat_obs[chosen], flat_action[chosen]) if chosen.numel() > 1 else {}
        with torch.no_grad():
            reward = self.discriminator_logits(obs, executed).clamp(-c.reward_clip, c.reward_clip)
            reward = torch.where(sample, reward, 0.0).cpu().numpy()
        arrivals = slice(self.rollout.context + 1, self.rollout.context + T + 1)  # record t+1 pays transition t
        env_reward = d["reward"][:, arrivals].copy()
        d["reward"][:, arrivals] = reward
        metrics.update(super()._update())
        metrics["ail/reward"] = float(reward[sample.cpu().numpy()].mean()) if chosen.numel() else 0.0
        metrics["rollout/env_reward"] = float(env_reward.mean())
        return metrics

    def intent_probs(self, state: Any) -> None:
        """None: the baseline has no intent estimate."""
        return None

    # --- checkpoint state

    def _learner_state(self) -> dict[str, Any]:
        state = super()._learner_state()
        if self.discriminator is not None:
            assert self.disc_optimizer is not None
            state["ail"] = {"demo_width": self.demo_width, "discriminator": self.discriminator.state_dict(),
                            "optimizer": self.disc_optimizer.state_dict()}
        return state

    def _load_learner_state(self, state: Mapping[str, Any]) -> None:
        super()._load_learner_state(state)
        ail = state.get("ail")
        if ail is None:
            return
        if self.discriminator is None:
            self._build_discriminator(int(ail["demo_width"]))
        elif int(ail["demo_width"]) != self.demo_width:
            raise ConfigError(f"checkpoint's discriminator reads {ail['demo_width']} observation features, "
                              f"this agent's {self.demo_width}")
        assert self.discriminator is not None and self.disc_optimizer is not None
        self.discriminator.load_state_dict(ail["discriminator"])
        self.disc_optimizer.load_state_dict(ail["optimizer"])


def build_assistant(config: DreamerAILConfig, obs_space: gym.spaces.Box, act_space: gym.spaces.Box,
                    intents: Sequence[str], seed: int = 0, device: str = "cpu") -> DreamerAILAgent:
    """The method registry's entry point for `dreamer-ail`: the env's action space narrowed to
    the residual's bound (the learner acts in [-1, 1], mapped onto [-bound, bound])."""
    low = np.maximum(act_space.low, -config.residual_bound)
    high = np.minimum(act_space.high, config.residual_bound)
    return DreamerAILAgent(obs_space, gym.spaces.Box(low, high, dtype=act_space.dtype), config, intents, seed=seed,
                           device=device)
