"""How far the assistant may move the car's controls (`assistant.authority`).

The car executes `clip(a_H + a_A, -1, 1)`. With authority `k` the assistant's actions lie in
[-k, k] on each control (its learner still acts in [-1, 1] and the action space maps that range
onto [-k, k]), so the human's own input keeps at least `1 - k` of the car in every direction.

Why: a full-range assistant can cancel the human's steering and drive the car alone, and at
`quick` size it learnt to (intervention norm ~1.1 per step for every driver, against the paper's
0.3-0.4), serving every driver with the same fast car (docs/experiments/assistant-safety.md).
Authority 1 is the paper's action space and leaves every array as it was.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np


def assistant_action_space(space: gym.spaces.Box, authority: float) -> gym.spaces.Box:
    """The env's action space narrowed to [-authority, authority] (the env's own at authority 1)."""
    if authority >= 1.0:
        return space
    bound = np.full(space.shape, authority, space.dtype)
    return gym.spaces.Box(-bound, bound, dtype=space.dtype)
