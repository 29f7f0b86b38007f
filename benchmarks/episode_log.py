"""Episode-log throughput: record N steps of 2 cars with 2 state channels, then read them back.

Prints one JSON object: recorded steps/s, file bytes per step and read-back steps/s.
Usage: python benchmarks/episode_log.py [--steps 20000]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from d2a_core.sim.episode_log import CarPose, EpisodeRecorder, StaticScene, read_episode


def _ring(radius: float) -> np.ndarray:
    angle = np.linspace(0.0, 2.0 * math.pi, 721)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(angle)])


def _scene() -> StaticScene:
    """A 100 m circle drawn with 720 segments per line, like a detailed real track."""
    return StaticScene("bench-circle", _ring(106.0), _ring(94.0),
                       [(_ring(108.0), 1.0), (_ring(92.0), 1.0)],
                       np.array([[94.0, 0.0, 0.0], [106.0, 0.0, 0.0]]), _ring(100.0))


def _inputs(steps: int, dt: float) -> list[tuple[float, dict, dict]]:
    """Pre-built step inputs so the timing measures the recorder, not the test data."""
    rng = np.random.default_rng(0)
    out = []
    for k in range(steps):
        t = k * dt
        a, b = 0.3 * t, 0.29 * t + 0.1
        cars = {"ego": CarPose(100 * math.cos(a), 100 * math.sin(a), 0.6, a + math.pi / 2),
                "opp": CarPose(97 * math.cos(b), 97 * math.sin(b), 0.6, b + math.pi / 2)}
        noise = rng.normal(size=8).tolist()
        ego = {"s": 100 * a, "e": noise[0], "speed": 30.0, "vx": 30.0, "vy": noise[1],
               "yaw_rate": 0.3, "slip_front": noise[2], "slip_rear": noise[3], "steer": noise[4],
               "accel": noise[5],
               "action": {"human": [noise[4], noise[5]], "assistant": [noise[6], 0.0],
                          "applied": [noise[4] + noise[6], noise[5]]},
               "reward": {"task": noise[7], "pass": 0.0, "smooth": -0.01},
               "intent": "pass", "off_track": False}
        opp = {"s": 97 * b, "e": 0.0, "speed": 29.1, "vx": 29.1, "vy": 0.0, "yaw_rate": 0.29,
               "slip_front": 0.0, "slip_rear": 0.0, "steer": 0.01, "accel": 0.0}
        out.append((t, cars, {"ego": ego, "opp": opp}))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20_000)
    args = parser.parse_args()
    dt = 0.05
    inputs = _inputs(args.steps, dt)
    scene = _scene()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "bench.mcap"
        start = time.perf_counter()
        with EpisodeRecorder(path, scene, {"bench": True}, dt=dt) as recorder:
            for step in inputs:
                recorder.log_step(*step)
        record_s = time.perf_counter() - start
        size = path.stat().st_size
        start = time.perf_counter()
        episode = read_episode(path)
        read_s = time.perf_counter() - start
        assert len(episode) == args.steps
    print(json.dumps({
        "steps": args.steps,
        "cars": 2,
        "state_channels": 2,
        "record_steps_per_s": round(args.steps / record_s),
        "file_bytes_per_step": round(size / args.steps, 1),
        "read_steps_per_s": round(args.steps / read_s),
        "target_record_steps_per_s": 10_000,
    }))


if __name__ == "__main__":
    main()
