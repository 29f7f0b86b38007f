"""`make-track`: compile a track source into a track artifact and record opponent replays.

Artifacts written (aliases in brackets):

- kind `track` [`track/<name>`]: `track.npz` (centreline samples, barriers, finish, grid) and the
  source it was compiled from (`source.yaml` or `source.csv`);
- kind `replay` [`track/<name>/opponents/<i>`], input: the track: `replay.mcap`, an episode log
  of the scripted driver at pace `pace_i` on its own line, labelled with pace and finish time.

Everything is deterministic in (source, config, seed), so running it twice gives the same ids.

A track and its replays appear together or not at all: the aliases are written only after every
replay is stored (a lease keeps the unaliased artifacts from a concurrent gc meanwhile), and
consumers (`opponents_of`) use only a complete set of replays, `opponents.count` of them, as
recorded in the replays' own config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.artifacts.store import alias_problem
from d2a_core.config import ResolvedConfig
from d2a_core.errors import UsageError
from d2a_core.sim.episode_log import CarPose, EpisodeRecorder
from d2a_core.sim.opponents import Lap, drive_lap, line_profile
from d2a_core.sim.recording import scene_of
from d2a_core.tracks.sources import TrackSource, load_track_source
from d2a_core.tracks.track import Track
from d2a_core.tracks.track_file import save_track

ProgressFn = Callable[[str, int, int], None]
LINE_ATTEMPTS = 5
# the sections a track and its replays depend on; nothing else changes their ids
TRACK_SECTIONS = ("tracks",)
REPLAY_SECTIONS = ("tracks", "opponents", "driver", "vehicle", "env", "episode_log")


@dataclass
class OpponentResult:
    id: str
    index: int
    pace: float
    finish_time_s: float

    def as_dict(self) -> dict[str, Any]:
        return {"id": self.id, "index": self.index, "pace": self.pace, "finish_time_s": self.finish_time_s}


def write_lap_log(path: Path, track: Track, lap: Lap, dt: float, metadata: dict[str, Any], log_config) -> None:
    """Record a driven lap as an episode log whose `/state/opponent` channel is a replay."""
    a = lap.arrays
    with EpisodeRecorder(path, scene_of(track), metadata, dt, config=log_config) as rec:
        for k in range(len(a["t"])):
            pose = CarPose(x=float(a["x"][k]), y=float(a["y"][k]), z=float(a["z"][k]), yaw=float(a["yaw"][k]))
            rec.log_step(float(a["t"][k]), {"opponent": pose}, {"opponent": {
                "speed": float(a["speed"][k]), "s": float(a["s"][k]), "e": float(a["e"][k]),
                "vx": float(a["vx"][k]), "vy": float(a["vy"][k]), "yaw_rate": float(a["yaw_rate"][k]),
                "slip_front": float(a["slip_front"][k]), "slip_rear": float(a["slip_rear"][k]),
                "action": {"steer": float(a["steer"][k]), "accel": float(a["accel"][k])},
            }})


def paces(count: int, low: float, high: float) -> list[float]:
    """Evenly spread paces from low to high (one value when count is 1)."""
    if count == 1:
        return [round(0.5 * (low + high), 4)]
    return [round(float(p), 4) for p in np.linspace(low, high, count)]


# room a car needs beside its own width on the narrowest stretch of road (each side)
EDGE_ROOM_M = 0.3


def check_drivable(track: Track, vehicle, car_width_m: float, source: str) -> None:
    """Fail where the road is impossible for any car, before opponents try and fail to drive it.

    A bend tighter than the car's kinematic turning circle (wheelbase / tan(full lock)) cannot be
    followed at any speed, and a road narrower than the car cannot be driven on at all.
    """
    min_radius = vehicle.wheelbase_m / math.tan(vehicle.max_steer_rad)
    curvature = np.abs(np.asarray(track.curvature)[: np.searchsorted(track.s, track.finish_s) + 1])
    if len(curvature) and float(np.max(curvature)) * min_radius > 1.0:
        k = int(np.argmax(curvature))
        raise UsageError(f"{source}: the bend at s={track.s[k]:.1f} m has a radius of {1 / curvature[k]:.1f} m; the car "
                         f"turns no tighter than {min_radius:.1f} m (vehicle.max_steer_rad), so no driver can follow it")
    width = np.asarray(track.w_left) + np.asarray(track.w_right)
    need = car_width_m + 2 * EDGE_ROOM_M
    if float(np.min(width)) < need:
        k = int(np.argmin(width))
        raise UsageError(f"{source}: the road is {width[k]:.2f} m wide at s={track.s[k]:.1f} m; a "
                         f"{car_width_m:.2f} m car needs at least {need:.2f} m")


def make_track(
    store: Store,
    source: str,
    resolved: ResolvedConfig,
    seed: int,
    start_m: float | None = None,
    length_m: float | None = None,
    name: str | None = None,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Build the track and its opponents; returns the JSON result of `d2a make-track`."""
    cfg = resolved.config
    src: TrackSource = load_track_source(source, start_m=start_m, length_m=length_m, name=name,
                                         config=cfg.tracks)
    track = src.track
    problem = alias_problem(f"track/{track.name}")
    if problem:  # checked before anything is written: the alias is the last thing make-track writes
        raise UsageError(f"track name {track.name!r} cannot name an alias ({problem}); give another with --name")
    check_drivable(track, cfg.vehicle, cfg.env.car_width_m, str(src.path))
    track_config = resolved.section(*TRACK_SECTIONS)
    with store.lease(), store.scratch_dir("make-track") as tmp:
        tmp = Path(tmp)
        npz = tmp / "track.npz"
        save_track(track, npz)
        labels = {"name": track.name, "length_m": round(track.length, 3), "finish_s": track.finish_s,
                  "elevation_range_m": round(track.elevation_range, 3), "source": src.description}
        track_art = store.put("track", {"track.npz": npz, f"source{src.suffix}": src.raw},
                              config=track_config, seed=None, labels=labels)

        opp_cfg = cfg.opponents
        rng = np.random.default_rng(seed)
        results: list[OpponentResult] = []
        env = cfg.env
        pace_list = paces(opp_cfg.count, opp_cfg.pace_min, opp_cfg.pace_max)
        for index, pace in enumerate(pace_list):
            if progress:
                progress(f"opponent {index + 1}/{len(pace_list)} (pace {pace:.2f})", index, len(pace_list))
            lap = None
            for _ in range(LINE_ATTEMPTS):  # a wild line may not be drivable at this pace: draw another
                line = line_profile(track, rng, opp_cfg.line_offset_max_m, env.car_width_m)
                lap = drive_lap(track, pace, line, cfg.vehicle, env.dt, env.start_speed_m_s, env.car_width_m,
                                cfg.driver)
                if lap.valid:
                    break
            else:
                line = np.zeros(track.n_samples)  # fall back to the centre line
                lap = drive_lap(track, pace, line, cfg.vehicle, env.dt, env.start_speed_m_s, env.car_width_m,
                                cfg.driver)
            if not lap.valid:
                # the geometry passed check_drivable, so the pace or the line is what fails: say where
                where = f"stopped at s={float(lap.arrays['s'][-1]):.1f} m" if not lap.finished else \
                    f"came {max(lap.max_edge_excursion_m, 0):.2f} m past a road edge"
                raise UsageError(
                    f"{src.path}: opponent {index} at pace {pace} could not drive track {track.name!r} even on the "
                    f"centre line ({where}); lower opponents.pace_max or ease the track there"
                )
            meta = {"kind": "opponent-replay", "track": track.name, "track_id": track_art.id, "index": index,
                    "pace": pace, "finish_time_s": lap.finish_time_s, "seed": seed}
            log_path = tmp / f"replay{index}.mcap"
            write_lap_log(log_path, track, lap, env.dt, meta, cfg.episode_log)
            replay_labels = {"track": track.name, "index": index, "pace": pace,
                             "finish_time_s": round(lap.finish_time_s, 3),
                             "line_offset_mean_m": round(float(np.mean(lap.line_offset)), 3),
                             "max_speed_m_s": round(float(np.max(lap.arrays["speed"])), 3)}
            art = store.put("replay", {"replay.mcap": log_path}, inputs=[track_art.id],
                            config=resolved.section(*REPLAY_SECTIONS), seed=seed, labels=replay_labels)
            results.append(OpponentResult(art.id, index, pace, float(lap.finish_time_s)))
        # all replays are stored: now name them, the track last (a kill before this leaves only
        # unaliased artifacts, which the next run reuses and gc collects)
        for result in results:
            store.tag(result.id, f"track/{track.name}/opponents/{result.index}")
        store.tag(track_art.id, f"track/{track.name}")
        if progress:
            progress("done", len(pace_list), len(pace_list))
    return {
        "id": track_art.id,
        "name": track.name,
        "alias": f"track/{track.name}",
        "length_m": round(track.finish_s, 3),
        "centreline_length_m": round(track.length, 3),
        "elevation_range_m": round(track.elevation_range, 3),
        "barriers": len(track.barriers),
        "opponents": [r.as_dict() for r in results],
    }

