"""Benchmark the track's Frenet queries as the simulator uses them; prints one JSON object.

The scalar `to_frenet` is timed on a drive along the track: a point every 0.1 s at 30 m/s with a
lateral weave, each call hinted with the previous answer (as the environment does). Also timed:
scalar `from_frenet`, `edge_points` for 10 look-ahead offsets, the vectorised `to_frenet` and
compiling the spec.

    python benchmarks/frenet.py [--track tracks/hairpin.yaml] [--calls 200000]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from d2a_core.tracks import build_track

REPO = Path(__file__).resolve().parents[1]


def _drive(track, count: int, speed: float = 30.0, dt: float = 0.1) -> tuple[list[float], list[float], list[float]]:
    """World points of a car weaving along the track, and the true s of each."""
    s_true = (np.arange(count) * speed * dt) % (track.finish_s - 1.0)
    w_left, w_right = track.width_at(s_true)
    weave = np.sin(np.arange(count) * 0.07)
    e_true = np.where(weave > 0, weave * w_left, weave * w_right) * 0.9
    x, y, _ = track.from_frenet(s_true, e_true)
    return x.tolist(), y.tolist(), s_true.tolist()


def _best_rate(run, calls: int, repeats: int = 3) -> float:
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return calls / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default=str(REPO / "tracks" / "hairpin.yaml"))
    parser.add_argument("--calls", type=int, default=200_000)
    args = parser.parse_args()

    start = time.perf_counter()
    track = build_track(args.track)
    build_s = time.perf_counter() - start

    xs, ys, s_true = _drive(track, args.calls)
    # The previous step's s; at each restart from the start line the env knows the start s.
    hints = [s if k == 0 or s < s_true[k - 1] else s_true[k - 1] for k, s in enumerate(s_true)]

    def scalar_to_frenet() -> None:
        to_frenet = track.to_frenet
        for x, y, hint in zip(xs, ys, hints):
            to_frenet(x, y, hint)

    def scalar_from_frenet() -> None:
        from_frenet = track.from_frenet
        for s in s_true:
            from_frenet(s, 1.5)

    offsets = np.linspace(2.0, 60.0, 10)
    edge_calls = min(args.calls, 50_000)

    def edges() -> None:
        edge_points = track.edge_points
        for s in s_true[:edge_calls]:
            edge_points(s, offsets)

    x_array, y_array = np.array(xs), np.array(ys)

    def vector_to_frenet() -> None:
        track.to_frenet(x_array, y_array, np.array(hints))

    # Accuracy of the timed calls, so a fast but wrong search would show.
    worst = max(abs(track.to_frenet(x, y, h)[0] - s) for x, y, h, s in zip(xs[:5000], ys[:5000], hints, s_true))
    result = {
        "track": Path(args.track).name,
        "samples": track.n_samples,
        "build_s": round(build_s, 4),
        "to_frenet_scalar_calls_per_s": round(_best_rate(scalar_to_frenet, args.calls)),
        "from_frenet_scalar_calls_per_s": round(_best_rate(scalar_from_frenet, args.calls)),
        "edge_points_10_calls_per_s": round(_best_rate(edges, edge_calls)),
        "to_frenet_vectorised_points_per_s": round(_best_rate(vector_to_frenet, args.calls)),
        "to_frenet_max_s_error_m": worst,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
