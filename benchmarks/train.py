"""Benchmark of full DreamerV3 updates (world model + actor-critic) on synthetic data.

Paper settings (batch 16 x 64, horizon 15, imagination from every replayed state), vector
observations of size 40 and 2 continuous actions. Prints one JSON object: updates/s after
warm-up and the world-model and behaviour seconds of each update, per model width.

    python benchmarks/train.py --units 128 512 --updates 5
    python benchmarks/train.py --loop-steps 4000        # the full loop on the straightaway
    python benchmarks/train.py --units 128 --deter 256 --latent 16 16 --obs-dim 98 \
        --imag-starts 256 128 256 128                                       # the `quick` model; starts

Each row also gives the floating-point work of one update (torch's FLOP counter: matmuls and
their gradients) and the GFLOP/s it achieves, and the report the machine's dense matmul GFLOP/s
measured in the same process: their ratio, `fraction_of_matmul_peak`, is how far the update is
from the CPU's own limit.

`--loop-steps N` instead runs the real training loop (8 race envs, the `quick` model, train
ratio 64, N env steps after a prefill) and reports the share of wall time spent simulating,
acting (policy inference and replay writes) and learning.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import gymnasium as gym
import numpy as np

from d2a_core import mkl_on_amd

mkl_on_amd.enable()  # before torch loads MKL (D2A_MKL_AMD=0 measures without it)
import torch  # noqa: E402

from d2a_core.agents.dreamer import DreamerAgent, DreamerConfig
from d2a_core.training.allocator import keep_freed_memory


def _fill_replay(agent: DreamerAgent, steps: int, envs: int, seed: int) -> None:
    """Synthetic transitions: random observations, actions and rewards, episodes of ~100 steps."""
    rng = np.random.default_rng(seed)
    for t in range(steps):
        agent.observe(
            {
                "obs": rng.normal(size=(envs, agent.obs_size)).astype(np.float32),
                "action": rng.uniform(-1, 1, size=(envs, agent.action_size)).astype(np.float32),
                "reward": rng.normal(size=envs).astype(np.float32),
                "is_first": rng.random(envs) < (1.0 if t == 0 else 0.01),
                "is_terminal": rng.random(envs) < 0.002,
            }
        )


def benchmark(units: int, deter: int, updates: int, warmup: int, args: argparse.Namespace,
              imag_starts: int | None = None) -> dict:
    """Time `updates` full updates of an agent of the given width after `warmup` updates."""
    config = DreamerConfig(
        units=units,
        deter=deter,
        stoch=args.latent[0],
        classes=args.latent[1],
        imag_starts=imag_starts,
        batch_size=args.batch_size,
        batch_length=args.batch_length,
        device=args.device,
        prefill_steps=0,
        replay_capacity=100_000,
    )
    agent = DreamerAgent(
        gym.spaces.Box(-np.inf, np.inf, (args.obs_dim,), np.float32),
        gym.spaces.Box(-1.0, 1.0, (args.action_dim,), np.float32),
        config,
        seed=0,
    )
    _fill_replay(agent, steps=400, envs=8, seed=0)
    params = sum(p.numel() for m in (agent.world_model, agent.behavior.actor, agent.behavior.critic) for p in m.parameters())
    for _ in range(warmup):
        agent.train_step()
    totals, world, behavior = [], [], []
    for _ in range(updates):
        start = time.perf_counter()
        metrics = agent.train_step()
        if agent.device.type == "cuda":
            torch.cuda.synchronize()
        totals.append(time.perf_counter() - start)
        world.append(metrics["time/world_model_s"])
        behavior.append(metrics["time/behavior_s"])
    median = statistics.median(totals)
    flops = update_flops(agent)
    profile = phase_profile(agent, updates) if args.profile else None
    return {
        "units": units,
        "deter": deter,
        "parameters": params,
        "updates_timed": updates,
        "updates_per_s": 1.0 / median,
        "seconds_per_update_median": median,
        "seconds_per_update_min": min(totals),
        "seconds_per_update_max": max(totals),
        "world_model_s_median": statistics.median(world),
        "behavior_s_median": statistics.median(behavior),
        "gflop_per_update": flops["total"] / 1e9,
        "gflop_world_model": flops["world_model"] / 1e9,
        "gflop_behavior": (flops["total"] - flops["world_model"]) / 1e9,
        "achieved_gflop_per_s": flops["total"] / 1e9 / median,
        **({"profile": profile} if profile else {}),
    }


def update_flops(agent: DreamerAgent) -> dict[str, int]:
    """Floating-point operations of one full update and of its world-model part, as torch's
    FLOP counter counts them (matmuls and their gradients; the compiled elementwise kernels and
    the one-hot latents' embedding-bag lookups are not counted, so this is a lower bound)."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as total:
        agent.train_step()
    with FlopCounterMode(display=False) as world:
        agent.world_model_update()
    return {"total": total.get_total_flops(), "world_model": world.get_total_flops()}


def matmul_gflops(size: int, device: str, repeats: int = 20) -> float:
    """The machine's dense float32 matmul rate (GFLOP/s) at size x size, with the benchmark's
    threads: the best of `repeats` timed products after a warm-up, the roof of the figure."""
    a = torch.randn(size, size, device=device)
    b = torch.randn(size, size, device=device)
    for _ in range(3):
        a @ b
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - start)
    return 2 * size**3 / best / 1e9


class _PhaseClock:
    """Wall time of each phase of an update, by wrapping (in this process only) the calls that
    make it: the replay sample, the world model's loss, imagination, the critic and actor terms,
    each backward pass (in `train_step`'s order: world model, actor, critic) and each optimiser
    step. What no wrapper covers (gradient clipping, metrics, Python between the calls) is `rest`."""

    def __init__(self, agent: DreamerAgent) -> None:
        self.seconds: dict[str, float] = {}
        self._backwards = 0
        self._restore: list[tuple[object, str, dict]] = []
        behavior = agent.behavior
        self._wrap(agent.replay, "sample", "replay_sample")
        self._wrap(agent.world_model, "loss", "world_model_forward")
        self._wrap(behavior, "_imagine", "imagination")
        self._wrap(behavior, "_critic_and_policy_terms", "critic_actor_terms")
        for name, opt in (("model", agent.model_opt), ("actor", agent.actor_opt), ("critic", agent.critic_opt)):
            self._wrap(opt, "step", f"optimiser_{name}")
        self._wrap(torch.autograd, "backward", None)

    def _wrap(self, owner, attr: str, phase: str | None) -> None:
        inner = getattr(owner, attr)
        clock = self

        def timed(*args, **kwargs):
            label = phase
            if label is None:  # backward passes come in train_step's order
                label = ("world_model_backward", "actor_backward", "critic_backward")[clock._backwards % 3]
                clock._backwards += 1
            start = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                clock.seconds[label] = clock.seconds.get(label, 0.0) + time.perf_counter() - start

        # what the owner itself held: a module's function, or nothing (an instance's bound method)
        own = {attr: vars(owner)[attr]} if attr in vars(owner) else {}
        self._restore.append((owner, attr, own))
        setattr(owner, attr, timed)

    def close(self) -> None:
        for owner, attr, own in reversed(self._restore):
            if own:
                setattr(owner, attr, own[attr])
            else:
                delattr(owner, attr)


def phase_profile(agent: DreamerAgent, updates: int) -> dict:
    """Seconds per update by phase (`_PhaseClock`), and the share of the update's wall time spent
    inside torch operators (the profiler's self CPU time of all aten ops and custom autograd
    functions) rather than in Python and dispatch between them."""
    clock = _PhaseClock(agent)
    try:
        start = time.perf_counter()
        for _ in range(updates):
            agent.train_step()
        wall = (time.perf_counter() - start) / updates
    finally:
        clock.close()
    phases = {name: seconds / updates for name, seconds in sorted(clock.seconds.items())}
    phases["rest"] = wall - sum(phases.values())
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        started = time.perf_counter()
        agent.train_step()
        profiled_wall = time.perf_counter() - started
    ops = sum(e.self_cpu_time_total for e in prof.key_averages()) / 1e6
    top = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)[:12]
    return {
        "seconds_per_update": wall,
        "phases_s": phases,
        "profiled_update_s": profiled_wall,
        "operator_share": ops / profiled_wall,
        "top_operators_s": {e.key: e.self_cpu_time_total / 1e6 for e in top},
    }


class _TimedEnv:
    """Delegates to an env and adds the time spent in its reset and step to `clock[0]`."""

    def __init__(self, env, clock: list[float]):
        self._env, self._clock = env, clock

    def __getattr__(self, name):
        return getattr(self._env, name)

    def reset(self, **kwargs):
        start = time.perf_counter()
        try:
            return self._env.reset(**kwargs)
        finally:
            self._clock[0] += time.perf_counter() - start

    def step(self, action):
        start = time.perf_counter()
        try:
            return self._env.step(action)
        finally:
            self._clock[0] += time.perf_counter() - start


def full_loop(args: argparse.Namespace) -> dict:
    """Wall-time shares of simulation, acting and learning in the training loop."""
    from d2a_core.sim.race_env import RaceEnv
    from d2a_core.training.rollout import Collector

    sim_clock = [0.0]
    envs = [_TimedEnv(RaceEnv("straightaway", intent="pass"), sim_clock) for _ in range(8)]
    config = DreamerConfig(units=128, deter=256, stoch=16, classes=16, train_ratio=args.train_ratio,
                           imag_starts=256, prefill_steps=1000, device=args.device)
    agent = DreamerAgent(envs[0].observation_space, envs[0].action_space, config, seed=0)
    collector = Collector(envs, agent, seed=0)
    env_steps = 0
    while env_steps < config.prefill_steps:  # untimed: random-policy prefill and the first update
        collector.step()
        env_steps += collector.n
    agent.train_step()
    sim_clock[0], learn, updates = 0.0, 0.0, 0
    start = time.perf_counter()
    for _ in range(args.loop_steps // collector.n):
        collector.step()
        env_steps += collector.n
        learn_start = time.perf_counter()
        for _ in range(agent.updates_due(env_steps)):
            agent.train_step()
            updates += 1
        learn += time.perf_counter() - learn_start
    total = time.perf_counter() - start
    act = total - learn - sim_clock[0]
    return {
        "benchmark": "dreamer_training_loop",
        "env_steps": args.loop_steps,
        "envs": collector.n,
        "train_ratio": args.train_ratio,
        "updates": updates,
        "wall_s": total,
        "env_steps_per_s": args.loop_steps / total,
        "updates_per_s": updates / learn if learn else None,
        "share_simulation": sim_clock[0] / total,
        "share_acting": act / total,
        "share_learning": learn / total,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, nargs="+", default=[128, 512], help="MLP widths to time")
    parser.add_argument("--deter", type=int, default=None, help="GRU size (default: same as units)")
    parser.add_argument("--latent", type=int, nargs=2, default=[32, 32], metavar=("STOCH", "CLASSES"),
                        help="latent variables x classes (the `quick` preset: 16 16)")
    parser.add_argument("--updates", type=int, default=5, help="timed updates per width")
    parser.add_argument("--warmup", type=int, default=2, help="untimed updates first")
    parser.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    parser.add_argument("--imag-starts", type=int, nargs="+", default=[None],
                        help="imagination starts, each timed at every width (default all 1024)")
    parser.add_argument("--batch-size", type=int, default=16, help="replayed sequences per update")
    parser.add_argument("--batch-length", type=int, default=64, help="steps per replayed sequence")
    parser.add_argument("--obs-dim", type=int, default=40)
    parser.add_argument("--action-dim", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--profile", action="store_true",
                        help="also time each phase of an update and the share spent inside torch operators")
    parser.add_argument("--loop-steps", type=int, default=0, help="time the full training loop instead")
    parser.add_argument("--train-ratio", type=float, default=64.0, help="replayed steps per env step (loop)")
    parser.add_argument("--default-malloc", action="store_true",
                        help="leave glibc's malloc untuned (training tunes it, see d2a_core/training/allocator.py)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    malloc_tuned = False if args.default_malloc else keep_freed_memory()
    if args.loop_steps:
        report = {**full_loop(args), "device": args.device, "threads": args.threads,
                  "malloc_tuned": malloc_tuned, "mkl_on_amd": mkl_on_amd.status(), "torch": torch.__version__,
                  "load_average_after": os.getloadavg()}
        json.dump(report, sys.stdout, indent=2)
        print()
        return 0
    # every setting in one process, in turn: their ratio is free of what differs between processes
    results = [dict(benchmark(u, args.deter or u, args.updates, args.warmup, args, starts),
                    imag_starts=starts or 1024)
               for u in args.units for starts in args.imag_starts]
    # the roof, measured in the same process: dense matmuls at the size of the largest layers and
    # at a size where the CPU reaches its peak
    roof = {f"matmul_gflop_per_s_{n}": matmul_gflops(n, args.device) for n in (1024, 2048)}
    peak = max(roof.values())
    for row in results:
        row["fraction_of_matmul_peak"] = row["achieved_gflop_per_s"] / peak
    report = {
        "benchmark": "dreamer_full_update",
        "batch": f"{args.batch_size}x{args.batch_length}",
        "imag_horizon": 15,
        "latent": args.latent,
        "device": args.device,
        "threads": args.threads,
        "malloc_tuned": malloc_tuned,
        "mkl_on_amd": mkl_on_amd.status(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "load_average_after": os.getloadavg(),
        **roof,
        "results": results,
    }
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
