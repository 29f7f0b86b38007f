"""Shared helpers of the DreamerV3 agent tests: a tiny config and random transitions."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from d2a_core.agents.dreamer import DreamerAgent, DreamerConfig


def tiny_config(**overrides) -> DreamerConfig:
    """A config small enough for sub-second updates."""
    values = dict(
        units=32,
        layers=1,
        deter=32,
        stoch=4,
        classes=4,
        bins=21,
        bin_range=5.0,
        batch_size=4,
        batch_length=8,
        imag_horizon=5,
        prefill_steps=0,
        replay_capacity=2000,
    )
    values.update(overrides)
    return DreamerConfig(**values)


def _fill_random(agent: DreamerAgent, steps: int, envs: int = 2, seed: int = 0, **extra_fields) -> None:
    """Observe `steps` random transitions of `envs` environments (episodes of ~10 steps)."""
    rng = np.random.default_rng(seed)
    obs_size = agent.obs_size
    for t in range(steps):
        transition = {
            "obs": rng.normal(size=(envs, obs_size)).astype(np.float32),
            "action": rng.uniform(-1, 1, size=(envs, agent.action_size)).astype(np.float32),
            "reward": rng.normal(size=envs).astype(np.float32),
            "is_first": np.full(envs, t % 10 == 0),
            "is_terminal": np.zeros(envs, bool),
        }
        for key, make in extra_fields.items():
            transition[key] = make(transition)
        agent.observe(transition)


@pytest.fixture
def fill_random():
    """Function that observes random transitions into an agent (see `_fill_random`)."""
    return _fill_random


@pytest.fixture
def make_agent():
    """Factory of small continuous-control agents (obs 3, action 2)."""

    def make(seed: int = 0, obs_size: int = 3, action_size: int = 2, **overrides) -> DreamerAgent:
        return DreamerAgent(
            gym.spaces.Box(-np.inf, np.inf, (obs_size,), np.float32),
            gym.spaces.Box(-1.0, 1.0, (action_size,), np.float32),
            tiny_config(**overrides),
            seed=seed,
        )

    return make
