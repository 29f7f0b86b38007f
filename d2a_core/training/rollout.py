"""Run a DreamerV3 agent in a batch of race envs: collect training data, or evaluate.

The envs are stepped one by one in this process (no gymnasium vector wrapper: we need each env's
own `info`, and merging ~27 info keys per step costs more than the stepping). The agent sees only
observation arrays; this module is the bridge between agent and simulator.

Record protocol (see `DreamerAgent`): every env contributes one record per call: the observation
it arrived at, the reward for arriving, `is_first`, `is_terminal`. The policy acts on every record;
for an env whose episode just ended, that action is not executed: the env is reset instead and its
next record is the reset observation with `is_first = True`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.agents.dreamer.agent import DreamerAgent, PolicyState
from d2a_core.evaluation.metrics import episode_metrics
from d2a_core.sim.episode_log import EpisodeRecorder
from d2a_core.sim.race_env import RaceEnv
from d2a_core.sim.recording import abort_open, close_with_outcome, scene_of, step_record


class Collector:
    """Steps `envs` with `agent.policy` and (when learning) feeds every record to `agent.observe`.

    Resets use seeds `seed, seed + 1, ...`, so a run is reproducible. With `log_dir`, the first
    `log_episodes` episodes started are written as MCAP episode logs `episode-<seed>.mcap` there
    (a log is complete once its episode ended; `close` removes the unfinished ones).
    `reset_options` go to every reset (e.g. `start_spread` for training starts along the track)."""

    def __init__(self, envs: Sequence[RaceEnv], agent: DreamerAgent, seed: int,
                 log_dir: Path | None = None, log_episodes: int = 0, reset_options: dict[str, Any] | None = None):
        self.envs = list(envs)
        self._reset_options = dict(reset_options) if reset_options else None
        self.agent = agent
        self.n = len(self.envs)
        self._next_seed = seed
        self._log_dir = None if log_dir is None else Path(log_dir)
        self._logs_left = log_episodes if log_dir is not None else 0
        self._recorders: list[EpisodeRecorder | None] = [None] * self.n
        self._scene = scene_of(self.envs[0].track) if self._logs_left else None
        self._state: PolicyState | None = None
        obs_size = self.envs[0].observation_space.shape[0]
        self._obs = np.zeros((self.n, obs_size), np.float32)
        self._reward = np.zeros(self.n, np.float32)
        self._first = np.ones(self.n, bool)
        self._terminal = np.zeros(self.n, bool)
        self._done = np.zeros(self.n, bool)
        self._infos: list[list[dict[str, Any]]] = [[] for _ in range(self.n)]
        self._rewards: list[list[float]] = [[] for _ in range(self.n)]
        for i in range(self.n):
            self._reset(i)

    def _reset(self, i: int) -> None:
        obs, info = self.envs[i].reset(seed=self._next_seed, options=self._reset_options)
        if self._logs_left > 0:
            self._logs_left -= 1
            self._open_log(i, self._next_seed, info)
        self._next_seed += 1
        self._obs[i] = obs
        self._reward[i] = 0.0
        self._first[i] = True
        self._terminal[i] = False
        self._done[i] = False
        self._infos[i] = [info]
        self._rewards[i] = []

    def step(self, explore: bool = True, learn: bool = True) -> list[dict[str, float]]:
        """One record per env: act, store (when `learn`), advance. Returns the metrics of the
        episodes that ended on this call."""
        record = {"obs": self._obs.copy(), "reward": self._reward.copy(), "is_first": self._first.copy(),
                  "is_terminal": self._terminal.copy()}
        actions, self._state = self.agent.policy(record, self._state, explore=explore)
        if learn:
            self.agent.observe({**record, "action": actions})
        finished = []
        for i, env in enumerate(self.envs):
            if self._done[i]:
                self._reset(i)
                continue
            obs, reward, terminated, truncated, info = env.step(actions[i])
            recorder = self._recorders[i]
            if recorder is not None:
                cars, states = step_record(env, info, reward)
                recorder.log_step(info["t"], cars, states)
            self._infos[i].append(info)
            self._rewards[i].append(float(reward))
            self._obs[i] = obs
            self._reward[i] = reward
            self._first[i] = False
            self._terminal[i] = terminated
            if terminated or truncated:
                self._done[i] = True
                finished.append(episode_metrics(self._infos[i], self._rewards[i]))
                if recorder is not None:
                    close_with_outcome(recorder, finished[-1])
                    self._recorders[i] = None
        return finished

    def close(self) -> None:
        """Remove the episode logs whose episodes had not ended."""
        abort_open(self._recorders)

    def _open_log(self, i: int, seed: int, info: dict[str, Any]) -> None:
        assert self._log_dir is not None and self._scene is not None
        self._log_dir.mkdir(parents=True, exist_ok=True)
        env = self.envs[i]
        meta = {"track": env.track.name, "intent": env.intent, "replay": info["replay"], "seed": seed}
        recorder = EpisodeRecorder(self._log_dir / f"episode-{seed}.mcap", self._scene, meta, env.cfg.dt)
        recorder.open()
        cars, states = step_record(env, info, 0.0)
        recorder.log_step(info["t"], cars, states)
        self._recorders[i] = recorder


def evaluate(agent: DreamerAgent, make_env: Callable[[], RaceEnv], episodes: int, seed: int,
             n_envs: int = 4, log_dir: Path | None = None, log_episodes: int = 0) -> list[dict[str, float]]:
    """`episodes` episodes with the actor's mode (no exploration); nothing is added to replay.

    Episodes are taken in the order they end; with several envs the extra episodes still running
    at the end are dropped, which keeps the set fixed for a given seed. The first `log_episodes`
    (by seed) are also written to `log_dir` as MCAP episode logs (see `Collector`); logging
    changes no metric."""
    envs = [make_env() for _ in range(max(1, min(n_envs, episodes)))]
    collector = None
    try:
        collector = Collector(envs, agent, seed, log_dir=log_dir, log_episodes=min(log_episodes, episodes))
        results: list[dict[str, float]] = []
        while len(results) < episodes:
            results.extend(collector.step(explore=False, learn=False))
        return results[:episodes]
    finally:
        if collector is not None:
            collector.close()
        for env in envs:
            env.close()
