"""`train-humans`: a fictitious co-play population of DreamerV3 drivers per intent.

For one (track, intent) the agent trains on `r^H = r^task + r^intent` against the track's opponent
replays. At `checkpoints` evenly spaced points of the run it is evaluated unassisted and stored
as an artifact (kind `human`): the partially trained ones are the imperfect humans. The expert is
chosen among them by `evaluation.criteria.choose_expert` (a checkpoint that meets the intent, not
simply the last). With `snapshot_every`, weight snapshots taken between checkpoints are then
evaluated and added until the population spans enough imperfect drivers (`imperfect_fill`; they
are never the expert). Then a `population` artifact lists them all with the training curve.

Aliases: `humans/<track>/<intent>` (the population) and `humans/<track>/<intent>/expert`.

Resume: after each checkpoint the full training state (agent, replay, counters, curve) is saved
in `<store>/runs/<run key>/state.pt`; the same command after a crash continues from there. The
run key hashes everything the result depends on (track, replays, intent, config, seed, and the
training-code version of `training.code_version`), and a finished run with the same key is
returned from the store instead of training again, marked `cached` with the code it came from.
"""

from __future__ import annotations

import shutil
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from d2a_core import mkl_on_amd
from d2a_core.agents.dreamer import native
from d2a_core.agents.dreamer.agent import DreamerAgent
from d2a_core.agents.dreamer.config import DreamerConfig
from d2a_core.artifacts import Store
from d2a_core.config import ResolvedConfig
from d2a_core.config.schema import Config
from d2a_core.errors import TrainingError, UsageError
from d2a_core.evaluation.criteria import (EXPERT_RULE, choose_expert, criterion_value, meets_intent,
                                          performance_fractions)
from d2a_core.evaluation.metrics import aggregate
from d2a_core.objectives.rewards import INTENTS
from d2a_core.sim.race_env import RaceEnv
from d2a_core.run_inputs import TrackBundle, load_track_bundle
from d2a_core.training.allocator import keep_freed_memory
from d2a_core.training.checkpoint_bytes import agent_bytes
from d2a_core.training.code_version import TRAINING_CODE_VERSION
from d2a_core.training.config import HumansConfig
from d2a_core.training.live_curve import LiveCurve
from d2a_core.training.imperfect_fill import below_near_perfect, next_snapshot
from d2a_core.training.rollout import Collector, evaluate
from d2a_core.training.run_state import (RUN_FORMAT, RunDir, RunProgress, cached_result, load_checked, result_record,
                                         save_atomic, training_run_key)

# config sections a population depends on (changing anything else does not retrain)
SECTIONS = ("env", "reward", "vehicle", "world", "dreamer", "humans")


ProgressFn = Callable[[dict[str, Any]], None]



def train_population(
    store: Store,
    track_ref: str,
    intent: str,
    resolved: ResolvedConfig,
    seed: int,
    device: str = "cpu",
    progress: ProgressFn | None = None,
    move_aliases: bool = True,
) -> dict[str, Any]:
    """Train (or resume, or look up) one intent's population; returns its JSON summary.

    Everything the run loads and stores is held against `d2a artifacts gc` while it runs (a store
    lease), and its saved state's checkpoints after it dies (run holds), until it finishes.
    `move_aliases=False` leaves `humans/<track>/<intent>` (and its expert) where they point: a side
    population (another seed, a sweep) is found by its id or `humans/<track>/<intent>/side/<id>`."""
    with store.lease():
        return _train_population(store, track_ref, intent, resolved, seed, device, progress, move_aliases)


def driver_dreamer_config(cfg: Config, device: str = "cpu") -> DreamerConfig:
    """The drivers' DreamerV3 settings: `dreamer.*` with the `humans.*` keys that override it."""
    # A short run's world model must fit rare crash terminals in few updates
    # (docs/experiments/crash-blind-world-model.md, "Why left fails"); the drivers may learn faster
    # than the assistant, which shares `dreamer`.
    if cfg.dreamer.action_cost:  # the drivers' reward charges nothing per action
        raise UsageError(f"dreamer.action_cost={cfg.dreamer.action_cost!r}: the drivers' reward has no charge on "
                         "their actions; it is the assistant's setting (assistant.exact_intervention)")
    hc = cfg.humans
    own = {"model_lr": hc.model_lr}
    return cfg.dreamer.model_copy(update={"device": device, **{k: v for k, v in own.items() if v is not None}})


def _train_population(store: Store, track_ref: str, intent: str, resolved: ResolvedConfig, seed: int,
                      device: str, progress: ProgressFn | None, move_aliases: bool) -> dict[str, Any]:
    if intent not in INTENTS:
        raise UsageError(f"unknown intent {intent!r}; choose from {', '.join(INTENTS)}")
    cfg = resolved.config
    bundle = load_track_bundle(store, track_ref, cfg.env.dt)
    config_record = resolved.section(*SECTIONS)
    key = training_run_key("humans", bundle, config_record, seed, intent=intent)
    with RunDir(store, key).exclusive() as run:
        return _run_population(store, bundle, intent, resolved, config_record, key, run, seed, device, progress,
                               move_aliases)


def _run_population(store: Store, bundle: TrackBundle, intent: str, resolved: ResolvedConfig,
                    config_record: dict[str, Any], key: str, run: RunDir, seed: int, device: str,
                    progress: ProgressFn | None, move_aliases: bool) -> dict[str, Any]:
    """The body of `_train_population`, with the run's lock held."""
    cfg = resolved.config
    hc: HumansConfig = cfg.humans
    cached = cached_result(store, "population", key, "population.json")
    if cached:
        names = _aliases(bundle.track.name, intent, cached["id"], cached["expert"], move_aliases)
        return dict(cached, aliases=names, aliases_moved=store.point_aliases(names))

    if hc.torch_threads:
        torch.set_num_threads(hc.torch_threads)
    keep_freed_memory()
    dreamer_cfg = driver_dreamer_config(cfg, device)

    def make_env() -> RaceEnv:
        return bundle.env(cfg, intent)

    envs = [make_env() for _ in range(hc.num_envs)]
    agent = DreamerAgent(envs[0].observation_space, envs[0].action_space, dreamer_cfg, seed=seed)
    state = RunProgress(store, run, [bundle.track_id, *bundle.replay_ids], hc.env_steps, hc.checkpoints)
    state.resume(agent, device, intent)
    env_steps = state.env_steps
    # resets after a resume use fresh seeds so the continued run does not replay old episodes
    collector = Collector(envs, agent, seed=seed * 1_000_003 + env_steps)
    pending = state.pending()
    snapshots = _Snapshots(run.path / "snapshots", hc.snapshot_every, after=env_steps)
    tags = {"track": bundle.track.name, "intent": intent}
    curve = LiveCurve(store, f"humans/{bundle.track.name}/{intent}/seed{seed}-{key[:12]}", state.curve_rows)
    state.curve_rows = curve.rows
    recent: deque[dict[str, float]] = deque(maxlen=20)
    last_metrics: dict[str, float] = {}
    next_log = (env_steps // hc.log_every + 1) * hc.log_every
    start_time, start_updates = time.monotonic(), agent.updates_done
    try:
        while pending:
            recent.extend(collector.step(explore=True, learn=True))
            env_steps += collector.n
            state.env_steps = env_steps
            for _ in range(agent.updates_due(env_steps)):
                last_metrics = agent.train_step()
            snapshots.maybe_save(agent, env_steps, checkpoint_now=env_steps >= pending[0])
            if env_steps >= next_log or env_steps >= pending[0]:
                row = {"env_step": env_steps, "updates": agent.updates_done,
                       **{f"episode/{k}": v for k, v in aggregate(list(recent)).items()},
                       # wall-clock timings stay out: the curve is hashed into the population's id
                       **{k: round(v, 6) for k, v in last_metrics.items() if not k.startswith("time/")}}
                curve.append(row)
                next_log = (env_steps // hc.log_every + 1) * hc.log_every
            if progress:
                elapsed = max(time.monotonic() - start_time, 1e-9)
                progress({"intent": intent, "env_steps": env_steps, "total": hc.env_steps,
                          "updates_per_s": (agent.updates_done - start_updates) / elapsed,
                          "recent_return": float(np.mean([e["return"] for e in recent])) if recent else None,
                          # metres reached tell a stuck run from a slow one on a long track
                          "recent_progress_m": float(np.mean([e["progress_m"] for e in recent])) if recent else None})
            if env_steps >= pending[0]:
                pending.pop(0)
                state.checkpointed(_store_checkpoint(store, agent, bundle, make_env, intent, env_steps, hc,
                                                     config_record, seed, tags),
                                   {"format": RUN_FORMAT, "agent": agent.state_dict(include_replay=True)})
    except TrainingError as exc:
        raise state.stopped(exc, intent) from None
    finally:
        curve.close()
        for env in envs:
            env.close()

    checkpoints = state.checkpoints
    expert = checkpoints[choose_expert(intent, checkpoints)]
    checkpoints = _fill_imperfect(store, agent, bundle, make_env, intent, hc, config_record, seed, tags,
                                  checkpoints, expert["id"], snapshots, key)
    expert_index = next(k for k, c in enumerate(checkpoints) if c["id"] == expert["id"])
    for checkpoint, fraction in zip(checkpoints, performance_fractions(checkpoints, expert_index)):
        checkpoint["performance"] = fraction
    # How the run executed: the compiled CPU kernels change float rounding, not the method.
    runtime = {"device": device, "torch_threads": torch.get_num_threads(), "cpu_kernels": native.status(),
               "mkl_on_amd": mkl_on_amd.status()}
    result = {"intent": intent, "track": bundle.track.name, "track_id": bundle.track_id, "seed": seed,
              "expert": expert["id"], "expert_env_step": expert["env_step"],
              "expert_meets_intent": expert["meets_intent"], "expert_rule": EXPERT_RULE,
              "training_code_version": TRAINING_CODE_VERSION, "checkpoints": checkpoints, "runtime": runtime,
              "resumed_from_env_step": state.resumed_from}
    with store.create("population", inputs=[c["id"] for c in checkpoints], config=config_record, seed=seed,
                      labels={**tags, "run_key": key}) as writer:
        writer.add_json("population.json", result_record(result))
        writer.note("config_source", resolved.source())
        writer.add_bytes("curve.jsonl", curve.jsonl_bytes())
    population = writer.artifact
    names = _aliases(bundle.track.name, intent, population.id, expert["id"], move_aliases)
    # finished: the aliases now keep everything; the resumable state (with its replay) goes
    moved = state.finish(names)
    snapshots.discard()
    return dict(result, id=population.id, cached=False, aliases=names, aliases_moved=moved)


def _aliases(track: str, intent: str, population_id: str, expert_id: str, main: bool = True) -> dict[str, str]:
    """The names a finished population is found by: the population and its expert; a side
    population (`main=False`) only by `humans/<track>/<intent>/side/<id>`, which keeps it and its
    checkpoints (its inputs) from `d2a artifacts gc`."""
    if not main:
        return {f"humans/{track}/{intent}/side/{population_id[:12]}": population_id}
    return {f"humans/{track}/{intent}": population_id, f"humans/{track}/{intent}/expert": expert_id}


class _Snapshots:
    """Weight snapshots of a run, one file per env step in the run directory
    (`training.imperfect_fill`). Those after `after` (a resumed run's step) belong to the timeline
    the crash ended and are dropped: the resumed run takes them again."""

    def __init__(self, folder: Path, every: int, after: int) -> None:
        self.folder, self.every = folder, every
        self.next = (after // every + 1) * every if every else None
        for path in folder.glob("*.pt") if folder.is_dir() else ():
            if int(path.stem) > after:
                path.unlink()

    def maybe_save(self, agent: DreamerAgent, env_steps: int, checkpoint_now: bool) -> None:
        """Snapshot when one is due, unless a checkpoint is taken at this step anyway or the
        agent has not been updated yet (during prefill every snapshot would be the same driver)."""
        if self.next is None or env_steps < self.next:
            return
        self.next = (env_steps // self.every + 1) * self.every
        if not checkpoint_now and agent.updates_done > 0:
            self.folder.mkdir(parents=True, exist_ok=True)
            save_atomic(agent.state_dict(include_replay=False), self.folder / f"{env_steps}.pt")

    def steps(self) -> list[int]:
        return sorted(int(p.stem) for p in self.folder.glob("*.pt")) if self.folder.is_dir() else []

    def load(self, env_steps: int, device: str) -> dict[str, Any]:
        return load_checked(self.folder / f"{env_steps}.pt", device, "the weight snapshot",
                            f"delete {self.folder.parent} to train this run from the start")

    def discard(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def _fill_imperfect(store: Store, agent: DreamerAgent, bundle: TrackBundle, make_env, intent: str,
                    hc: HumansConfig, config_record: dict[str, Any], seed: int, tags: dict[str, str],
                    checkpoints: list[dict[str, Any]], expert_id: str, snapshots: _Snapshots,
                    key: str) -> list[dict[str, Any]]:
    """The checkpoints with snapshots added until `hc.fill_imperfect` of them (the expert aside)
    perform below 75 % of the expert (`training.imperfect_fill`). Runs after training: loading a
    snapshot into `agent` no longer matters to anything but the evaluation."""
    checkpoints = sorted(checkpoints, key=lambda c: c["env_step"])
    taken = {c["env_step"] for c in checkpoints}
    left = [s for s in snapshots.steps() if s not in taken]
    while left:
        expert = next(k for k, c in enumerate(checkpoints) if c["id"] == expert_id)
        performance = performance_fractions(checkpoints, expert)
        if below_near_perfect(performance, expert) >= hc.fill_imperfect:
            break
        step = next_snapshot([(c["env_step"], p) for c, p in zip(checkpoints, performance)], left)
        if step is None:
            break
        left.remove(step)
        agent.load_state_dict(snapshots.load(step, str(agent.device)))
        added = _store_checkpoint(store, agent, bundle, make_env, intent, step, hc, config_record, seed, tags)
        checkpoints = sorted([*checkpoints, dict(added, filled=True)], key=lambda c: c["env_step"])
        store.hold_run(key, [bundle.track_id, *bundle.replay_ids, *(c["id"] for c in checkpoints)])
    return checkpoints


def _store_checkpoint(store: Store, agent: DreamerAgent, bundle: TrackBundle, make_env, intent: str,
                      env_steps: int, hc: HumansConfig, config_record: dict[str, Any], seed: int,
                      tags: dict[str, str]) -> dict[str, Any]:
    with store.scratch_dir("checkpoint-eval") as logs:
        episodes = evaluate(agent, make_env, hc.eval_episodes, seed=10_000_019 + seed, n_envs=hc.eval_envs,
                            log_dir=Path(logs), log_episodes=hc.eval_logs)
        metrics = aggregate(episodes)
        fraction = round(env_steps / hc.env_steps, 6)
        with store.create("human", inputs=[bundle.track_id, *bundle.replay_ids], config=config_record, seed=seed,
                          labels={**tags, "env_step": env_steps, "fraction": fraction}) as writer:
            writer.add_bytes("agent.pt", agent_bytes(agent))
            writer.add_json("eval.json", {"metrics": metrics, "episodes": episodes})
            for log in sorted(Path(logs).glob("*.mcap")):  # where the checkpoint fails, for Foxglove
                writer.add_file(f"episodes/{log.name}", log)
    return {"id": writer.artifact.id, "env_step": env_steps, "fraction": fraction, "metrics": metrics,
            "meets_intent": meets_intent(intent, metrics), "criterion": criterion_value(intent, metrics)}
