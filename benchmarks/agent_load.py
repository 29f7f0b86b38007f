"""Benchmark of loading a DreamerV3 agent only to act, as `d2a eval` and `d2a intent-swap` do:
a new interpreter imports the agent, builds it, loads a checkpoint and takes one action. The
reference in the same run does the same and then builds the optimisers, as every load did before
they were built on first use (constructing torch's Adam imports torch._dynamo). Runs alternate,
and one JSON object is printed: per mode the median seconds of the imports and of build + load +
act (+ optimisers), and the ratio.

    python benchmarks/agent_load.py --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = """
import sys, time
t0 = time.perf_counter()
import gymnasium as gym, numpy as np, torch
from d2a_core.agents.dreamer import DreamerAgent, DreamerConfig
t1 = time.perf_counter()
spaces = (gym.spaces.Box(-np.inf, np.inf, (40,), np.float32), gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
agent = DreamerAgent(*spaces, DreamerConfig(units=128, deter=256, stoch=16, classes=16), seed=1)
agent.load_state_dict(torch.load(sys.argv[1], weights_only=False))
agent.policy({"obs": np.zeros((2, 40), np.float32), "is_first": np.ones(2, bool)}, explore=False)
if sys.argv[2] == "eager":
    agent.model_opt
t2 = time.perf_counter()
print(t1 - t0, t2 - t1, "torch._dynamo" in sys.modules)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        checkpoint = Path(tmp) / "agent.pt"
        # the checkpoint is written by a child too, so this process never builds torch's optimisers
        subprocess.run([sys.executable, "-c", "import sys, gymnasium as gym, numpy as np, torch\n"
                        "from d2a_core.agents.dreamer import DreamerAgent, DreamerConfig\n"
                        "a = DreamerAgent(gym.spaces.Box(-np.inf, np.inf, (40,), np.float32), "
                        "gym.spaces.Box(-1.0, 1.0, (2,), np.float32), "
                        "DreamerConfig(units=128, deter=256, stoch=16, classes=16))\n"
                        "torch.save(a.state_dict(), sys.argv[1])", str(checkpoint)], check=True)
        times: dict[str, dict[str, list[float]]] = {m: {"imports_s": [], "load_and_act_s": []} for m in ("lazy", "eager")}
        dynamo: dict[str, bool] = {}
        for _ in range(args.repeats):
            for mode in ("eager", "lazy"):
                out = subprocess.run([sys.executable, "-c", _CHILD, str(checkpoint), mode], check=True,
                                     capture_output=True, text=True).stdout.split()
                times[mode]["imports_s"].append(float(out[0]))
                times[mode]["load_and_act_s"].append(float(out[1]))
                dynamo[mode] = out[2] == "True"
    result = {mode: {key: round(statistics.median(values), 3) for key, values in figures.items()}
              | {"imports_torch_dynamo": dynamo[mode]} for mode, figures in times.items()}
    result["load_and_act_eager_over_lazy"] = round(
        result["eager"]["load_and_act_s"] / result["lazy"]["load_and_act_s"], 2)
    result["repeats"] = args.repeats
    result["cpus"] = os.cpu_count()
    print(json.dumps(result))


if __name__ == "__main__":
    main()
