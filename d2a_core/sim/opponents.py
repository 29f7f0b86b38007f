"""Opponent laps: the scripted driver runs the simulator alone and its trajectory becomes a replay.

Each lap starts at the track's opponent grid slot at the environment's rolling-start speed and
runs past the finish line. A lap counts only if the car stays on the road the whole way (its
body within the edges) and reaches the finish; `make-track` refuses to store one that does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from d2a_core.sim.driver import DriverConfig, LineFollower
from d2a_core.sim.replay import OpponentReplay
from d2a_core.sim.vehicle import Vehicle, VehicleConfig
from d2a_core.tracks.track import Track

RECORDED_FIELDS = ("t", "x", "y", "z", "yaw", "speed", "s", "e", "vx", "vy", "yaw_rate", "slip_front", "slip_rear",
                   "steer", "accel")
RUN_PAST_FINISH_M = 40.0


@dataclass
class Lap:
    """One driven lap: per-step arrays, and whether it is a valid replay."""

    pace: float
    arrays: dict[str, np.ndarray]
    finished: bool
    finish_time_s: float | None
    max_edge_excursion_m: float  # how far the car body came past a road edge (<= 0: stayed on)
    line_offset: np.ndarray = field(repr=False)

    @property
    def valid(self) -> bool:
        return self.finished and self.max_edge_excursion_m <= 0.0

    def replay(self, name: str = "opponent") -> OpponentReplay:
        a = self.arrays
        return OpponentReplay(t=a["t"], x=a["x"], y=a["y"], z=a["z"], yaw=a["yaw"], speed=a["speed"], s=a["s"],
                              e=a["e"], name=name)


def line_profile(track: Track, rng: np.random.Generator, max_offset: float, car_width: float,
                 edge_margin: float = 0.6) -> np.ndarray:
    """A smooth lateral line e(s): an offset plus a slow sway, kept inside the road."""
    if max_offset <= 0:
        return np.zeros(track.n_samples)
    offset = rng.uniform(-max_offset, max_offset) * 0.6
    sway = rng.uniform(0.0, max_offset - abs(offset))
    wavelength = rng.uniform(150.0, 400.0)
    phase = rng.uniform(0.0, 2.0 * math.pi)
    e = offset + sway * np.sin(2.0 * math.pi * track.s / wavelength + phase)
    room_left = track.w_left - 0.5 * car_width - edge_margin
    room_right = track.w_right - 0.5 * car_width - edge_margin
    return np.clip(e, -room_right, room_left)


def drive_lap(
    track: Track,
    pace: float,
    line_offset: np.ndarray | None,
    vehicle_config: VehicleConfig,
    dt: float,
    start_speed: float,
    car_width: float,
    driver_config: DriverConfig | None = None,
    time_limit_s: float | None = None,
) -> Lap:
    """Drive the scripted driver from the opponent grid slot to past the finish line."""
    follower = LineFollower(track, vehicle_config, pace, line_offset, driver_config)
    vehicle = Vehicle(vehicle_config)
    slot = track.start_grid.opponent
    x, y, _ = track.from_frenet(slot.s, slot.e)
    state = vehicle.reset(x, y, track.heading_at(slot.s), start_speed)
    s, e = slot.s, slot.e
    end_s = min(track.finish_s + RUN_PAST_FINISH_M, track.length - 1.0)
    limit = time_limit_s if time_limit_s is not None else 4.0 * track.finish_s / max(start_speed, 5.0) + 60.0
    rows: list[tuple[float, ...]] = []
    finish_time = None
    excursion = -math.inf
    half_width = 0.5 * car_width
    steer = accel = 0.0
    step = 0
    while True:
        t = step * dt
        w_left, w_right = track.width_at(s)
        excursion = max(excursion, e + half_width - w_left, -e + half_width - w_right)
        rows.append((t, state.x, state.y, track.z_at(s), state.yaw, state.speed, s, e, state.vx, state.vy,
                     state.yaw_rate, state.slip_angle_front, state.slip_angle_rear, steer, accel))
        if finish_time is None and s >= track.finish_s:
            # interpolate the crossing between the last two samples
            s_before = rows[-2][6] if len(rows) > 1 else s
            frac = (track.finish_s - s_before) / (s - s_before) if s > s_before else 1.0
            finish_time = t - dt * (1.0 - frac)
        if s >= end_s or t >= limit or excursion > 3.0:
            break
        steer, accel = follower.act(state, s)
        heading = track.heading_at(s)
        grade = track.grade_at(s) * math.cos(state.yaw - heading)
        state = vehicle.step(steer, accel, grade, dt)
        s, e = track.to_frenet(state.x, state.y, s)
        step += 1
    arrays = {name: np.array(col, dtype=np.float64) for name, col in zip(RECORDED_FIELDS, zip(*rows))}
    return Lap(pace=pace, arrays=arrays, finished=finish_time is not None, finish_time_s=finish_time,
               max_edge_excursion_m=float(excursion), line_offset=np.asarray(follower.line_offset))


def default_replays(track: Track, env_config, vehicle_config: VehicleConfig) -> list[OpponentReplay]:
    """One centre-line lap at 85 % pace: the opponent used when an env is built without replays."""
    lap = drive_lap(track, 0.85, None, vehicle_config, env_config.dt, env_config.start_speed_m_s,
                    env_config.car_width_m)
    if not lap.valid:
        raise RuntimeError(f"the scripted driver could not complete {track.name} (excursion "
                           f"{lap.max_edge_excursion_m:.2f} m, finished={lap.finished})")
    return [lap.replay()]
