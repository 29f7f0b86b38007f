"""Can a driver's world model learn where episodes end, given the data? Offline, away from the
RL loop: record episodes by driving stored human checkpoints as training does (sampled actions,
grid starts), then train a fresh world model of a given config on them (world-model loss only,
the replay sampling of training) and score, on held-out recorded episodes, how its continue
head and reward head read the steps that ended an episode.

    python docs/analysis/wm_offline.py record STORE HUMAN_ID [HUMAN_ID ...] --out DATA.npz [--episodes 20]
    python docs/analysis/wm_offline.py train DATA.npz [--updates 2500] [--set dreamer.KEY=VALUE ...]
    python docs/analysis/wm_offline.py score DATA.npz STORE HUMAN_ID [HUMAN_ID ...]

`train` prints one JSON line per evaluation (`score`: per stored checkpoint, its own world model): updates done, the mean continue probability at
collisions with the opponent (0 is right) and at the other steps, the ROC AUC of 1 - continue
for "this step is a car collision" among the steps within 15 m of the opponent (0.5: no better
than chance), and the mean reward the head predicts at car collisions against what was paid.
The config is the `quick` preset's with the drivers' `humans.model_lr`, plus `--set` overrides;
the last fifth of the recorded episodes (by recording order, every checkpoint alike) is held out.
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np
import torch
from sklearn.metrics import roc_auc_score

from d2a_core.agents.dreamer.agent import DreamerAgent
from d2a_core.artifacts import Store
from d2a_core.config import load
from terminal_fit import checkpoint_and_env  # beside this script, on sys.path when it runs

OUTCOMES = ("running", "collision (car)", "collision (barrier)", "off track", "finish", "truncated")
NEAR_M = 15.0


def outcome_index(info: dict, terminated: bool, truncated: bool) -> int:
    if terminated:
        if info["collision_car"]:
            return 1
        if info["collision_barrier"]:
            return 2
        return 3 if info["off_track"] else 4
    return 5 if truncated else 0


def record(store: Store, refs: list[str], episodes: int, seed: int) -> dict[str, np.ndarray]:
    """Every step of `episodes` episodes per checkpoint, in the replay's record layout, plus
    each step's episode number, outcome and gap to the opponent along the road."""
    columns: dict[str, list] = {k: [] for k in ("obs", "action", "reward", "is_first", "is_terminal",
                                                "episode", "outcome", "ds", "env_step")}
    episode_no = 0
    for ref in refs:
        art = store.get(store.resolve(ref))
        agent, env = checkpoint_and_env(store, art.id)
        generator = torch.Generator().manual_seed(seed)
        for k in range(episodes):
            obs, info = env.reset(seed=seed + k)
            state, reward, first, terminated, truncated = None, 0.0, True, False, False
            while True:
                action, state = agent.policy({"obs": obs[None], "is_first": np.array([first])}, state,
                                             explore=True, generator=generator)
                for key, value in (("obs", obs), ("action", action[0]), ("reward", reward), ("is_first", first),
                                   ("is_terminal", terminated), ("episode", episode_no),
                                   ("outcome", outcome_index(info, terminated, truncated)), ("ds", info["ds"]),
                                   ("env_step", art.labels["env_step"])):
                    columns[key].append(value)
                if terminated or truncated:
                    break
                obs, reward, terminated, truncated, info = env.step(action[0])
                first = False
            episode_no += 1
        env.close()
    return {k: np.asarray(v) for k, v in columns.items()}


def streams(data: dict[str, np.ndarray], episodes: np.ndarray, n: int) -> list[dict[str, np.ndarray]]:
    """Time steps of `n` parallel streams, each a concatenation of whole episodes (each episode
    goes to the shortest stream so far; the streams are cut to the shortest)."""
    per_stream: list[list[np.ndarray]] = [[] for _ in range(n)]
    lengths = np.zeros(n, int)
    for e in episodes:
        rows = np.flatnonzero(data["episode"] == e)
        i = int(lengths.argmin())
        per_stream[i].append(rows)
        lengths[i] += len(rows)
    index = np.stack([np.concatenate(p)[: lengths.min()] for p in per_stream])  # (n, T)
    fields = ("obs", "action", "reward", "is_first", "is_terminal")
    return [{k: data[k][index[:, t]] for k in fields} for t in range(index.shape[1])]


@torch.no_grad()
def score(agent: DreamerAgent, data: dict[str, np.ndarray], episodes: np.ndarray) -> dict[str, float]:
    """Filter every held-out episode with the world model (latents sampled from a generator seeded
    with the episode number, so a score repeats exactly) and read its heads at every step."""
    wm = agent.world_model
    cont, reward = [], []
    for e in episodes:
        rows = np.flatnonzero(data["episode"] == e)
        obs = torch.as_tensor(data["obs"][rows], dtype=torch.float32)[None]
        action = torch.as_tensor(agent._internal_action_array(data["action"][rows]))[None]
        prev = torch.cat((torch.zeros_like(action[:, :1]), action[:, :-1]), 1)
        first = torch.as_tensor(data["is_first"][rows])[None]
        latent = wm.rssm.observe(wm.embed(obs), prev, first, torch.Generator().manual_seed(int(e))).latent
        cont.append(wm.continue_prob(latent)[0].numpy())
        reward.append(wm.reward(latent)[0].numpy())
    rows = np.concatenate([np.flatnonzero(data["episode"] == e) for e in episodes])
    cont, reward = np.concatenate(cont), np.concatenate(reward)
    outcome, ds = data["outcome"][rows], data["ds"][rows]
    car = outcome == 1
    near = np.abs(ds) < NEAR_M
    result = {"continue_at_car_collision": float(cont[car].mean()) if car.any() else float("nan"),
              "continue_elsewhere": float(cont[outcome == 0].mean()),
              "reward_at_car_collision": float(reward[car].mean()) if car.any() else float("nan"),
              "paid_at_car_collision": float(data["reward"][rows][car].mean()) if car.any() else float("nan"),
              "car_collisions": int(car.sum()), "near_steps": int(near.sum())}
    if car.any() and (near & ~car).any():
        result["auc_near"] = float(roc_auc_score(car[near], 1.0 - cont[near]))
    terminal = data["is_terminal"][rows]
    result["continue_at_any_terminal"] = float(cont[terminal].mean())
    return result


def train(path: str, updates: int, overrides: list[str], eval_every: int, seed: int, streams_n: int,
          grow: bool) -> None:
    data = dict(np.load(path))
    config = load("quick", overrides=overrides).config
    dreamer = config.dreamer.model_copy(update={"model_lr": config.humans.model_lr or config.dreamer.model_lr})
    episodes = np.unique(data["episode"])
    held = episodes[episodes % 5 == 4]
    train_eps = episodes[episodes % 5 != 4]
    obs_size = data["obs"].shape[1]
    obs_space = gym.spaces.Box(-np.inf, np.inf, (obs_size,), np.float32)
    act_space = gym.spaces.Box(-1.0, 1.0, (data["action"].shape[1],), np.float32)
    agent = DreamerAgent(obs_space, act_space, dreamer, seed=seed)
    if grow:
        # as in a run: episodes arrive in the order of the checkpoints that drove them, and the
        # world model trains on the replay so far at the config's train ratio
        first_step = {e: data["env_step"][np.argmax(data["episode"] == e)] for e in train_eps}
        train_eps = np.array(sorted(train_eps, key=lambda e: (first_step[e], e)))
        steps, added, u = streams(data, train_eps, streams_n), 0, 0
        started = time.perf_counter()
        for t, step in enumerate(steps):
            agent.observe(step)
            added += streams_n
            for _ in range(agent.updates_due(added)):
                u += 1
                agent.updates_done += 1
                _, out, _ = agent.world_model_update()
            if (t + 1) % (len(steps) // 5) == 0 or t == len(steps) - 1:
                print(json.dumps({"env_steps": added, "updates": u, "seconds": round(time.perf_counter() - started, 1),
                                  **{k: round(v, 3) if isinstance(v, float) else v
                                     for k, v in score(agent, data, held).items()}}), flush=True)
        return
    for step in streams(data, train_eps, streams_n):
        agent.observe(step)
    started = time.perf_counter()
    for u in range(1, updates + 1):
        _, out, _ = agent.world_model_update()
        if u % eval_every == 0 or u == updates:
            line = {"updates": u, "seconds": round(time.perf_counter() - started, 1),
                    "wm_loss": round(out.loss.item(), 3), **score(agent, data, held)}
            print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in line.items()}), flush=True)


def score_checkpoints(path: str, store: Store, refs: list[str]) -> None:
    """Score stored checkpoints' own world models on the held-out recorded episodes."""
    data = dict(np.load(path))
    episodes = np.unique(data["episode"])
    held = episodes[episodes % 5 == 4]
    for ref in refs:
        art = store.get(store.resolve(ref))
        agent, env = checkpoint_and_env(store, art.id)
        env.close()
        line = {"checkpoint": art.id[:12], "env_step": art.labels["env_step"], **score(agent, data, held)}
        print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in line.items()}), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("store")
    rec.add_argument("humans", nargs="+")
    rec.add_argument("--out", required=True)
    rec.add_argument("--episodes", type=int, default=20)
    rec.add_argument("--seed", type=int, default=5000)
    tr = sub.add_parser("train")
    tr.add_argument("data")
    tr.add_argument("--updates", type=int, default=2500)
    tr.add_argument("--eval-every", type=int, default=500)
    tr.add_argument("--set", dest="overrides", action="append", default=[])
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--streams", type=int, default=8)
    tr.add_argument("--grow", action="store_true",
                    help="add the episodes in checkpoint order and update at the train ratio, as a run does")
    sc = sub.add_parser("score")
    sc.add_argument("data")
    sc.add_argument("store")
    sc.add_argument("humans", nargs="+")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.command == "record":
        data = record(Store(args.store), args.humans, args.episodes, args.seed)
        np.savez(args.out, **data)
        outcome = np.bincount(data["outcome"], minlength=len(OUTCOMES))
        print(json.dumps({"steps": len(data["obs"]), "episodes": int(data["episode"].max() + 1),
                          **{name: int(n) for name, n in zip(OUTCOMES, outcome) if name != "running"}}))
    elif args.command == "score":
        score_checkpoints(args.data, Store(args.store), args.humans)
    else:
        train(args.data, args.updates, args.overrides, args.eval_every, args.seed, args.streams, args.grow)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
