"""The steps of assisted episodes, as evaluation drives them (mode actions, env seeds 50,000 + k),
for the probes that look inside the assistant at every step (imagined_throttle.py,
intervention_seen.py)."""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import numpy as np

from d2a_core import api
from d2a_core.sim.shared_control import blend


def assisted_steps(assistant: api.Assistant, human: api.Driver, episodes: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (observation, the assistant's action) at every step of `episodes` assisted episodes,
    after the assistant acted and before the env steps: its model state is the one it acted from."""
    env = assistant.make_env(human.intent)
    try:
        for seed in range(episodes):
            obs, _ = env.reset(seed=50_000 + seed)
            human.reset()
            assistant.reset()
            a_assist, done = np.zeros(2, np.float32), False
            while not done:
                a_human = human.act(api.human_view(obs, a_assist))
                a_assist = assistant.act(obs)
                yield obs, a_assist
                executed = blend(a_human, a_assist)
                human.executed(executed)
                env.unwrapped.set_partner_action(a_human)
                obs, _, terminated, truncated, _ = env.step(executed)
                done = terminated or truncated
    finally:
        env.close()


def probe_parser(description: str, episodes: int) -> argparse.ArgumentParser:
    """The probes' shared command line: STORE ASSISTANT HUMAN..., --episodes, --samples (prior
    draws per imagined action)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("store")
    parser.add_argument("assistant")
    parser.add_argument("humans", nargs="+", help="human checkpoint ids")
    parser.add_argument("--episodes", type=int, default=episodes)
    parser.add_argument("--samples", type=int, default=8)
    return parser
