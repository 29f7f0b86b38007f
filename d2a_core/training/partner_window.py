"""The assistant's view of the human's recent actions (`assistant.partner_window`).

The env's observation ends with a partner slot: the human's last action. With a window of K > 1
the assistant's observation also carries the K - 1 human actions before it, newest first,
appended after the env's observation (zeros before the episode's first actions, as the slot).

Why: under shared control the car's state mixes both drivers' actions, and only the human's own
actions carry the intent. A classifier on a 16-step window of the human's actions separates the
training humans' intents on 0.985 of steps (per-step F1, held-out episodes) where the assistant's
world model, which sees one action per step through its stochastic latent, reaches 0.78
(docs/experiments/intent-estimate.md, "How much of the intent the human's actions carry"). K = 1
is the paper's observation and leaves every array as it was.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

PARTNER_SLOT = 2
"""Width of the partner slot at the end of the env's observation (the other driver's action)."""


def assistant_observation_space(space: gym.spaces.Box, window: int) -> gym.spaces.Box:
    """The env's observation space widened by the K - 1 earlier human actions."""
    if window <= 1:
        return space
    extra = PARTNER_SLOT * (window - 1)
    low = np.concatenate([space.low, np.full(extra, -1.0, space.dtype)])
    high = np.concatenate([space.high, np.full(extra, 1.0, space.dtype)])
    return gym.spaces.Box(low, high, dtype=space.dtype)


class PartnerWindow:
    """The K - 1 human actions before the partner slot, per env, newest first.

    Call `reset(i)` when env i starts an episode, `push(i, slot)` with env i's partner slot just
    before a step overwrites it, and `view(obs)` for the assistant's observation of all envs."""

    def __init__(self, num_envs: int, window: int) -> None:
        if window < 1:
            raise ValueError(f"partner window must be >= 1, got {window}")
        self.window = window
        self._past = np.zeros((num_envs, window - 1, PARTNER_SLOT), np.float32)

    def reset(self, i: int) -> None:
        self._past[i] = 0.0

    def push(self, i: int, slot: np.ndarray) -> None:
        if self.window > 1:
            self._past[i, 1:] = self._past[i, :-1]
            self._past[i, 0] = slot

    def view(self, obs: np.ndarray) -> np.ndarray:
        """The assistant's observation (N, D + 2 (K - 1)); `obs` itself when K = 1."""
        if self.window == 1:
            return obs
        return np.concatenate([obs, self._past.reshape(len(obs), -1)], axis=1)
