"""Environment steps/s for one `d2a/Race-v0` env (two cars, contacts, edge points) and a batch.

    python benchmarks/sim.py [--track hairpin] [--steps 20000] [--batch 8]

A simple observation-based controller drives (steer toward the middle of the road 20 m ahead,
moderate throttle), so episodes are realistic: both cars on track, opponent nearby, resets
included. Policy time is excluded. `vehicle_steps_per_s` is the bare vehicle model measured in
the same process, a reference for how busy the machine is.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from d2a_core.sim import make_vector_env
from d2a_core.sim.race_env import RaceEnv
from d2a_core.sim.vehicle import Vehicle


def _controller(names: list[str]):
    lx, ly = names.index("left_edge_20m_x"), names.index("left_edge_20m_y")
    rx, ry = names.index("right_edge_20m_x"), names.index("right_edge_20m_y")

    def act(obs: np.ndarray) -> np.ndarray:
        mx, my = 0.5 * (obs[..., lx] + obs[..., rx]), 0.5 * (obs[..., ly] + obs[..., ry])
        steer = np.clip(2.0 * np.arctan2(my, mx), -1, 1)
        return np.stack([steer, np.full_like(steer, 0.45)], axis=-1).astype(np.float32)

    return act


def bench_single(track: str, steps: int) -> float:
    env = RaceEnv(track, intent="pass")
    act = _controller(env.observation_names)
    obs, _ = env.reset(seed=0)
    actions = []
    busy = 0.0
    episode = 0
    for _ in range(steps):
        a = act(obs)
        start = time.perf_counter()
        obs, _, term, trunc, _ = env.step(a)
        if term or trunc:
            episode += 1
            obs, _ = env.reset(seed=episode)
        busy += time.perf_counter() - start
        actions.append(a)
    env.close()
    return steps / busy


def bench_batch(track: str, steps: int, batch: int) -> float:
    envs = make_vector_env(batch, track=track, intent="pass")
    act = _controller(envs.envs[0].unwrapped.observation_names)
    obs, _ = envs.reset(seed=0)
    busy = 0.0
    for _ in range(steps // batch):
        a = act(obs)
        start = time.perf_counter()
        obs, *_ = envs.step(a)
        busy += time.perf_counter() - start
    envs.close()
    return (steps // batch) * batch / busy


def bench_vehicle(steps: int) -> float:
    vehicle = Vehicle()
    vehicle.reset(0.0, 0.0, 0.0, 30.0)
    start = time.perf_counter()
    for k in range(steps):
        vehicle.step(0.3 * math.sin(0.05 * k), 0.5, 0.0, 0.1)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--track", default="hairpin")
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--batch", type=int, default=8)
    args = parser.parse_args()
    single = bench_single(args.track, args.steps)
    batch = bench_batch(args.track, args.steps, args.batch)
    vehicle = bench_vehicle(args.steps)
    print(json.dumps({
        "benchmark": "sim",
        "track": args.track,
        "env_steps_per_s": round(single),
        "batch": args.batch,
        "batch_env_steps_per_s": round(batch),
        "vehicle_steps_per_s": round(vehicle),
        "env_step_vs_vehicle_step_cost": round(vehicle / single, 2),
    }))


if __name__ == "__main__":
    main()
