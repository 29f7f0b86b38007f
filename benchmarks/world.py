"""Per-step cost of the pybullet race world; prints one JSON object.

Builds a ~1 km synthetic circuit (1 m spacing, hills, barriers on both sides), drives two cars along
it at race speed (one control step of 0.1 s per iteration) and times: placing both cars plus the
collision query (the env's per-step world cost), the collision query alone, a 20-ray batch, a
road-height ray, and TinyRenderer images at 84x84 and 256x256. Costs are CPU time per call.

Usage: python benchmarks/world.py [--steps 20000]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from d2a_core.sim.world import RaceWorld, WorldConfig


def _circuit(spacing: float = 1.0, half_width: float = 6.0):
    """A closed rounded-rectangle-ish loop with a wavy elevation profile."""
    t = np.arange(0.0, 2 * math.pi, spacing / 160.0)
    # superellipse: long straights and tight-ish corners
    x = 300.0 * np.sign(np.cos(t)) * np.abs(np.cos(t)) ** 0.5
    y = 120.0 * np.sign(np.sin(t)) * np.abs(np.sin(t)) ** 0.5
    z = 4.0 * np.sin(2 * t) + 2.0 * np.sin(5 * t)
    centre = np.stack([x, y, z], axis=1)
    centre = np.concatenate([centre, centre[:1]])  # closed: repeat the first point
    tangent = np.gradient(centre[:, :2], axis=0)
    tangent[0] = tangent[-1] = centre[1, :2] - centre[-2, :2]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0], np.zeros(len(centre))], axis=1)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    left, right = centre + half_width * normal, centre - half_width * normal
    barriers = [(centre + (half_width + 1.5) * normal, 1.0), (centre - (half_width + 1.5) * normal, 1.0)]
    return centre, normal, heading, left, right, barriers


def _per_call_us(fn, repeats: int) -> float:
    """CPU time per call in microseconds (process time: robust to other load on a shared machine)."""
    start = time.process_time()
    for _ in range(repeats):
        fn()
    return (time.process_time() - start) / repeats * 1e6


def _drive(world: RaceWorld, centre, normal, heading, steps: int, points_per_step: int, seed: int = 0):
    """Time ``steps`` control steps of two cars driving along the road: place both, query contacts.

    Car 1 follows 3-12 points behind car 0 and both weave across the road, passing within ~0.25 m
    of the barriers, so car-car contacts and (above ~25 m/s) barrier-crossing sweeps occur.
    Barrier contacts (which end an episode) are timed separately. Returns (us per step, counts).
    """
    n = len(centre) - 1
    rng = np.random.default_rng(seed)
    k = np.arange(steps)
    idx0 = (k * points_per_step) % n
    idx1 = (idx0 - rng.integers(3, 12, steps)) % n
    p0 = centre[idx0] + (6.3 * np.sin(k / 37.0))[:, None] * normal[idx0]
    p1 = centre[idx1] + (6.3 * np.sin(k / 23.0))[:, None] * normal[idx1]
    poses = list(zip(p0.tolist(), heading[idx0].tolist(), p1.tolist(), heading[idx1].tolist(), strict=True))
    set_pose, collisions = world.set_car_pose, world.collisions
    counts = {"car_car": 0, "car_barrier": 0}
    (x0, y0, z0), h0, (x1, y1, z1), h1 = poses[0]
    set_pose(0, x0, y0, z0, h0, teleport=True)  # a new run, not a move from the previous one
    set_pose(1, x1, y1, z1, h1, teleport=True)
    start = time.process_time()
    for (x0, y0, z0), h0, (x1, y1, z1), h1 in poses:
        set_pose(0, x0, y0, z0, h0, -0.02, 0.0)
        set_pose(1, x1, y1, z1, h1, -0.02, 0.0)
        report = collisions()
        counts["car_car"] += report.car_car
        counts["car_barrier"] += report.car_barrier[0] or report.car_barrier[1]
    return (time.process_time() - start) / steps * 1e6, counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    args = parser.parse_args()

    centre, normal, heading, left, right, barriers = _circuit()
    start = time.perf_counter()
    world = RaceWorld(left, right, barriers, n_cars=2)
    build_s = time.perf_counter() - start

    _drive(world, centre, normal, heading, 2000, 5)  # warm-up
    step = {}
    no_sweep = RaceWorld(left, right, barriers, n_cars=2, config=WorldConfig(sweep_barrier_crossing=False))
    for name, target in (("sweep_on", world), ("sweep_off", no_sweep)):
        for speed, points in (("20_m_s", 2), ("50_m_s", 5)):
            us, counts = _drive(target, centre, normal, heading, args.steps, points)
            step[f"{name}_{speed}"] = {
                "us": round(us, 2),
                "steps_with_car_contact": counts["car_car"],
                "steps_with_barrier_contact": counts["car_barrier"],
            }
    no_sweep.close()

    x0, y0, z0 = centre[200].tolist()
    h0 = float(heading[200])
    world.set_car_pose(0, x0, y0, z0, h0, teleport=True)
    world.set_car_pose(1, *centre[206].tolist(), float(heading[206]), teleport=True)
    set_pose_us = _per_call_us(
        lambda: world.set_car_pose(0, x0, y0, z0, h0, -0.02, 0.0, teleport=True), 20000
    )
    collisions_us = _per_call_us(world.collisions, 20000)
    barrier_face = 7.5 - 0.5 * world.car_size[1]
    touching = centre[206] - (barrier_face + 0.05) * normal[206]
    world.set_car_pose(1, *touching.tolist(), float(heading[206]), teleport=True)
    assert world.collisions().car_barrier[1]
    touching_us = _per_call_us(world.collisions, 5000)
    origin = np.array([x0, y0, z0 + 0.6])
    angles = np.linspace(-math.pi / 2, math.pi / 2, 20) + h0
    directions = np.stack([np.cos(angles), np.sin(angles), np.zeros(20)], axis=1)
    rays_us = _per_call_us(lambda: world.ray_distances(origin, directions, 50.0, exclude_car=0), 5000)
    road_height_us = _per_call_us(lambda: world.road_height(x0, y0), 20000)

    render_ms = {}
    for mode in ("chase", "birdseye"):
        for size in (84, 256):
            repeats = 40 if size == 84 else 10
            render_ms[f"{mode}_{size}x{size}"] = (
                _per_call_us(lambda m=mode, z=size: world.render(m, 0, z, z), repeats) / 1e3
            )
    world.close()
    print(
        json.dumps(
            {
                "track_points": len(centre),
                "build_world_s": round(build_s, 3),
                "steps": args.steps,
                "step_place_2_cars_plus_collisions": step,
                "set_car_pose_us": round(set_pose_us, 2),
                "collisions_us_2_cars_6_m_apart": round(collisions_us, 2),
                "collisions_us_one_car_5_cm_into_barrier": round(touching_us, 2),
                "ray_batch_20_rays_50_m_us": round(rays_us, 2),
                "road_height_us": round(road_height_us, 2),
                "render_ms": {k: round(v, 3) for k, v in render_ms.items()},
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
