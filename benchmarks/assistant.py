"""Benchmark of the assistant's training loop: where the wall time goes.

Runs `train_assistant` for a short stretch (the `quick` model and collection settings, one
checkpoint, a small panel) on populations already in a store, and prints one JSON object with
the share of wall time in acting (assistant, humans), expert filtering, simulation, learning and
the panel evaluation, and collection steps/s. The target: acting and expert filtering
together <= 15 % of the training loop's time (evaluation excluded, it is per checkpoint).

    python benchmarks/assistant.py --store /tmp/grid/store --humans PASS_POP --humans STAY_POP --steps 4000

Without --humans the store's `humans/<track>/<intent>` aliases are used. The run writes to the
given store under a run key of its own (seed `--seed`, default 999; a second call with the same
arguments returns the stored result, `"cached": true`, so change the seed to measure again).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from d2a_core import mkl_on_amd

mkl_on_amd.enable()  # before torch loads MKL (D2A_MKL_AMD=0 measures without it)
import torch  # noqa: E402

from d2a_core import config as config_mod
from d2a_core.artifacts import Store
from d2a_core.training.assistant import train_assistant


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", default=os.environ.get("D2A_STORE", "artifacts"))
    parser.add_argument("--track", default="straightaway")
    parser.add_argument("--pair", default="pass-stay")
    parser.add_argument("--method", default="dream2assist")
    parser.add_argument("--humans", action="append", default=None)
    parser.add_argument("--steps", type=int, default=4000, help="env steps after the model's prefill")
    parser.add_argument("--seed", type=int, default=999)
    parser.add_argument("--threads", type=int, default=0)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    resolved = config_mod.load("quick", None, [
        f"assistant.env_steps={args.steps}", "assistant.checkpoints=1", "assistant.panel_weakest=1",
        "assistant.panel_episodes=1", f"assistant.torch_threads={args.threads}",
    ])
    started = time.perf_counter()
    result = train_assistant(Store(args.store), args.track, args.pair, args.method, resolved, args.seed,
                             humans=args.humans)
    wall = time.perf_counter() - started
    seconds = result["time_s"]
    loop = {k: v for k, v in seconds.items() if k != "evaluation"}
    loop_total = sum(loop.values())
    acting = sum(v for k, v in loop.items() if k.startswith("acting/")) + loop.get("expert_filtering", 0.0)
    print(json.dumps({
        "benchmark": "assistant_training_loop", "method": args.method, "env_steps": args.steps,
        "cached": result["cached"], "wall_s": round(wall, 2),
        "loop_shares": {k: round(v / loop_total, 4) for k, v in sorted(loop.items())},
        "acting_and_expert_filtering_share": round(acting / loop_total, 4),
        "collection_env_steps_per_s": round(args.steps / max(loop_total - loop.get("learning", 0.0), 1e-9), 1),
        "time_s": seconds, "torch_threads": torch.get_num_threads(),
        "mkl_on_amd": mkl_on_amd.status(), "machine": platform.machine(),
        "cpus": os.cpu_count(),
    }, indent=2))


if __name__ == "__main__":
    main()
