"""Wall time of `d2a reproduce` and how it scales with `--jobs`; prints JSON.

    python benchmarks/grid.py [--preset smoke] [--seeds 3] [--method dreamer] [--jobs 1 2] [--repeats 2]

Each repeat runs the same grid from an empty store once per `--jobs` value, alternating the
values so that a change in the machine's load hits them alike, then runs the last one again to
time a rerun of a finished grid (nothing to do). Reported per `--jobs`: the command's wall time
(best and every repeat) and the sum of its cells' own times; `speedup` is the best `--jobs 1`
time over each best time, measured in this process's runs, so it is a ratio on a noisy machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def run_grid(store: Path, args: argparse.Namespace, jobs: int) -> tuple[float, dict]:
    cmd = [sys.executable, "-m", "d2a_cli", "--store", str(store), "--json", "reproduce", "--preset", args.preset,
           "--track", args.track, "--pair", args.pair, "--seeds", str(args.seeds), "--jobs", str(jobs)]
    for method in args.method:
        cmd += ["--method", method]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(f"grid failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return seconds, json.loads(proc.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--preset", default="smoke")
    parser.add_argument("--track", default="straightaway")
    parser.add_argument("--pair", default="pass-stay")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--method", action="append", default=None)
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    args.method = args.method or ["dreamer"]

    walls: dict[int, list[float]] = {j: [] for j in args.jobs}
    cell_sums: dict[int, list[float]] = {j: [] for j in args.jobs}
    cells, rerun = 0, None
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            order = args.jobs if repeat % 2 == 0 else list(reversed(args.jobs))
            for jobs in order:
                store = Path(tmp) / f"store-{repeat}-{jobs}"
                seconds, result = run_grid(store, args, jobs)
                walls[jobs].append(round(seconds, 2))
                cell_sums[jobs].append(round(sum(c.get("seconds") or 0 for c in result["cells"]), 2))
                cells = len(result["cells"])
        rerun, again = run_grid(store, args, args.jobs[-1])
        assert all(c["status"] == "done" for c in again["cells"]), "a finished grid ran cells again"
    base = min(walls[args.jobs[0]])
    print(json.dumps({
        "grid": {"preset": args.preset, "track": args.track, "pair": args.pair, "seeds": args.seeds,
                 "methods": args.method, "cells": cells},
        "cpus": os.cpu_count(), "load_average": [round(x, 2) for x in os.getloadavg()],
        "jobs": {str(j): {"best_s": min(walls[j]), "wall_s": walls[j], "cells_sum_s": cell_sums[j],
                          "speedup": round(base / min(walls[j]), 3)} for j in args.jobs},
        "rerun_finished_s": round(rerun, 2),
    }, indent=2))


if __name__ == "__main__":
    main()
