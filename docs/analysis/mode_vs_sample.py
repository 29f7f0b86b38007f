"""Is a driver's mode the driver it was trained as? Training samples the actor; evaluation, the
population's criterion and the assistant's humans take its mode (the mean of the tanh-bounded
normal). For stored human checkpoints, drive the same grid starts both ways and print, per
checkpoint and way, the actor's mean and std (averaged over the steps), the action the car got
(a sample is clipped to [-1, 1], so a mean near 1 is applied lower on average) and how the
episodes ended.

    python docs/analysis/mode_vs_sample.py STORE HUMAN_ID [HUMAN_ID ...] [--episodes 10] [--seed 100]

A std far above the actor's minimum means the two are different drivers: the sampled one is
what the world model and the critic were trained on, the mode one is what is evaluated.
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np
import torch

from d2a_core.agents.dreamer.agent import DreamerAgent
from d2a_core.agents.dreamer.distributions import bounded_normal_params
from d2a_core.artifacts import Store
from d2a_core.sim.race_env import RaceEnv
from terminal_fit import checkpoint_and_env, outcome_of  # beside this script, on sys.path when it runs


def drive(agent: DreamerAgent, env: RaceEnv, episodes: int, explore: bool, seed: int) -> dict:
    """Mean actor mean, std and applied action over every step, and the episodes' outcomes."""
    actor, c = agent.behavior.actor, agent.config
    generator = torch.Generator().manual_seed(seed)
    means, stds, applied, outcomes = [], [], [], Counter()
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        state, first = None, True
        while True:
            action, state = agent.policy({"obs": obs[None], "is_first": np.array([first])}, state,
                                         explore=explore, generator=generator)
            with torch.no_grad():
                mean, std = bounded_normal_params(actor.net(state.latent), c.actor_min_std, c.actor_max_std)
            means.append(mean[0].numpy())
            stds.append(std[0].numpy())
            applied.append(np.clip(np.asarray(action).reshape(-1), -1.0, 1.0))
            obs, _, terminated, truncated, info = env.step(np.asarray(action).reshape(-1))
            first = False
            if terminated or truncated:
                outcomes[outcome_of(info, terminated) if terminated else "truncated"] += 1
                break
    return {"mean": np.mean(means, 0), "std": np.mean(stds, 0), "applied": np.mean(applied, 0),
            "outcomes": dict(outcomes)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("humans", nargs="+", help="`human` checkpoint ids or aliases")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=100)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    store = Store(args.store)
    print("| checkpoint | actions | actor mean (steer, accel) | actor std | applied | outcomes |")
    print("|---|---|---|---|---|---|")
    for ref in args.humans:
        human_id = store.resolve(ref)
        env_step = store.get(human_id).labels["env_step"]
        agent, env = checkpoint_and_env(store, human_id)
        for explore in (False, True):
            r = drive(agent, env, args.episodes, explore, args.seed)
            fmt = lambda v: ", ".join(f"{x:.2f}" for x in v)  # noqa: E731
            outcomes = ", ".join(f"{k} {n}" for k, n in sorted(r["outcomes"].items()))
            print(f"| {human_id[:12]} ({env_step}) | {'sampled' if explore else 'mode'} | {fmt(r['mean'])} "
                  f"| {fmt(r['std'])} | {fmt(r['applied'])} | {outcomes} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
