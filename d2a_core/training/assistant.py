"""`train-assistant`: an assistant trained with frozen human populations (paper Algorithm 1, phase 2).

For a pair of intents (`pass-stay`, `left-right`) the populations are frozen: one per intent, or
several (`--humans A,B`: populations of other training seeds, fictitious co-play's diversity),
the first of each intent being its reference (expert, panel). Every episode of every env draws an
intent uniformly, then a checkpoint of that intent's populations (the experts included) and an
env seed (which draws the opponent replay). Human and assistant drive together
(`training.shared_rollout`); the assistant learns on its own reward (equation 6, made in this
process from the env's `r^task`, its action and, for the Dream2Assist methods, the experts of
the pair filtered along every episode). What the method changes (intent head, reward weights,
learner) comes from the method registry (`training.methods`).

At `checkpoints` evenly spaced points the assistant is stored (kind `assistant`) with a paired
evaluation on a fixed panel of the pair's humans (`evaluation.paired`): the panel's unassisted
episodes are run once per run, the assisted ones at every checkpoint, on the same specs.

Aliases: `assistants/<track>/<pair>/<method>/seed<k>` for the final checkpoint; the run's summary
(kind `assistant-run`: checkpoints, curve, timing) gets `assistant-runs/<track>/<pair>/<method>/seed<k>`.

Resume and caching work as in `training.humans`: the run key hashes the track, replays, both
populations, pair, method, the config sections the method depends on, the seed and the training
code version.
"""

from __future__ import annotations

import io
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from d2a_core import mkl_on_amd
from d2a_core.agents.dreamer import native
from d2a_core.agents.dreamer.expert import ExpertFilter
from d2a_core.artifacts import Store
from d2a_core.config import ResolvedConfig
from d2a_core.config.section import record
from d2a_core.errors import TrainingError
from d2a_core.evaluation.metrics import aggregate
from d2a_core.evaluation.paired import PanelHuman, paired_summary, panel
from d2a_core.sim.race_env import RaceEnv
from d2a_core.training.allocator import keep_freed_memory
from d2a_core.training.checkpoint_bytes import agent_bytes
from d2a_core.training.code_version import TRAINING_CODE_VERSION
from d2a_core.run_inputs import TrackBundle, load_population_groups, load_track_bundle, parse_pair
from d2a_core.stored_agents import load_human
from d2a_core.training.demonstrations import expert_demonstrations
from d2a_core.training.live_curve import LiveCurve
from d2a_core.training.methods import INTENT_HEAD_NAME, Method, get_method
from d2a_core.training.partner_window import assistant_observation_space
from d2a_core.training.run_state import RUN_FORMAT, RunDir, RunProgress, cached_result, result_record, training_run_key
from d2a_core.training.shared_rollout import ASSISTANT_TERMS, EpisodeSpec, HumanDrivers, SharedCollector

ProgressFn = Callable[[dict[str, Any]], None]


class _Timer:
    """Wall time per phase (acting, expert filtering, simulation, learning, evaluation)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def add(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + seconds

    def shares(self) -> dict[str, float]:
        total = sum(self.seconds.values()) or 1.0
        return {k: round(v / total, 4) for k, v in sorted(self.seconds.items())}


def train_assistant(store: Store, track_ref: str, pair: str, method_name: str, resolved: ResolvedConfig,
                    seed: int, humans: Sequence[str] | None = None, device: str = "cpu",
                    progress: ProgressFn | None = None, move_aliases: bool = True) -> dict[str, Any]:
    """Train (or resume, or look up) one assistant; returns its JSON summary. Everything it loads
    and stores is held against `d2a artifacts gc` while it runs (lease) and after it dies (run holds).
    `move_aliases=False` leaves `assistants/...` and `assistant-runs/...` where they point (a side
    run, e.g. a sweep or a timing, found by its id or its own `.../side/<run id>` alias), so
    evaluations by method and seed keep theirs."""
    with store.lease():
        return _train(store, track_ref, pair, method_name, resolved, seed, humans, device, progress, move_aliases)


def _train(store: Store, track_ref: str, pair: str, method_name: str, resolved: ResolvedConfig, seed: int,
           humans_refs: Sequence[str] | None, device: str, progress: ProgressFn | None,
           move_aliases: bool) -> dict[str, Any]:
    intents = parse_pair(pair)
    method = get_method(method_name)
    cfg = method.configure(resolved.config, intents)
    bundle = load_track_bundle(store, track_ref, cfg.env.dt)
    groups = load_population_groups(store, bundle, intents, humans_refs)
    population_ids = [pid for group in groups for pid, _ in group]
    # the sections the method depends on, as patched by the method (intent head, reward weights)
    config_record = {name: record(getattr(cfg, name)) for name in method.config_sections}
    key = training_run_key("assistant", bundle, config_record, seed, populations=list(population_ids), pair=pair,
                           method=method.name)
    with RunDir(store, key).exclusive() as run:
        return _run(store, bundle, pair, intents, method, cfg, groups, population_ids, config_record, key, run,
                    seed, device, progress, move_aliases, resolved.source())


def _run(store: Store, bundle: TrackBundle, pair: str, intents: tuple[str, ...], method: Method, cfg: Any,
         groups: list, population_ids: list[str], config_record: dict[str, Any], key: str, run: RunDir, seed: int,
         device: str, progress: ProgressFn | None, move_aliases: bool,
         config_source: dict[str, Any]) -> dict[str, Any]:
    """The body of `_train`, with the run's lock held."""
    ac = cfg.assistant
    # each intent's reference population (its expert, the panel); with one per intent, all of them
    populations = [group[0] for group in groups]
    cached = cached_result(store, "assistant-run", key, "run.json", id_key="run_id", notes=("time_shares", "time_s"))
    if cached:
        names = _aliases(bundle.track.name, pair, method.name, seed, cached["id"], cached["run_id"], move_aliases)
        return dict(cached, aliases_moved=store.point_aliases(names))

    if ac.torch_threads:
        torch.set_num_threads(ac.torch_threads)
    keep_freed_memory()

    def make_env() -> RaceEnv:
        return bundle.env(cfg)

    envs = [make_env() for _ in range(ac.num_envs)]
    obs_space, act_space = envs[0].observation_space, envs[0].action_space
    # every checkpoint of every population, in pair order; labels are the intents' indices
    human_ids, human_labels, human_population = [], [], []
    for k, group in enumerate(groups):
        for pid, pop in group:
            for c in pop["checkpoints"]:
                human_ids.append(c["id"])
                human_labels.append(k)
                human_population.append(population_ids.index(pid))
    human_agents = [load_human(store, hid, obs_space, act_space, device) for hid in human_ids]
    by_id = dict(zip(human_ids, human_agents))
    expert_agents = [by_id[pop["expert"]] for _, pop in populations]
    the_panel = panel([pop for _, pop in populations], intents, ac.panel_weakest)

    agent = method.build_agent(cfg, assistant_observation_space(obs_space, ac.partner_window), act_space, intents,
                               seed, device)
    inputs = [bundle.track_id, *bundle.replay_ids, *population_ids]
    demos_s = 0.0
    if method.demonstrations:
        started = time.perf_counter()
        demos_id, demos = expert_demonstrations(
            store, bundle, cfg, [(pop["expert"], by_id[pop["expert"]]) for _, pop in populations],
            getattr(cfg, method.agent_section).demo_episodes, seed)
        agent.set_demonstrations(demos["obs"], demos["action"])
        inputs.append(demos_id)
        demos_s = time.perf_counter() - started
    state = RunProgress(store, run, inputs, ac.env_steps, ac.checkpoints)
    timer = _Timer()
    saved = state.resume(agent, device, "the assistant")
    env_steps = state.env_steps
    unassisted = saved.get("unassisted")
    drawn = saved.get("drawn", [0] * len(population_ids))  # finished training episodes per population
    timer.seconds = saved.get("timing", timer.seconds)
    if demos_s:
        timer.add("demonstrations", demos_s)
    if not saved:
        state.hold()

    # episodes: intent uniform, then a checkpoint of its population, fresh env seeds (after a
    # resume, seeds continue from the step count so the continued run does not replay old episodes)
    rng = np.random.default_rng([seed, env_steps])
    by_label = [[j for j, lab in enumerate(human_labels) if lab == k] for k in range(len(intents))]
    next_seed = iter(range(seed * 1_000_003 + env_steps, 2**62))

    def draw() -> EpisodeSpec:
        label = int(rng.integers(len(intents)))
        return EpisodeSpec(seed=next(next_seed), human=int(rng.choice(by_label[label])), label=label)

    drivers = HumanDrivers(human_agents, ac.num_envs, explore=ac.human_explore, seed=seed * 7 + 1 + env_steps)
    experts = [ExpertFilter(e, ac.num_envs, sample=True, seed=seed * 11 + k + env_steps)
               for k, e in enumerate(expert_agents)] if method.uses_experts else None
    label_field = INTENT_HEAD_NAME if method.intent_head else None
    collector = SharedCollector(envs, drivers, intents, draw, assistant=agent, experts=experts,
                                reward_config=ac.reward, label_field=label_field, partner_window=ac.partner_window,
                                reward_by_intent=method.relabels_reward(cfg))

    def evaluate_panel(assistant, steps: bool = False) -> list[dict[str, Any]]:
        return _run_panel(the_panel, by_id, intents, make_env, ac, seed, assistant, expert_agents,
                          method, cfg, steps=steps)

    if unassisted is None:
        started = time.perf_counter()
        unassisted = evaluate_panel(None)
        timer.add("evaluation", time.perf_counter() - started)

    pending = state.pending()
    tags = {"track": bundle.track.name, "pair": pair, "method": method.name, "seed": seed}
    curve = LiveCurve(store, f"assistants/{bundle.track.name}/{pair}/{method.name}/seed{seed}-{key[:12]}",
                      state.curve_rows)
    state.curve_rows = curve.rows
    recent: deque[dict[str, Any]] = deque(maxlen=40)
    last_metrics: dict[str, float] = {}
    next_log = (env_steps // ac.log_every + 1) * ac.log_every
    start_time, start_updates = time.monotonic(), agent.updates_done if hasattr(agent, "updates_done") else 0
    try:
        while pending:
            finished = collector.step(explore=True, learn=True)
            for row in finished:
                drawn[human_population[row["human"]]] += 1
            recent.extend(finished)
            env_steps += collector.n
            state.env_steps = env_steps
            started = time.perf_counter()
            for _ in range(agent.updates_due(env_steps)):
                last_metrics = agent.train_step()
            timer.add("learning", time.perf_counter() - started)
            if env_steps >= next_log or env_steps >= pending[0]:
                curve.append({"env_step": env_steps, **_episode_stats(list(recent), len(intents)),
                              # wall-clock timings stay out: the curve is hashed into the run's id
                              **{k: round(v, 6) for k, v in last_metrics.items() if not k.startswith("time/")}})
                next_log = (env_steps // ac.log_every + 1) * ac.log_every
            if progress:
                elapsed = max(time.monotonic() - start_time, 1e-9)
                updates = getattr(agent, "updates_done", 0)
                progress({"method": method.name, "env_steps": env_steps, "total": ac.env_steps,
                          "updates_per_s": (updates - start_updates) / elapsed,
                          "recent_return": float(np.mean([e["assist/total"] for e in recent])) if recent else None,
                          "recent_progress_m": float(np.mean([e["progress_m"] for e in recent])) if recent else None})
            if env_steps >= pending[0]:
                pending.pop(0)
                started = time.perf_counter()
                checkpoint = _store_checkpoint(store, agent, the_panel, unassisted, intents, inputs, env_steps,
                                               ac, config_record, seed, tags, evaluate_panel)
                timer.add("evaluation", time.perf_counter() - started)
                for name, seconds in collector.timing.items():
                    timer.add(name, seconds)
                collector.timing.clear()
                state.checkpointed(checkpoint, {"format": RUN_FORMAT, "agent": agent.state_dict(include_replay=True),
                                                "unassisted": unassisted, "timing": timer.seconds, "drawn": drawn})
    except TrainingError as exc:
        raise state.stopped(exc, f"assistant ({method.name})") from None
    finally:
        curve.close()
        for env in envs:
            env.close()

    checkpoints = state.checkpoints
    final = checkpoints[-1]
    runtime = {"device": device, "torch_threads": torch.get_num_threads(), "cpu_kernels": native.status(),
               "mkl_on_amd": mkl_on_amd.status()}
    result = {"method": method.name, "track": bundle.track.name, "track_id": bundle.track_id, "pair": pair,
              "intents": list(intents), "seed": seed, "id": final["id"], "populations": population_ids,
              "training_episodes": dict(zip(population_ids, drawn)),
              "panel": [vars(h) for h in the_panel], "checkpoints": checkpoints,
              "time_shares": timer.shares(), "time_s": {k: round(v, 3) for k, v in timer.seconds.items()},
              "training_code_version": TRAINING_CODE_VERSION, "runtime": runtime,
              "resumed_from_env_step": state.resumed_from}
    timing = ("time_shares", "time_s")  # wall clock: in the manifest's provenance, not in the hashed files
    with store.create("assistant-run", inputs=[*inputs, *(c["id"] for c in checkpoints)], config=config_record,
                      seed=seed, labels={**tags, "run_key": key}) as writer:
        writer.add_json("run.json", result_record(result, leave_out=timing))
        for name in timing:
            writer.note(name, result[name])
        writer.note("config_source", config_source)
        writer.add_json("unassisted.json", {"episodes": unassisted})
        writer.add_bytes("curve.jsonl", curve.jsonl_bytes())
    names = _aliases(bundle.track.name, pair, method.name, seed, final["id"], writer.artifact.id, move_aliases)
    moved = state.finish(names)
    return dict(result, run_id=writer.artifact.id, cached=False, aliases_moved=moved)


def _aliases(track: str, pair: str, method: str, seed: int, final_id: str, run_id: str,
             main: bool = True) -> dict[str, str]:
    """The names a finished assistant run is found by: its final checkpoint and its run record;
    a side run (`main=False`) only by its own `assistant-runs/.../seed<k>/side/<run id>`, which
    keeps it and its checkpoints (the run's inputs) from `d2a artifacts gc`."""
    name = f"{track}/{pair}/{method}/seed{seed}"
    if not main:
        return {f"assistant-runs/{name}/side/{run_id[:12]}": run_id}
    return {f"assistants/{name}": final_id, f"assistant-runs/{name}": run_id}


def _episode_stats(episodes: list[dict[str, Any]], classes: int) -> dict[str, Any]:
    """Training-curve columns from recent episodes: outcome rates, each assistant reward term's
    mean episode sum, and the intent estimate's per-step accuracy."""
    if not episodes:
        return {"episode/episodes": 0}
    out = {f"episode/{k}": v for k, v in aggregate(
        [{k: e[k] for k in ("progress_m", "return", "finished", "collision", "off_track", "intervention")}
         for e in episodes]).items()}
    for name in ASSISTANT_TERMS:
        values = [e[f"assist/{name}"] for e in episodes if e.get(f"assist/{name}") is not None]
        if values:
            out[f"assist/{name}"] = round(float(np.mean(values)), 6)
    acc = [e["intent_accuracy"] for e in episodes if "intent_accuracy" in e]
    if acc:
        out["episode/intent_accuracy"] = round(float(np.mean(acc)), 6)
    return out


def _run_panel(the_panel: Sequence[PanelHuman], by_id: dict[str, Any], intents: Sequence[str], make_env,
               ac, seed: int, assistant, expert_agents, method: Method, cfg, steps: bool) -> list[dict[str, Any]]:
    """Every panel human on the same `panel_episodes` env seeds; assisted when `assistant` is
    given (its mode), else unassisted. One row per spec, in spec order."""
    specs = [EpisodeSpec(seed=20_000_003 + seed * 1_000 + j, human=h, label=the_panel[h].label)
             for h in range(len(the_panel)) for j in range(ac.panel_episodes)]
    queue = iter(specs)
    envs = [make_env() for _ in range(max(1, min(ac.eval_envs, len(specs))))]
    agents = [by_id[h.id] for h in the_panel]
    drivers = HumanDrivers(agents, len(envs), explore=False, seed=0)
    experts = None
    if assistant is not None and method.uses_experts:
        experts = [ExpertFilter(e, len(envs), sample=False, seed=k) for k, e in enumerate(expert_agents)]
    try:
        collector = SharedCollector(envs, drivers, intents, lambda: next(queue, None), assistant=assistant,
                                    experts=experts, reward_config=cfg.assistant.reward, keep_steps=steps,
                                    label_field=None, partner_window=ac.partner_window)
        rows: list[dict[str, Any]] = []
        while not collector.idle:
            rows.extend(collector.step(explore=False, learn=False))
    finally:
        for env in envs:
            env.close()
    order = {(s.human, s.seed): k for k, s in enumerate(specs)}
    return sorted(rows, key=lambda r: order[(r["human"], r["seed"])])


def _steps_npz(logs: Sequence[dict[str, Any]]) -> bytes:
    """Per-step logs of the assisted panel episodes, concatenated: `episode` (row index in
    eval.json's `assisted`), the unweighted reward terms (`terms`, columns `term_names`), the
    inferred intent `y_hat`, its probability of the true intent `p_true`, and both actions."""
    episode = np.concatenate([np.full(len(log["terms"]), k, np.int32) for k, log in enumerate(logs)] or
                             [np.zeros(0, np.int32)])
    def stack(name: str, width: int) -> np.ndarray:
        rows = [np.asarray(log[name], np.float32).reshape(-1, width) for log in logs if len(log[name])]
        return np.concatenate(rows) if rows else np.zeros((0, width), np.float32)

    arrays = {"episode": episode, "terms": stack("terms", len(ASSISTANT_TERMS)),
              "term_names": np.array(ASSISTANT_TERMS), "human_action": stack("human_action", 2),
              "assistant_action": stack("assistant_action", 2)}
    if all(len(log["y_hat"]) == len(log["terms"]) for log in logs) and any(len(log["y_hat"]) for log in logs):
        arrays["y_hat"] = np.concatenate([np.asarray(log["y_hat"], np.int8) for log in logs])
        arrays["p_true"] = np.concatenate([np.asarray(log["p_true"], np.float32) for log in logs])
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def _store_checkpoint(store: Store, agent, the_panel, unassisted, intents, inputs, env_steps, ac, config_record,
                      seed, tags, evaluate_panel) -> dict[str, Any]:
    assisted = evaluate_panel(agent, steps=True)
    step_logs = [row.pop("steps_log") for row in assisted]
    summary = paired_summary(the_panel, unassisted, assisted, intents)
    fraction = round(env_steps / ac.env_steps, 6)
    with store.create("assistant", inputs=inputs, config=config_record, seed=seed,
                      labels={**tags, "env_step": env_steps, "fraction": fraction}) as writer:
        writer.add_bytes("agent.pt", agent_bytes(agent))
        writer.add_json("eval.json", {"summary": summary, "panel": [vars(h) for h in the_panel],
                                      "assisted": assisted})
        writer.add_bytes("steps.npz", _steps_npz(step_logs))
    return {"id": writer.artifact.id, "env_step": env_steps, "fraction": fraction, "metrics": summary}
