"""A frozen expert run along the assistant's episodes (Dream2Assist's expert alignment terms).

The assistant's reward (paper equation 6, `d2a_core.objectives.assistant`) queries, for each
intent y of the pair, the expert `(W*_y, pi*_y)`: the reward `r_hat*(y)` its world model predicts
and an action `a*(y)` of its actor. Both must be conditioned on the episode so far, not on a
blank state, so the expert's world model is filtered along every episode like its own `policy`
filters when it drives: its posterior is updated with each observation and the *blended* action
that was executed (not the expert's own), through `DreamerAgent.policy`/`with_action`.

Timing, per environment step (DreamerV3's convention: a reward belongs to the state it leads to):

    x_t  --(blended a_t executed)-->  x_{t+1}

    ExpertFilter.step(x_{t+1}, a_t)   ->  reward = r_hat*(s_{t+1}): the expert world model's
                                          reward for having taken a_t at s_t, read at the
                                          posterior state that saw where it led (the states its
                                          reward head was trained on); 0 on an episode's first step
                                       ->  action = a*_{t+1} ~ pi*(s_{t+1}): what the expert would
                                          do now, to compare with the blended a_{t+1} (keep it
                                          until the next step's reward is made)

So the assistant's reward for arriving at x_{t+1} takes `reward` of this step and `action` of
the previous one. Everything runs without gradients; the expert's networks are never changed and
its own acting generator is not drawn from (the filter has its own).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from .agent import DreamerAgent, PolicyState


class ExpertPrediction(NamedTuple):
    """The expert's outputs at the current state of N environments."""

    reward: np.ndarray  # (N,) r_hat*: predicted reward of the last transition (0 on a first step)
    action: np.ndarray  # (N, *action_shape) a*: a sample (or the mode) of the expert actor, env units


class ExpertFilter:
    """Filters one frozen `DreamerAgent`'s world model along a batch of `num_envs` episodes.

        experts = ExpertFilter(agent, num_envs)
        experts.reset(np.ones(num_envs, bool))        # every env starts an episode
        out = experts.step(obs, blended_action)       # after each env step (action ignored on a first step)
        out.reward, out.action                        # r_hat*, a*  (see the module docstring)

    `sample`: a* is a sample of the actor (the paper's `a* ~ pi*`); False takes its mode.
    """

    def __init__(self, agent: DreamerAgent, num_envs: int, sample: bool = True, seed: int = 0) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        self.agent = agent
        self.num_envs = num_envs
        self.sample = sample
        self.generator = torch.Generator(agent.device).manual_seed(seed)
        self.state: PolicyState = agent.initial_state(num_envs)
        self._first = np.ones(num_envs, bool)  # envs whose next observation starts an episode
        self.last: ExpertPrediction | None = None

    def reset(self, mask: np.ndarray) -> None:
        """Envs where `mask` (N,) is true start a new episode: their next `step` observation is
        the episode's first and their history is forgotten."""
        mask = np.asarray(mask, bool).reshape(self.num_envs)
        self._first = self._first | mask

    @torch.no_grad()
    def step(self, obs: np.ndarray, blended_action: np.ndarray | None) -> ExpertPrediction:
        """Update the posterior with the observation `obs` (N, *obs_shape) reached after the
        blended action `blended_action` (N, *action_shape, env units) was executed at the previous
        observation, and return the expert's reward prediction and action at the new state.
        `blended_action` may be None when every env starts an episode."""
        first = self._first.copy()
        state = self.state
        if blended_action is not None:
            state = self.agent.with_action(state, blended_action)
        elif not first.all():
            raise ValueError("ExpertFilter.step: blended_action is needed for envs continuing an episode")
        action, self.state = self.agent.policy(
            {"obs": obs, "is_first": first}, state, explore=self.sample, generator=self.generator
        )
        reward = self.agent.world_model.reward(self.state.latent).float().cpu().numpy()
        reward = np.where(first, 0.0, reward).astype(np.float32)
        self._first = np.zeros(self.num_envs, bool)
        self.last = ExpertPrediction(reward, action)
        return self.last
