"""Throughput of the single-track vehicle model: control steps per second for one car.

The car drives a slalom-like command sequence (sinusoidal steering, throttle with periodic
braking, a gentle grade) so every branch of the model is exercised. Prints one JSON line:
``{"vehicle_steps_per_s": ..., "substeps": ..., "us_per_step": ..., "cpu_us_per_step": ...}``.

Run: ``python benchmarks/vehicle.py [--steps N]``.
"""

from __future__ import annotations

import argparse
import json
import math
import time

from d2a_core.sim.vehicle import Vehicle, VehicleConfig


def slalom_commands(n_steps: int) -> list[tuple[float, float, float]]:
    """Precomputed (steer, accel, grade) commands so the timing covers the model only."""
    commands = []
    for i in range(n_steps):
        t = 0.1 * i
        steer = 0.35 * math.sin(0.8 * t)
        accel = -0.6 if (i % 80) >= 70 else 0.6  # brake for 1 s every 8 s
        grade = 0.03 * math.sin(0.05 * t)
        commands.append((steer, accel, grade))
    return commands


def measure(n_steps: int, config: VehicleConfig | None = None, repeats: int = 3) -> dict:
    """Best-of-``repeats`` control steps per second over ``n_steps`` steps of the slalom."""
    vehicle = Vehicle(config)
    commands = slalom_commands(n_steps)
    best_wall = best_cpu = float("inf")
    for _ in range(repeats):
        vehicle.reset(0.0, 0.0, 0.0, 20.0)
        step = vehicle.step
        wall, cpu = time.perf_counter(), time.process_time()
        for steer, accel, grade in commands:
            step(steer, accel, grade, 0.1)
        best_wall = min(best_wall, time.perf_counter() - wall)
        best_cpu = min(best_cpu, time.process_time() - cpu)
    # Wall time is what a training loop sees; CPU time is less disturbed by other processes on a
    # shared machine.
    return {
        "vehicle_steps_per_s": round(n_steps / best_wall),
        "substeps": vehicle.config.substeps,
        "us_per_step": round(best_wall / n_steps * 1e6, 2),
        "cpu_us_per_step": round(best_cpu / n_steps * 1e6, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(json.dumps(measure(args.steps, repeats=args.repeats)))


if __name__ == "__main__":
    main()
