"""The experts' demonstrations: each intent's expert driving alone, as (observation, action) pairs.

An imitation method (`Method.demonstrations`, e.g. `dreamer-ail`) learns from them. They are an
artifact of kind `demonstrations` (file `demonstrations.npz`), made once per experts, episode
count, seed and env settings and found again by that key, so a run that uses them is reproducible
from the store and its lineage names them.

`demonstrations.npz`: `obs` (M, D) the env's observation without its partner slot (an expert
driving alone has no partner), `action` (M, 2) the expert's action (its actor's mode, as in
evaluation), `label` (M,) the intent's index in the pair, `episode` (M,) the episode's index.
Only executed steps are kept (an action taken on an episode's last observation is not).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from d2a_core.artifacts import Store, content_key
from d2a_core.config.section import record
from d2a_core.run_inputs import ENV_SECTIONS, TrackBundle
from d2a_core.training.partner_window import PARTNER_SLOT

KIND = "demonstrations"
FILE = "demonstrations.npz"
SEED_BASE = 70_000_003  # env seeds of demonstration episodes: SEED_BASE + 1000 * seed + j


def drive_alone(agent: Any, make_env: Callable[[], Any], episodes: int, first_seed: int,
                generator: torch.Generator) -> dict[str, np.ndarray]:
    """`episodes` episodes of `agent` (a DreamerAgent) driving alone, one at a time, with its
    actor's mode; its latent states are sampled from `generator`."""
    obs_rows, action_rows, episode_rows = [], [], []
    env = make_env()
    try:
        for j in range(episodes):
            obs, _ = env.reset(seed=first_seed + j)
            state, first, done = None, True, False
            while not done:
                action, state = agent.policy({"obs": obs[None].astype(np.float32), "is_first": np.array([first])},
                                             state, explore=False, generator=generator)
                action = np.asarray(action, np.float32).reshape(-1)
                obs_rows.append(obs[:-PARTNER_SLOT].astype(np.float32))
                action_rows.append(action)
                episode_rows.append(j)
                obs, _, terminated, truncated, _ = env.step(action)
                first, done = False, terminated or truncated
    finally:
        env.close()
    return {"obs": np.stack(obs_rows), "action": np.stack(action_rows), "episode": np.asarray(episode_rows, np.int32)}


def expert_demonstrations(store: Store, bundle: TrackBundle, cfg: Any, experts: Sequence[tuple[str, Any]],
                          episodes: int, seed: int) -> tuple[str, dict[str, np.ndarray]]:
    """The demonstrations of `experts` ((checkpoint id, agent) per intent of the pair, in pair
    order), `episodes` each: the stored artifact if one was made with the same key, else made
    and stored now. Returns (artifact id, arrays)."""
    env_record = {name: record(getattr(cfg, name)) for name in ENV_SECTIONS}
    expert_ids = [expert_id for expert_id, _ in experts]
    key = content_key({"kind": KIND, "experts": expert_ids, "episodes": episodes, "seed": seed,
                       "track": bundle.track_id, "replays": list(bundle.replay_ids), "env": env_record})
    done = store.finished(KIND, key)
    if done is not None:
        with np.load(io.BytesIO(store.read_bytes(done.id, FILE))) as stored:
            return done.id, {name: stored[name] for name in stored.files}
    parts = []
    for k, (_, agent) in enumerate(experts):
        generator = torch.Generator().manual_seed(seed * 1000 + k)
        part = drive_alone(agent, lambda: bundle.env(cfg), episodes, SEED_BASE + 1000 * seed + 100 * k, generator)
        part["label"] = np.full(len(part["obs"]), k, np.int8)
        part["episode"] = part["episode"] + k * episodes
        parts.append(part)
    arrays = {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    with store.create(KIND, inputs=[bundle.track_id, *bundle.replay_ids, *expert_ids], config=env_record, seed=seed,
                      labels={"track": bundle.track.name, "episodes": episodes, "run_key": key}) as writer:
        writer.add_bytes(FILE, buffer.getvalue())
    return writer.artifact.id, arrays
