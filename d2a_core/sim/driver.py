"""A scripted racing driver: a speed profile from curvature and the tyre limit, plus path tracking.

`make-track` uses it to record opponent laps at a chosen pace (a fraction of the tyre limit) on a
chosen line (a lateral offset profile). It is a classic two-part controller:

- speed: the fastest speed the line's curvature allows at `pace * mu * g` lateral acceleration,
  limited by braking (backward pass) and by the engine (forward pass) so the profile is drivable;
  a proportional controller with a short preview follows it, and the throttle never exceeds
  `pace`, so slower opponents also accelerate more gently on straights;
- steering: pure pursuit toward a point on the line a speed-dependent distance ahead, plus a
  yaw-rate damping term that keeps the car settled at the limit.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from d2a_core.config.section import Section
from d2a_core.sim.vehicle import VehicleConfig, VehicleState
from d2a_core.tracks.track import Track


class DriverConfig(Section):
    """Gains and margins of the scripted driver (opponent replays)."""

    lookahead_min_m: float = Field(6.0, gt=0, description="pure-pursuit lookahead at standstill")
    lookahead_time_s: float = Field(0.45, ge=0, description="lookahead grows by speed times this")
    speed_gain: float = Field(0.35, gt=0, description="accel command per m/s of speed error")
    speed_preview_s: float = Field(0.4, ge=0, description="read the speed profile this far ahead")
    yaw_damping: float = Field(0.05, ge=0, description="steer command per rad/s of yaw-rate error")
    grip_margin: float = Field(0.9, gt=0, le=1, description="share of peak mu the profile plans with")
    brake_margin: float = Field(0.7, gt=0, le=1, description="share of the planned grip used to brake")
    curvature_window_m: float = Field(8.0, ge=0, description="smoothing of the line curvature")


def _smooth(values: np.ndarray, window: int) -> np.ndarray:
    if window <= 1:
        return values
    kernel = np.ones(window) / window
    padded = np.pad(values, (window // 2, window - 1 - window // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


class LineFollower:
    """Drives one car along `track` at `pace` on the line `e = line_offset(s)` (an array over track.s)."""

    def __init__(
        self,
        track: Track,
        vehicle: VehicleConfig,
        pace: float,
        line_offset: np.ndarray | None = None,
        config: DriverConfig | None = None,
    ) -> None:
        self.track = track
        self.vehicle = vehicle
        self.pace = float(pace)
        self.config = config or DriverConfig()
        n = track.n_samples
        self.line_offset = np.zeros(n) if line_offset is None else np.asarray(line_offset, dtype=float)
        if self.line_offset.shape != (n,):
            raise ValueError(f"line_offset must have one value per track sample ({n})")
        lx, ly, _ = track.from_frenet(track.s, self.line_offset)
        self._line_x = np.asarray(lx).tolist()
        self._line_y = np.asarray(ly).tolist()
        self.speed_profile = self._speed_profile(np.asarray(lx), np.asarray(ly))
        self._profile = self.speed_profile.tolist()
        self._inv_spacing = 1.0 / track.spacing
        self._n = n

    def _line_curvature(self, lx: np.ndarray, ly: np.ndarray) -> np.ndarray:
        heading = np.unwrap(np.arctan2(np.gradient(ly), np.gradient(lx)))
        curvature = np.gradient(heading) / self.track.spacing
        window = max(1, int(round(self.config.curvature_window_m / self.track.spacing)))
        return _smooth(curvature, window)

    def _speed_profile(self, lx: np.ndarray, ly: np.ndarray) -> np.ndarray:
        v = self.vehicle
        g = v.gravity_m_s2
        mu = min(v.front_tyre.d_peak_mu, v.rear_tyre.d_peak_mu) * self.config.grip_margin * self.pace
        kappa = np.abs(self._line_curvature(lx, ly))
        top = self._top_speed()
        profile = np.minimum(np.sqrt(mu * g / np.maximum(kappa, 1e-6)), top)
        ds = self.track.spacing
        a_brake = mu * g * self.config.brake_margin
        for i in range(len(profile) - 2, -1, -1):  # braking: reach the next sample's speed in time
            profile[i] = min(profile[i], math.sqrt(profile[i + 1] ** 2 + 2 * a_brake * ds))
        return profile

    def _top_speed(self) -> float:
        """Speed where the engine power just balances drag and rolling resistance (bisection)."""
        v = self.vehicle
        g = v.gravity_m_s2

        def surplus(speed: float) -> float:
            resist = 0.5 * v.air_density_kg_m3 * v.drag_area_m2 * speed**2 + v.rolling_resistance * v.mass_kg * g
            return v.engine_power_w - resist * speed

        lo, hi = 1.0, 200.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if surplus(mid) > 0 else (lo, mid)
        return lo

    def target_speed(self, s: float) -> float:
        i = int(s * self._inv_spacing)
        return self._profile[min(max(i, 0), self._n - 1)]

    def act(self, state: VehicleState, s: float) -> tuple[float, float]:
        """(steer_cmd, accel_cmd) in [-1, 1] for the car in `state` at track position `s`."""
        cfg = self.config
        speed = state.speed
        lookahead = cfg.lookahead_min_m + cfg.lookahead_time_s * speed
        i = int((s + lookahead) * self._inv_spacing)
        i = min(max(i, 0), self._n - 1)
        dx = self._line_x[i] - state.x
        dy = self._line_y[i] - state.y
        cos_yaw, sin_yaw = math.cos(state.yaw), math.sin(state.yaw)
        ahead = cos_yaw * dx + sin_yaw * dy
        left = -sin_yaw * dx + cos_yaw * dy
        dist_sq = max(ahead * ahead + left * left, 1e-6)
        wheelbase = self.vehicle.wheelbase_m
        curvature = 2.0 * left / dist_sq  # pure pursuit: the arc through the target point
        delta = math.atan(wheelbase * curvature)
        delta -= cfg.yaw_damping * (state.yaw_rate - curvature * speed)
        steer = max(-1.0, min(1.0, delta / self.vehicle.steer_lock_rad(speed)))

        v_target = self.target_speed(s + speed * cfg.speed_preview_s)
        accel = cfg.speed_gain * (v_target - speed)
        accel = max(-1.0, min(self.pace, accel))
        return steer, accel
