"""Record every episode of a `d2a/Race-v0` env as an MCAP episode log (one file per episode)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from d2a_core.objectives.rewards import RewardTerms
from d2a_core.sim.episode_log import CarPose, EpisodeLogConfig, EpisodeRecorder, StaticScene


def scene_of(track) -> StaticScene:
    """The static 3-D scene of a track (road, edges, barriers, finish line) for episode logs."""
    left, right = track.edges()
    return StaticScene(track_name=track.name, left_edge=left, right_edge=right,
                       barriers=track.barrier_polylines(), finish_line=track.finish_line_points(),
                       centreline=track.centreline_points())


def _action(values: Any) -> dict[str, float]:
    a = np.asarray(values, dtype=float).reshape(2)
    return {"steer": float(a[0]), "accel": float(a[1])}


class RecordEpisodes(gym.Wrapper):
    """Writes `directory/<prefix>-<n>.mcap` for each episode; `paths` lists the files written."""

    def __init__(self, env: gym.Env, directory: str | Path, prefix: str = "episode",
                 metadata: dict[str, Any] | None = None, config: EpisodeLogConfig | None = None):
        super().__init__(env)
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.prefix = prefix
        self.metadata = dict(metadata or {})
        self.config = config
        self.paths: list[Path] = []
        self._recorder: EpisodeRecorder | None = None
        self._scene = scene_of(env.unwrapped.track)

    def _close_recorder(self) -> None:
        if self._recorder is not None:
            self._recorder.close()
            self.paths.append(self._recorder.path)
            self._recorder = None

    def reset(self, **kwargs: Any):
        self._close_recorder()
        obs, info = self.env.reset(**kwargs)
        race = self.env.unwrapped
        meta = dict(self.metadata, track=race.track.name, intent=race.intent, replay=info["replay"],
                    seed=kwargs.get("seed"))
        path = self.directory / f"{self.prefix}-{len(self.paths):04d}.mcap"
        self._recorder = EpisodeRecorder(path, self._scene, meta, race.cfg.dt, config=self.config)
        self._recorder.open()
        self._log(info)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._log(info, reward)
        if terminated or truncated:
            self._recorder.update_metadata({"outcome": {
                "terminated": terminated, "truncated": truncated, "finished": info["finished"],
                "collision": info["collision"], "off_track": info["off_track"], "progress_m": info["progress"],
            }})
            self._close_recorder()
        return obs, reward, terminated, truncated, info

    def _log(self, info: dict[str, Any], reward: float = 0.0) -> None:
        cars, states = step_record(self.env.unwrapped, info, reward)
        self._recorder.log_step(info["t"], cars, states)

    def close(self) -> None:
        self._close_recorder()
        super().close()


def step_record(race, info: dict[str, Any], reward: float = 0.0) -> tuple[dict[str, CarPose], dict[str, dict]]:
    """The car poses and per-agent state fields of one step of a `RaceEnv` (`race`), as episode
    logs record them: ego state (position on the track, speed, slip, ds/de, every action, reward
    and its terms, intent, outcome) and the opponent's."""
    world = race.world
    ego = world.car_pose(0)
    opp = world.car_pose(1)
    cars = {"ego": CarPose(*ego[:4]), "opponent": CarPose(*opp[:4])}
    ego_state = {
        "s": info["s"], "e": info["e"], "speed": info["speed"], "yaw_rate": info["yaw_rate"],
        "sideslip": info["sideslip"], "slip_front": info["slip_front"], "slip_rear": info["slip_rear"],
        "ds": info["ds"], "de": info["de"], "progress": info["progress"],
        "applied_action": _action(info["applied_action"]), "partner_action": _action(info["partner_action"]),
        "human_action": _action(info.get("human_action", (np.nan, np.nan))),
        "assistant_action": _action(info.get("assistant_action", (np.nan, np.nan))),
        "reward": float(reward), "reward_terms": info["reward_terms"] or {},
        "intent": info["intent"] or "", "collision": info["collision"], "off_track": info["off_track"],
    }
    if not ego_state["reward_terms"]:  # the first step has no terms yet: same layout, zeros
        ego_state["reward_terms"] = RewardTerms.zeros().as_dict()
    opp_state = {"s": info["opponent_s"], "e": info["opponent_e"], "racing": info["opponent_racing"]}
    return cars, {"ego": ego_state, "opponent": opp_state}


# The episode outcome every training/evaluation log carries in its metadata (so a log can be
# sorted without reading its messages).
OUTCOME_FIELDS = ("progress_m", "finished", "collision", "off_track", "return")


def close_with_outcome(recorder: EpisodeRecorder, metrics: dict[str, Any]) -> None:
    """Write the episode's outcome (`OUTCOME_FIELDS` of its metrics) into the log and close it."""
    recorder.update_metadata({"outcome": {k: metrics[k] for k in OUTCOME_FIELDS}})
    recorder.close()


def abort_open(recorders: list[EpisodeRecorder | None]) -> None:
    """Abandon the logs still being written (their partial files are removed), in place."""
    for i, recorder in enumerate(recorders):
        if recorder is not None:
            recorder.abort()
            recorders[i] = None
