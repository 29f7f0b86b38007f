"""Does a driver's world model know where its episodes end? For stored human checkpoints, drive
episodes as training does (sampled actions, grid starts), filter the checkpoint's own world
model along them, and compare its predictions at the steps that ended an episode (collision
with the opponent or a barrier, leaving the road, the finish) with the other steps: the
continue probability (1 - P(end); 0 is right at a terminal step) and the reward prediction
against the reward the env paid.

    python docs/analysis/terminal_fit.py STORE HUMAN_ID [HUMAN_ID ...] [--episodes 20] [--mode]

Prints one markdown row per checkpoint and outcome. `wm/terminal_continue` in a training curve
is the same continue figure on replayed batches; this script splits it by what ended the episode
and shows the states the model saw there (gap to the opponent along and across the road), how
far the world model's reconstruction of that gap is off. (Checkpoints trained with the retired
`env.observe_clearance` need d2a at commit 805c724, which also printed the clearance columns.)
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
import torch

from d2a_core.agents.dreamer.distributions import symexp
from d2a_core.agents.dreamer.agent import DreamerAgent
from d2a_core.artifacts import Store
from d2a_core.config import load
from d2a_core.sim.race_env import RaceEnv
from d2a_core.run_inputs import load_track_bundle
from d2a_core.stored_agents import load_human, trained_env_config


def outcome_of(info: dict, terminated: bool) -> str:
    """What ended the step's episode (or `running`)."""
    if not terminated:
        return "running"
    if info["collision_car"]:
        return "collision (car)"
    if info["collision_barrier"]:
        return "collision (barrier)"
    if info["off_track"]:
        return "off track"
    return "finish"


def checkpoint_and_env(store: Store, human_id: str) -> tuple[DreamerAgent, RaceEnv]:
    """A stored human checkpoint and an env of its intent on its track, with the env settings it
    was trained in."""
    art = store.get(human_id)
    config = load("quick").config
    config = config.model_copy(update={"env": trained_env_config(art)})
    bundle = load_track_bundle(store, art.labels["track"], config.env.dt)
    env = bundle.env(config, intent=art.labels["intent"])
    return load_human(store, human_id, env.observation_space, env.action_space), env


def drive(store: Store, human_id: str, episodes: int, explore: bool, seed: int) -> dict[str, list[tuple]]:
    """(continue prob, predicted reward, paid reward, ds, de, decoded ds, decoded de) per step,
    grouped by outcome (decoded: the world model's reconstruction of the observation)."""
    agent, env = checkpoint_and_env(store, human_id)
    generator = torch.Generator().manual_seed(seed)
    ds_at, de_at = env.observation_names.index("ds"), env.observation_names.index("de")
    rows: dict[str, list[tuple]] = defaultdict(list)
    for episode in range(episodes):
        obs, info = env.reset(seed=seed + episode)
        state, reward, first, done, terminated = None, 0.0, True, False, False
        while True:
            record = {"obs": obs[None], "is_first": np.array([first])}
            action, state = agent.policy(record, state, explore=explore, generator=generator)
            if not first:
                predicted = agent.predict(state)
                with torch.no_grad():
                    decoded = symexp(agent.world_model.decoder(state.latent).float())[0]
                outcome = outcome_of(info, terminated) if done else "running"
                rows[outcome].append((float(predicted["continue"][0]), float(predicted["reward"][0]), reward,
                                      float(info["ds"]), float(info["de"]), float(decoded[ds_at]),
                                      float(decoded[de_at])))
            if done:
                break
            obs, reward, terminated, truncated, info = env.step(action[0])
            first, done = False, terminated or truncated
    env.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("humans", nargs="+", help="`human` checkpoint ids or aliases")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--mode", action="store_true", help="take the actor's mode (evaluation) instead of sampling")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    store = Store(args.store)
    print("| checkpoint | outcome | steps | continue prob (mean, min-max) | predicted reward | paid reward "
          "| ds m (mean) | |de| m (mean) | decoded ds / de error m (mean abs) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for ref in args.humans:
        human_id = store.resolve(ref)
        env_step = store.get(human_id).labels["env_step"]
        rows = drive(store, human_id, args.episodes, not args.mode, args.seed)
        for outcome in sorted(rows, key=lambda k: (k == "running", k)):
            a = np.array(rows[outcome])
            print(f"| {human_id[:12]} ({env_step}) | {outcome} | {len(a)} | {a[:, 0].mean():.2f} "
                  f"({a[:, 0].min():.2f}-{a[:, 0].max():.2f}) | {a[:, 1].mean():.1f} | {a[:, 2].mean():.1f} "
                  f"| {a[:, 3].mean():.1f} | {np.abs(a[:, 4]).mean():.1f} "
                  f"| {np.abs(a[:, 5] - a[:, 3]).mean():.2f} / {np.abs(a[:, 6] - a[:, 4]).mean():.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
