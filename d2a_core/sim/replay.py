"""Opponent replays: a recorded trajectory that the opponent car follows step by step.

A replay is an episode log (see `episode_log`) whose `/state/<agent>` channel carries at least
t, x, y, yaw, speed, s, e (z optional). The opponent does not react: at control step k it is
wherever the recording was at step k. After the recording ends the opponent has finished its
run; it leaves the world and its track position keeps advancing at its last speed, so the
passing terms of the reward stay defined.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from d2a_core.errors import UsageError
from d2a_core.sim.episode_log import read_replay


@dataclass
class OpponentReplay:
    """Arrays of one recorded run, sampled at the environment's control step."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    s: np.ndarray
    e: np.ndarray
    name: str = "opponent"

    def __post_init__(self) -> None:
        n = len(self.t)
        if n < 2:
            raise UsageError(f"replay {self.name!r} has {n} steps; at least 2 are needed")
        for field in ("x", "y", "z", "yaw", "speed", "s", "e"):
            if len(getattr(self, field)) != n:
                raise UsageError(f"replay {self.name!r}: field {field} has {len(getattr(self, field))} steps, t has {n}")
        # plain lists: per-step indexing of Python floats is several times faster than numpy scalars
        self._rows = list(zip(*(getattr(self, f).tolist() for f in ("x", "y", "z", "yaw", "speed", "s", "e"))))

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def at(self, step: int) -> tuple[float, float, float, float, float, float, float] | None:
        """(x, y, z, yaw, speed, s, e) at control step `step`, or None once the recording ended."""
        return self._rows[step] if step < len(self._rows) else None

    def s_after_end(self, step: int, dt: float) -> float:
        """Track position `step` steps in, continuing at the final speed after the recording."""
        last = len(self._rows) - 1
        return self._rows[last][5] + self._rows[last][4] * (step - last) * dt

    @classmethod
    def from_log(cls, path: str | Path, agent: str | None = None, dt: float | None = None) -> "OpponentReplay":
        """Read a replay log; if `dt` is given, check the log was recorded at that step."""
        episode = read_replay(path, agent)
        name = agent or episode.agents[0]
        st = episode.state[name]
        z = st["z"] if "z" in st else np.zeros(len(st["t"]))
        replay = cls(t=st["t"], x=st["x"], y=st["y"], z=z, yaw=st["yaw"], speed=st["speed"], s=st["s"], e=st["e"],
                     name=str(Path(path).name))
        if dt is not None and abs(replay.dt - dt) > 1e-6:
            raise UsageError(f"replay {path} was recorded every {replay.dt} s; the environment steps every {dt} s")
        return replay
