"""End-to-end learning: a smoke-sized DreamerV3 agent learns a 1-D reaching task within a few
hundred updates, through the public acting / observe / train-ratio / update API."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from d2a_core.agents.dreamer import DreamerAgent, DreamerConfig

EPISODE_STEPS = 20


class PointReach:
    """Vectorised 1-D points starting at 0 that are paid -|x - goal| per step; the action moves
    the point by 0.2 * clip(a, -1, 1). Observation: (x, goal - x). Episodes last 20 steps
    (truncated, never terminal). The best return is about -0.5; uniform random actions get about -6."""

    def __init__(self, envs: int, seed: int) -> None:
        self.envs = envs
        self.rng = np.random.default_rng(seed)

    def reset(self) -> np.ndarray:
        self.x = np.zeros(self.envs)
        self.goal = self.rng.uniform(-0.8, 0.8, self.envs)
        self.t = 0
        return self._obs()

    def _obs(self) -> np.ndarray:
        return np.stack([self.x, self.goal - self.x], -1).astype(np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        self.x = np.clip(self.x + 0.2 * np.clip(action[:, 0], -1, 1), -1, 1)
        self.t += 1
        return self._obs(), -np.abs(self.x - self.goal), self.t >= EPISODE_STEPS


def _first(obs: np.ndarray) -> dict[str, np.ndarray]:
    n = len(obs)
    return {"obs": obs, "reward": np.zeros(n), "is_first": np.ones(n, bool), "is_terminal": np.zeros(n, bool)}


def _evaluate(policy, envs: int, seed: int) -> float:
    """Mean return of one episode of `envs` environments."""
    env = PointReach(envs, seed)
    step, state, total = _first(env.reset()), None, np.zeros(envs)
    for _ in range(EPISODE_STEPS):
        action, state = policy(step, state)
        obs, reward, _ = env.step(action)
        total += reward
        step = {**_first(obs), "reward": reward, "is_first": np.zeros(envs, bool)}
    return float(total.mean())


def test_smoke_agent_learns_to_reach_the_goal():
    # Smoke size, and faster-than-paper learning rates, fewer two-hot bins and a faster slow
    # critic so that ~400 updates (about 15 s on 2 cores) suffice; the algorithm is unchanged.
    config = DreamerConfig(
        units=64,
        layers=2,
        deter=64,
        stoch=8,
        classes=8,
        bins=41,
        bin_range=5.0,
        batch_size=8,
        batch_length=12,
        imag_horizon=8,
        discount=0.9,
        model_lr=3e-3,
        actor_lr=3e-3,
        critic_lr=3e-3,
        train_ratio=64.0,
        prefill_steps=200,
        replay_capacity=20_000,
        slow_critic_fraction=0.1,
    )
    envs = 4
    agent = DreamerAgent(gym.spaces.Box(-2, 2, (2,), np.float32), gym.spaces.Box(-1, 1, (1,), np.float32), config, seed=0)
    env = PointReach(envs, seed=0)
    step, state, env_steps = _first(env.reset()), None, 0
    episode_return, returns = np.zeros(envs), []
    while agent.updates_done < 400:
        action, state = agent.policy(step, state)
        agent.observe({**step, "action": action})
        env_steps += envs
        for _ in range(agent.updates_due(env_steps)):
            metrics = agent.train_step()
        if env.t >= EPISODE_STEPS:  # this record was the last of the episode: reset next
            returns.append(episode_return.mean())
            episode_return[:] = 0
            step = _first(env.reset())
            continue
        obs, reward, _ = env.step(action)
        episode_return += reward
        step = {**_first(obs), "reward": reward, "is_first": np.zeros(envs, bool)}

    assert all(np.isfinite(v) for v in metrics.values())
    rng = np.random.default_rng(1)
    random_return = _evaluate(lambda s, st: (rng.uniform(-1, 1, (len(s["obs"]), 1)), None), 16, seed=99)
    learned_return = _evaluate(lambda s, st: agent.policy(s, st, explore=False), 16, seed=99)
    early_return = float(np.mean(returns[:3]))
    detail = f"learned {learned_return:.2f}, random {random_return:.2f}, training {np.round(returns, 1).tolist()}"
    assert random_return < -5.0, detail  # the task is not solved by chance
    # Seeds 0-6 reach -1.1 .. -2.4 here (best possible about -0.5); a policy that does not
    # learn stays near its first episodes (about -10) or random actions (about -6).
    assert learned_return > -3.5, detail
    assert learned_return > random_return + 2.0, detail
    assert learned_return > early_return + 4.0, detail
