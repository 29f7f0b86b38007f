"""`d2a/Race-v0`: one ego car against a replayed opponent on a compiled track.

Dynamics come from the project's single-track model (`vehicle`), the 3-D world (road, barriers,
contacts, camera) from pybullet (`world`), rewards from `d2a_core.objectives`.

Observation (a flat float32 `Box`; `observation_names()` lists every entry):

- ego state: x, y, vx, vy, speed, yaw rate, heading (cos, sin), heading relative to the track
  (cos, sin), front and rear tyre slip angles, steer angle, lateral offset e, distance travelled,
  time left until the time limit (s; the limit shapes the return, so the agent must see it);
- track edges: for each lookahead distance, the left and right edge points in the car frame;
- opponent: ds = s_ego - s_opp, de = e_ego - e_opp, its speed minus ours, its position in the car
  frame, its heading relative to ours (cos, sin), and whether it is still racing (once its replay
  has ended it has left the track: it is shown far ahead, `FAR_AHEAD_M` in the car frame, not
  at the car's own position);
- partner action (2 values): the other driver's last action under shared control, zeros when one
  agent drives alone. Never the intent.

Action `[steer, accel]` in [-1, 1]; accel < 0 brakes.

Shared control: a wrapper (see `shared_control.SharedControl`) computes the applied action
`clip(a_H + a_A, -1, 1)` itself, calls `set_partner_action(a)` with the action the observing agent
should see, then `step(applied)`. `info["applied_action"]` and `info["partner_action"]` record both.

Termination: collision with the opponent or a barrier (pybullet contacts), more than
`off_track_margin_m` beyond a road edge, or the finish line; truncation at the time limit. A step
has at most one outcome, in this order: collision, off track, finish (a car that crosses the line
while crashing or leaving the road has not finished, and is paid only the crash).
`info` carries every reward term and the quantities metrics need, so evaluation never re-simulates.

Reset options: `replay` (index), `intent`, `ego_s`/`ego_e`/`start_speed` (a custom start), and
`start_step` or `start_spread` for a start further along the race: the episode begins as if
`start_step` control steps had passed (`start_spread` f draws it uniformly from the first f of
the opponent's recorded race, from the env's seeded generator): the opponent at that point of
its replay, the ego the grid's distance behind it at the grid's lateral offset and the
opponent's speed, the time limit as it would stand. Training may spread starts this way so the
world model sees the far corners of a long track; evaluation starts from the grid.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from d2a_core.objectives.rewards import INTENTS, RewardConfig, StepQuantities, reward_terms
from d2a_core.sim.env_config import DEFAULT_LOOKAHEAD_M, EnvConfig
from d2a_core.sim.replay import OpponentReplay
from d2a_core.sim.vehicle import Vehicle, VehicleConfig
from d2a_core.sim.world import RaceWorld, WorldConfig
from d2a_core.tracks.track import Track

# where a finished opponent is shown, straight ahead in the car frame (beyond every lookahead)
FAR_AHEAD_M = 200.0


EGO_FIELDS = ("x", "y", "vx", "vy", "speed", "yaw_rate", "cos_yaw", "sin_yaw", "cos_track_yaw", "sin_track_yaw",
              "slip_front", "slip_rear", "steer", "e", "distance", "time_left")
OPPONENT_FIELDS = ("ds", "de", "dspeed", "opp_dx", "opp_dy", "opp_cos_dyaw", "opp_sin_dyaw", "opp_racing")
PARTNER_FIELDS = ("partner_steer", "partner_accel")


def observation_names(lookahead: tuple[float, ...] | list[float] = DEFAULT_LOOKAHEAD_M) -> list[str]:
    """Name of every observation entry, in order."""
    edges = [f"{side}_edge_{d:g}m_{axis}" for d in lookahead for side in ("left", "right") for axis in ("x", "y")]
    return [*EGO_FIELDS, *edges, *OPPONENT_FIELDS, *PARTNER_FIELDS]


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class RaceEnv(gym.Env):
    """See the module docstring. Build with `gym.make("d2a/Race-v0", track=..., replays=...)`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        track: Track | str | Path = "straightaway",
        replays: list[OpponentReplay] | None = None,
        intent: str | None = None,
        env_config: EnvConfig | None = None,
        reward_config: RewardConfig | None = None,
        vehicle_config: VehicleConfig | None = None,
        world_config: WorldConfig | None = None,
        render_mode: str | None = None,
    ) -> None:
        if intent is not None and intent not in INTENTS:
            raise ValueError(f"intent must be one of {INTENTS} or None, got {intent!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.cfg = env_config or EnvConfig()
        self.reward_cfg = reward_config or RewardConfig()
        self.vehicle_cfg = vehicle_config or VehicleConfig()
        self.track = track if isinstance(track, Track) else _load_track(track)
        if replays is None:
            from d2a_core.sim.opponents import default_replays

            replays = default_replays(self.track, self.cfg, self.vehicle_cfg)
        if not replays:
            raise ValueError("at least one opponent replay is needed")
        self.replays = list(replays)
        self.intent = intent
        self.render_mode = render_mode

        self.observation_names = observation_names(self.cfg.edge_lookahead_m)
        n_obs = len(self.observation_names)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(n_obs,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

        left, right = self.track.edges()
        self._edge_lists = (left[:, 0].tolist(), left[:, 1].tolist(), right[:, 0].tolist(), right[:, 1].tolist())
        self._lookahead_list = [float(d) for d in self.cfg.edge_lookahead_m]
        self._inv_spacing = 1.0 / self.track.spacing
        self._n_samples = self.track.n_samples
        world_cfg = world_config or WorldConfig()
        self.world = RaceWorld(
            left, right, self.track.barrier_polylines(),
            car_size=(self.cfg.car_length_m, self.cfg.car_width_m, self.cfg.car_height_m),
            n_cars=2, config=world_cfg,
        )
        self.vehicle = Vehicle(self.vehicle_cfg)
        self.time_limit_s = self.cfg.time_limit_s or (self.track.finish_s / 8.0)
        self._max_steps = int(math.ceil(self.time_limit_s / self.cfg.dt))
        self._partner_list = [0.0, 0.0]
        self._replay: OpponentReplay | None = None
        self._replay_index = -1
        self._teleport = True  # the next placement is a reset's: cars jump, no contact sweep

    # --------------------------------------------------------------------------------- API
    def set_partner_action(self, action: np.ndarray | None) -> None:
        """The partner's action shown in the next observation (zeros when driving alone)."""
        if action is None:
            self._partner_list = [0.0, 0.0]
        else:
            a = np.asarray(action, dtype=np.float64).reshape(2)
            self._partner_list = [min(1.0, max(-1.0, float(a[0]))), min(1.0, max(-1.0, float(a[1])))]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        index = options.get("replay")
        self._replay_index = int(self.np_random.integers(len(self.replays))) if index is None else int(index)
        self._replay = self.replays[self._replay_index]
        if "intent" in options:
            intent = options["intent"]
            if intent is not None and intent not in INTENTS:
                raise ValueError(f"intent must be one of {INTENTS} or None, got {intent!r}")
            self.intent = intent
        grid = self.track.start_grid.ego
        start_step = self._start_step(options)
        s0, e0 = float(options.get("ego_s", grid.s)), float(options.get("ego_e", grid.e))
        speed = float(options.get("start_speed", self.cfg.start_speed_m_s))
        if start_step:
            _, _, _, _, opp_speed, opp_s, _ = self._replay.at(start_step)
            s0 = opp_s - (self.track.start_grid.opponent.s - grid.s)
            speed = opp_speed
        x, y, _ = self.track.from_frenet(s0, e0)
        yaw = self.track.heading_at(s0)
        self.vehicle.reset(x, y, yaw, speed)
        self._step = start_step
        self._teleport = True
        self._s = s0
        self._e = e0
        self._s_start = s0
        self._partner_list = [0.0, 0.0]
        self._applied = (0.0, 0.0)
        self._place_cars()
        self._teleport = False
        self._ds = self._s - self._opp_s
        at_limit = self._replay.at(self._max_steps)
        self._opp_s_at_limit = self._replay.s_after_end(self._max_steps, self.cfg.dt) if at_limit is None else at_limit[5]
        return self._observation(), self._info(None, collision=(False, False), off_track=False, finished=False)

    def step(self, action):
        steer, accel = (float(v) for v in np.asarray(action, dtype=np.float64).reshape(2))
        if not (math.isfinite(steer) and math.isfinite(accel)):
            raise ValueError(f"action must be finite, got {action}")
        steer, accel = min(1.0, max(-1.0, steer)), min(1.0, max(-1.0, accel))
        self._applied = (steer, accel)
        state = self.vehicle.step(steer, accel, self._grade_along(self.vehicle.state.yaw), self.cfg.dt)
        self._step += 1
        s_prev, ds_prev = self._s, self._ds
        self._s, self._e = self.track.to_frenet(state.x, state.y, s_prev)
        self._place_cars()
        self._ds = self._s - self._opp_s
        hits = self.world.collisions()
        car_hit = bool(hits.car_car)
        barrier_hit = bool(hits.car_barrier[0])
        w_left, w_right = self.track.width_at(self._s)
        margin = self.cfg.off_track_margin_m
        off_track = self._e > w_left + margin or self._e < -(w_right + margin)
        collision = car_hit or barrier_hit
        off_track = off_track and not collision
        finished = self._s >= self.track.finish_s and not (collision or off_track)
        q = StepQuantities(s=self._s, s_prev=s_prev, ds=self._ds, ds_prev=ds_prev, de=self._e - self._opp_e,
                           collision=collision, off_track=off_track, finished=finished,
                           remaining_m=self._opp_s_at_limit - self._opp_s, opponent_racing=self._opp_racing)
        terms = reward_terms(q, self.reward_cfg)
        reward = terms.human(self.intent)
        terminated = collision or off_track or finished
        truncated = not terminated and self._step >= self._max_steps
        info = self._info(terms, collision=(car_hit, barrier_hit), off_track=off_track, finished=finished)
        return self._observation(), float(reward), terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self.world.render(self.cfg.render_view, car=0, width=self.cfg.render_width,
                                 height=self.cfg.render_height)

    def close(self) -> None:
        world = getattr(self, "world", None)
        if world is not None:
            world.close()
            self.world = None

    # --------------------------------------------------------------------------------- internals
    def _grade_along(self, yaw: float) -> float:
        """Road slope along the car's heading (the track grade projected on the heading)."""
        return self.track.grade_at(self._s) * math.cos(_wrap(yaw - self.track.heading_at(self._s)))

    def _start_step(self, options: dict[str, Any]) -> int:
        """The control step the episode starts at (0: the grid); see the module docstring."""
        racing_steps = len(self._replay) - 1  # the last step at which the opponent is still racing
        horizon = min(racing_steps, self._max_steps - 1)
        if "start_step" in options:
            step = int(options["start_step"])
            if not 0 <= step <= horizon:
                raise ValueError(f"start_step must be in [0, {horizon}] (the opponent races and time is left), got {step}")
            return step
        spread = float(options.get("start_spread", 0.0))
        if not 0.0 <= spread <= 1.0:
            raise ValueError(f"start_spread must be in [0, 1], got {spread}")
        if spread == 0.0:
            return 0  # no draw: the generator's stream is that of a grid start
        return int(self.np_random.integers(0, int(spread * horizon) + 1))

    def _place_cars(self) -> None:
        st = self.vehicle.state
        # the world takes the road height under the car and adds clearance and half the body height
        pitch = -math.atan(self.track.grade_at(self._s))
        self.world.set_car_pose(0, st.x, st.y, self.track.z_at(self._s), st.yaw, pitch=pitch,
                                teleport=self._teleport)
        row = self._replay.at(self._step)
        if row is None:  # the opponent's recording is over: it has finished and left the track
            self._opp_racing = False
            self._opp_s = self._replay.s_after_end(self._step, self.cfg.dt)
            self._opp_e = self._replay.e[-1]
            self._opp_row = None
            self.world.set_car_pose(1, 0.0, 0.0, -1000.0, 0.0, teleport=True)
        else:
            x, y, z, yaw, speed, s, e = row
            self._opp_racing = True
            self._opp_s, self._opp_e = s, e
            self._opp_row = row
            self.world.set_car_pose(1, x, y, z, yaw, pitch=-math.atan(self.track.grade_at(s)),
                                    teleport=self._teleport)

    def _observation(self) -> np.ndarray:
        # Plain Python floats throughout: for ~65 values, per-element numpy calls cost more than
        # the arithmetic, and one np.array() at the end is the only conversion.
        st = self.vehicle.state
        x, y, yaw = st.x, st.y, st.yaw
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        rel = _wrap(yaw - self.track.heading_at(self._s))
        values = [x, y, st.vx, st.vy, st.speed, st.yaw_rate, cos_yaw, sin_yaw, math.cos(rel), math.sin(rel),
                  st.slip_angle_front, st.slip_angle_rear, st.steer, self._e, self._s - self._s_start,
                  (self._max_steps - self._step) * self.cfg.dt]
        # edge points by linear interpolation between samples, in the car frame
        lx, ly, rx, ry = self._edge_lists
        inv, last = self._inv_spacing, self._n_samples - 2
        s = self._s
        for ahead in self._lookahead_list:
            pos = (s + ahead) * inv
            i = int(pos)
            if i < 0:
                i, f = 0, 0.0
            elif i > last:
                i, f = last, 1.0
            else:
                f = pos - i
            g = 1.0 - f
            for ex, ey in ((lx, ly), (rx, ry)):
                dx = ex[i] * g + ex[i + 1] * f - x
                dy = ey[i] * g + ey[i + 1] * f - y
                values.append(cos_yaw * dx + sin_yaw * dy)
                values.append(cos_yaw * dy - sin_yaw * dx)
        if self._opp_row is not None:
            ox, oy, _, oyaw, ospeed, _, _ = self._opp_row
            odx, ody = ox - x, oy - y
            dyaw = _wrap(oyaw - yaw)
            values += (self._ds, self._e - self._opp_e, ospeed - st.speed, cos_yaw * odx + sin_yaw * ody,
                       cos_yaw * ody - sin_yaw * odx, math.cos(dyaw), math.sin(dyaw), 1.0)
        else:
            values += (self._ds, self._e - self._opp_e, 0.0, FAR_AHEAD_M, 0.0, 1.0, 0.0, 0.0)
        values += self._partner_list
        return np.array(values, dtype=np.float32)

    def _info(self, terms, collision: tuple[bool, bool], off_track: bool, finished: bool) -> dict[str, Any]:
        st = self.vehicle.state
        return {
            "t": self._step * self.cfg.dt,
            "s": self._s,
            "e": self._e,
            "ds": self._ds,
            "de": self._e - self._opp_e,
            "progress": self._s - self._s_start,
            "speed": st.speed,
            "yaw_rate": st.yaw_rate,
            "sideslip": st.sideslip,
            "slip_front": st.slip_angle_front,
            "slip_rear": st.slip_angle_rear,
            "opponent_s": self._opp_s,
            "opponent_e": self._opp_e,
            "opponent_racing": self._opp_racing,
            "opponent_s_at_limit": self._opp_s_at_limit,
            "collision": collision[0] or collision[1],
            "collision_car": collision[0],
            "collision_barrier": collision[1],
            "off_track": off_track,
            "finished": finished,
            "ahead": self._ds > 0.0,
            "left_of_opponent": self._e > self._opp_e,
            "applied_action": np.array(self._applied, dtype=np.float32),
            "partner_action": np.array(self._partner_list, dtype=np.float32),
            "intent": self.intent,
            "replay": self._replay_index,
            "reward_terms": terms.as_dict() if terms is not None else None,
        }


def _load_track(track: str | Path) -> Track:
    from d2a_core.tracks.sources import load_track_source

    return load_track_source(str(track)).track
