"""Benchmark of `d2a eval`: wall time and env steps/s of a paired evaluation, against the bare
simulator in the same process.

Runs `d2a_core.pipelines.evaluate.evaluate` (the code behind `d2a eval`) on assistants and
populations already in a store, then steps the same track's `RaceEnv` alone with a fixed action
for as many steps, and prints one JSON object: the evaluation's wall time, episodes and env steps,
its env steps/s, the bare env's steps/s, and their ratio (the share of the bare env's speed the
whole protocol keeps: humans, assistants, MCAP logs and storing included). The target: a
`quick` evaluation (one seed, two methods, 20 episodes per human) in <= 5 min on 2 cores.

    python benchmarks/evaluate.py --store /tmp/grid/store --baseline dreamer --seed 0 \\
        --humans PASS_POP --humans STAY_POP --episodes 20

An evaluation is stored under a key that includes `--eval-seed` (default 1000); a second call with
the same arguments is answered from the store (`"cached": true` in the output), so change the
eval seed to measure again.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import time

import numpy as np

from d2a_core import mkl_on_amd

mkl_on_amd.enable()  # as the d2a command line does, before torch loads MKL
import torch  # noqa: E402

from d2a_core.artifacts import Store
from d2a_core.pipelines.evaluate import evaluate
from d2a_core.sim.race_env import RaceEnv
from d2a_core.run_inputs import load_track_bundle


def _bare_env_steps_per_s(store: Store, track: str, steps: int) -> float:
    """Steps/s of `RaceEnv` alone (default configs, one env, a constant half-throttle action)."""
    bundle = load_track_bundle(store, track, 0.1)
    env = RaceEnv(bundle.track, bundle.replays, intent="pass")
    action = np.array([0.0, 0.5], np.float32)
    env.reset(seed=0)
    start, done = time.perf_counter(), 0
    while done < steps:
        _, _, terminated, truncated, _ = env.step(action)
        done += 1
        if terminated or truncated:
            env.reset(seed=done)
    elapsed = time.perf_counter() - start
    env.close()
    return done / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", default=os.environ.get("D2A_STORE", "artifacts"))
    parser.add_argument("--track", default="straightaway")
    parser.add_argument("--pair", default="pass-stay")
    parser.add_argument("--method", default="dream2assist")
    parser.add_argument("--baseline", action="append", default=[])
    parser.add_argument("--seed", type=int, action="append", default=None, help="assistant training seed")
    parser.add_argument("--humans", action="append", default=None)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--eval-seed", type=int, default=1000)
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    store = Store(args.store)
    cpu0, wall0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    result = evaluate(store, args.track, args.pair, method=args.method, baselines=args.baseline, seeds=args.seed,
                      humans=args.humans, episodes=args.episodes, eval_seed=args.eval_seed, n_envs=args.envs)
    wall = time.perf_counter() - wall0
    cpu1 = resource.getrusage(resource.RUSAGE_SELF)
    episodes = steps = 0
    unassisted_counted = False
    for e in result["evaluations"]:
        stored = store.read_json(e["id"], "eval.json")
        rows = stored["assisted"] + ([] if unassisted_counted else stored["unassisted"])
        unassisted_counted = True  # the unassisted episodes run once per call, shared by every assistant
        episodes += len(rows)
        steps += int(sum(r["steps"] for r in rows))
    eval_rate = steps / wall
    bare_rate = _bare_env_steps_per_s(store, args.track, min(max(steps // 10, 500), 5000))
    print(json.dumps({
        "benchmark": "evaluate",
        "cached": any(e.get("cached") for e in result["evaluations"]),
        "evaluations": [{"method": e["method"], "seed": e["seed"], "id": e["id"]} for e in result["evaluations"]],
        "episodes": episodes,
        "env_steps": steps,
        "wall_s": round(wall, 2),
        "cpu_s": round((cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime), 2),
        "eval_env_steps_per_s": round(eval_rate, 1),
        "bare_env_steps_per_s": round(bare_rate, 1),
        "ratio_to_bare_env": round(eval_rate / bare_rate, 3),
        "envs": args.envs,
        "torch_threads": torch.get_num_threads(),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "torch": torch.__version__},
    }))


if __name__ == "__main__":
    main()
