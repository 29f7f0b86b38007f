"""Shared control: a human policy and an assistant drive one car through `clip(a_H + a_A, -1, 1)`.

`SharedControl` is the assistant's view of the environment: `step(a_A)` asks the human policy
for `a_H` (the human observes the assistant's previous action in its partner slot), applies the
blended action, and returns the assistant's observation (whose partner slot holds `a_H`).
`info` gains `human_action` and `assistant_action`; `applied_action` is the clipped sum.
"""

from __future__ import annotations

from typing import Any, Callable, Protocol

import gymnasium as gym
import numpy as np


class HumanPolicy(Protocol):
    """What drives the human side: reset at episode start, then one action per observation."""

    def reset(self) -> None: ...

    def __call__(self, observation: np.ndarray) -> np.ndarray: ...


class _Callable:
    """Adapts a plain function obs -> action to `HumanPolicy` (no memory to reset)."""

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray]):
        self.fn = fn

    def reset(self) -> None:
        pass

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        return self.fn(observation)


def blend(human: np.ndarray, assistant: np.ndarray) -> np.ndarray:
    """The action the car receives: the clipped sum of both drivers' actions."""
    return np.clip(np.asarray(human, dtype=np.float32) + np.asarray(assistant, dtype=np.float32), -1.0, 1.0)


class SharedControl(gym.Wrapper):
    """Wraps a `d2a/Race-v0` env so that an assistant acts alongside `human`."""

    def __init__(self, env: gym.Env, human: HumanPolicy | Callable[[np.ndarray], np.ndarray]):
        super().__init__(env)
        self.human = human if hasattr(human, "reset") else _Callable(human)
        self._human_obs: np.ndarray | None = None
        self._assistant_action = np.zeros(2, dtype=np.float32)

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self.human.reset()
        self._assistant_action[:] = 0.0
        self._human_obs = obs.copy()  # the partner slot is zero at the start for both
        return obs, info

    def step(self, assistant_action):
        assert self._human_obs is not None, "call reset() first"
        a_a = np.clip(np.asarray(assistant_action, dtype=np.float32).reshape(2), -1.0, 1.0)
        a_h = np.clip(np.asarray(self.human(self._human_obs), dtype=np.float32).reshape(2), -1.0, 1.0)
        race = self.env.unwrapped
        race.set_partner_action(a_h)  # the assistant's next observation shows the human's action
        obs, reward, terminated, truncated, info = self.env.step(blend(a_h, a_a))
        human_obs = obs.copy()
        human_obs[-2:] = a_a  # ...and the human's shows the assistant's
        self._human_obs = human_obs
        info = dict(info, human_action=a_h, assistant_action=a_a)
        return obs, reward, terminated, truncated, info
