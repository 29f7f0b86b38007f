"""`d2a eval`: the paper's evaluation protocol on stored assistants and humans, paired.

For a pair, the humans under test come from each intent's population by the paper's rule
(`evaluation.paired.select_humans`: five imperfect humans at every 20 % of the expert's
performance, and the near-perfect ones). Each human drives `episodes` episodes unassisted and,
on the same env seeds (so the same start and opponent replay), with every assistant evaluated:
the main method and its baselines, for each training seed. A difference between the two
conditions of one spec is the assistant's doing. Humans act with their actor's mode, assistants
with theirs.

Per assistant an `evaluation` artifact holds every episode row of both conditions, the summary
and the per-step log of the assisted episodes (the inferred intent's probability of the true
intent at every step, both actions and the reward terms), with inputs: the assistant, the humans
and the track. Alias `eval/<track>/<pair>/<method>/seed<k>` (with `/humans-<ids>` appended when
the humans come from populations the assistant was not trained with: `held_out` in the result).
By default the assistants are the final ones (`assistants/<track>/<pair>/<method>/seed<k>`);
`assistants=` names any assistant artifacts instead, e.g. checkpoints along a run, whose
evaluations get `/checkpoint-<id>` in their alias so they never take the final's.
An evaluation is deterministic, so an identical request
returns the stored artifact.

The env (env, reward, vehicle, world sections) is the one the assistants were trained in, read
from their artifacts; assistants trained in different envs are not compared.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.artifacts import Store, content_key
from d2a_core.errors import NotFoundError, UsageError
from d2a_core.evaluation.criteria import CRITERION_KEY, criterion_value
from d2a_core.evaluation.paired import TestHuman, f1_macro, f1_of_class, intent_confusion, select_humans
from d2a_core.evaluation.safety import safety_flags
from d2a_core.objectives.assistant import AssistantRewardConfig
from d2a_core.sim.race_env import EnvConfig, RaceEnv
from d2a_core.training.code_version import TRAINING_CODE_VERSION
from d2a_core.run_inputs import ENV_SECTIONS, load_populations, load_track_bundle, parse_pair
from d2a_core.stored_agents import load_assistant, load_human
from d2a_core.training.methods import get_method
from d2a_core.training.shared_rollout import EpisodeSpec, HumanDrivers, SharedCollector

EVAL_FORMAT = 2  # 2: the off-track rate is recorded beside the collision rate
METRICS = ("progress_m", "return", "collision", "off_track", "intervention", "mean_speed_m_s")
"""The paper's Table 1 metrics, per human: means over its episodes; `return` is under the human's
own objective (r^task + r^intent). `off_track` (not in the paper's table) is the share of
episodes that ended off the road: with `collision`, what the safety rule bounds."""
# ... and the human's own intent criterion (`evaluation.criteria.criterion_value`: finished ahead
# for pass, finished never ahead for stay, the side share for left/right), so a table shows whether
# assistance served the intent, not only the progress.
CRITERION = CRITERION_KEY
SUMMARY_METRICS = (*METRICS, CRITERION)
SEED_BASE = 50_000_017  # env seeds of evaluation episodes: SEED_BASE + 1000 * eval_seed + j

ProgressFn = Callable[[dict[str, Any]], None]


def assistant_alias(track: str, pair: str, method: str, seed: int) -> str:
    return f"assistants/{track}/{pair}/{method}/seed{seed}"


def stored_seeds(store: Store, track: str, pair: str, method: str) -> list[int]:
    """Training seeds with a stored assistant of this track, pair and method."""
    prefix = assistant_alias(track, pair, method, 0)[:-1]
    return sorted(int(a[len(prefix):]) for a in store.refs() if a.startswith(prefix) and a[len(prefix):].isdigit())


def find_assistants(store: Store, track: str, pair: str, names: Sequence[str],
                seeds: Sequence[int] | None) -> list[tuple[str, int, str]]:
    """(method, seed, assistant id) for every method and seed asked for."""
    out = []
    for name in names:
        get_method(name)
        chosen = list(seeds) if seeds else stored_seeds(store, track, pair, name)
        if not chosen:
            raise NotFoundError(f"no stored {name} assistant for {track} {pair}; make one with: "
                                f"d2a train-assistant --track {track} --pair {pair} --method {name} --seed 0")
        for seed in chosen:
            alias = assistant_alias(track, pair, name, seed)
            try:
                out.append((name, seed, store.resolve(alias)))
            except NotFoundError:
                raise NotFoundError(f"no assistant {alias!r} in store {store.root}; make it with: "
                                    f"d2a train-assistant --track {track} --pair {pair} --method {name} "
                                    f"--seed {seed}") from None
    return out


def named_assistants(store: Store, track: str, pair: str, refs: Sequence[str]) -> list[tuple[str, int, str]]:
    """(method, seed, assistant id) of assistant artifacts named by id, prefix or alias (e.g. a
    checkpoint along a run, not only its final one); method and seed come from their labels."""
    out = []
    for ref in refs:
        art = store.get(ref)
        if art.kind != "assistant":
            raise UsageError(f"--assistant {ref!r} is a {art.kind} artifact, not an assistant")
        if (art.labels.get("track"), art.labels.get("pair")) != (track, pair):
            raise UsageError(f"assistant {art.id[:12]} was trained on {art.labels.get('track')} "
                             f"{art.labels.get('pair')}, not {track} {pair}")
        out.append((art.labels["method"], int(art.labels["seed"]), art.id))
    if len({a for _, _, a in out}) != len(out):
        raise UsageError("an assistant is named twice")
    return out


def _stats(values: Sequence[float]) -> dict[str, float | None]:
    values = [v for v in values if v is not None]
    if not values:
        return {"mean": None, "std": None}
    return {"mean": round(float(np.mean(values)), 6), "std": round(float(np.std(values)), 6)}


def _per_human(humans: Sequence[TestHuman], unassisted: Sequence[dict], assisted: Sequence[dict]) -> list[dict]:
    base = {(r["human"], r["seed"]): r for r in unassisted}
    out = []
    for h, human in enumerate(humans):
        mine = [(base[(r["human"], r["seed"])], r) for r in assisted if r["human"] == h]
        u = {m: round(float(np.mean([x[m] for x, _ in mine])), 6) for m in METRICS}
        a = {m: round(float(np.mean([y[m] for _, y in mine])), 6) for m in METRICS}
        u[CRITERION] = round(float(np.mean([criterion_value(human.intent, x) for x, _ in mine])), 6)
        a[CRITERION] = round(float(np.mean([criterion_value(human.intent, y) for _, y in mine])), 6)
        row = {**vars(human), "episodes": len(mine), "unassisted": u, "assisted": a,
               "delta": {m: round(a[m] - u[m], 6) for m in SUMMARY_METRICS}}
        accuracy = [y["intent_accuracy"] for _, y in mine if "intent_accuracy" in y]
        if accuracy:
            row["intent_accuracy"] = round(float(np.mean(accuracy)), 6)
        out.append(row)
    return out


def summarise(humans: Sequence[TestHuman], unassisted: Sequence[dict], assisted: Sequence[dict],
              intents: Sequence[str]) -> dict[str, Any]:
    """Per intent and group, mean and std over humans of each metric's change (assisted minus
    unassisted, per human over its paired episodes) and of the unassisted intent criterion;
    per-class and macro per-step intent F1."""
    per_human = _per_human(humans, unassisted, assisted)
    counts = intent_confusion(assisted, len(intents))
    has_estimate = bool(counts.sum())
    out: dict[str, Any] = {"intents": {}, "humans": per_human,
                           "intent_f1": round(f1_macro(counts), 6) if has_estimate else None,
                           "intent_confusion": counts.tolist() if has_estimate else None}
    for label, intent in enumerate(intents):
        block: dict[str, Any] = {}
        for group in ("imperfect", "near_perfect"):
            rows = [r for r in per_human if r["intent"] == intent and r["group"] == group]
            if rows:
                block[group] = {m: _stats([r["delta"][m] for r in rows]) for m in SUMMARY_METRICS}
                block[group][f"{CRITERION}_unassisted"] = _stats([r["unassisted"][CRITERION] for r in rows])
        f1 = f1_of_class(counts, label) if has_estimate else None
        block["intent_f1"] = None if f1 is None else round(f1, 6)
        out["intents"][intent] = block
    return out


def panel_specs(humans: Sequence[TestHuman], episodes: int, eval_seed: int) -> list[EpisodeSpec]:
    """Every human's `episodes` episodes on the same env seeds, grouped by human (so a batch of
    envs holds few distinct humans)."""
    return [EpisodeSpec(seed=SEED_BASE + 1000 * eval_seed + j, human=h, label=humans[h].label)
            for h in range(len(humans)) for j in range(episodes)]


def run_specs(specs: Sequence[EpisodeSpec], human_agents: Sequence[Any], intents: Sequence[str], make_env,
              n_envs: int, log_dir: Path, assistant=None, log_metadata: dict[str, Any] | None = None,
              record_features: Callable[[EpisodeSpec], bool] | None = None,
              partner_window: int = 1) -> tuple[list[dict], list[dict]]:
    """Drive every spec (humans act with their mode; the assistant, if any, with its mode, seeing
    `partner_window` of the human's last actions).
    Returns the rows in spec order and, when assisted, their per-step logs. Each episode's MCAP
    log goes to `log_dir` (its path in the row's `log`)."""
    queue = iter(specs)
    envs = [make_env() for _ in range(max(1, min(n_envs, len(specs))))]
    drivers = HumanDrivers(list(human_agents), len(envs), explore=False, seed=0)
    try:
        # no expert terms in evaluation: the metrics are the human's, not the assistant's reward
        collector = SharedCollector(envs, drivers, intents, lambda: next(queue, None), assistant=assistant,
                                    reward_config=AssistantRewardConfig(alpha_r=0.0, alpha_a=0.0),
                                    keep_steps=assistant is not None, label_field=None, log_dir=log_dir,
                                    log_metadata=log_metadata, record_features=record_features,
                                    partner_window=partner_window)
        try:
            rows: list[dict] = []
            while not collector.idle:
                rows.extend(collector.step(explore=False, learn=False))
        finally:
            collector.close()
    finally:
        for env in envs:
            env.close()
    order = {(s.human, s.seed): k for k, s in enumerate(specs)}
    rows.sort(key=lambda r: order[(r["human"], r["seed"])])
    logs = [r.pop("steps_log") for r in rows if "steps_log" in r]
    return rows, logs


def _steps_npz(rows: Sequence[dict], logs: Sequence[dict]) -> bytes:
    """Per-step arrays of the assisted episodes, concatenated (`episode`: row index)."""
    arrays: dict[str, np.ndarray] = {
        "episode": np.concatenate([np.full(len(log["terms"]), k, np.int32) for k, log in enumerate(logs)]),
        "label": np.concatenate([np.full(len(log["terms"]), r["label"], np.int8) for r, log in zip(rows, logs)]),
        "human_action": np.concatenate([np.asarray(log["human_action"], np.float32).reshape(-1, 2) for log in logs]),
        "assistant_action": np.concatenate([np.asarray(log["assistant_action"], np.float32).reshape(-1, 2)
                                            for log in logs]),
    }
    if all(len(log["y_hat"]) == len(log["terms"]) for log in logs):
        arrays["y_hat"] = np.concatenate([np.asarray(log["y_hat"], np.int8) for log in logs])
        arrays["p_true"] = np.concatenate([np.asarray(log["p_true"], np.float32) for log in logs])
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def evaluate(store: Store, track_ref: str, pair: str, method: str | None = None, baselines: Sequence[str] = (),
             seeds: Sequence[int] | None = None, humans: Sequence[str] | None = None, episodes: int = 20,
             eval_seed: int = 0, n_envs: int = 8, device: str = "cpu",
             progress: ProgressFn | None = None, assistants: Sequence[str] | None = None) -> dict[str, Any]:
    """Evaluate `method` (default dream2assist) and `baselines`, every stored seed unless `seeds`;
    or, instead, the assistant artifacts named in `assistants`. See the module docstring."""
    if episodes < 1:
        raise UsageError(f"--episodes must be at least 1, got {episodes}")
    if assistants and (method or baselines or seeds):
        raise UsageError("--assistant names the assistants itself; drop --method, --baseline and --seed")
    with store.lease():
        result = _evaluate(store, track_ref, pair, [method or "dream2assist", *baselines], seeds, humans, episodes,
                           eval_seed, n_envs, device, progress, assistants)
    for evaluation in result["evaluations"]:  # read off the stored numbers, so stored results get it too
        evaluation["safety_flags"] = safety_flags(evaluation)
    return result


class _EvalRun:
    """What every assistant of one `d2a eval` call shares: the env, the humans under test, their
    loaded agents and (once run) their unassisted episodes."""

    def __init__(self, store: Store, track_ref: str, pair: str, intents: tuple[str, ...], env_record: dict,
                 humans_refs: Sequence[str] | None, episodes: int, eval_seed: int, n_envs: int, device: str,
                 log_root: Path) -> None:
        from d2a_core.config.schema import Config

        self.store, self.pair, self.intents = store, pair, intents
        self.env_record, self.episodes, self.eval_seed, self.n_envs, self.device = (
            env_record, episodes, eval_seed, n_envs, device)
        self.log_root = log_root
        self.cfg = Config.model_validate(env_record)
        self.bundle = load_track_bundle(store, track_ref, self.cfg.env.dt)
        self.track = self.bundle.track.name
        populations = load_populations(store, self.bundle, intents, humans_refs)
        self.population_ids = [pid for pid, _ in populations]
        self.humans = [h for label, (_, pop) in enumerate(populations)
                       for h in select_humans(pop, intents[label], label)]
        self.human_ids = [h.id for h in self.humans]
        self.held_out_suffix = "/humans-" + "-".join(p[:8] for p in self.population_ids)
        probe = self.make_env()
        self.obs_space, self.act_space = probe.observation_space, probe.action_space
        probe.close()
        self._agents: dict[str, Any] | None = None
        self._unassisted: list[dict] | None = None

    def make_env(self) -> RaceEnv:
        return self.bundle.env(self.cfg)

    def run(self, name: str, assistant=None, metadata: dict[str, Any] | None = None,
            partner_window: int = 1) -> tuple[list[dict], list[dict]]:
        if self._agents is None:
            self._agents = {hid: load_human(self.store, hid, self.obs_space, self.act_space, self.device)
                            for hid in dict.fromkeys(self.human_ids)}
        specs = panel_specs(self.humans, self.episodes, self.eval_seed)
        first_seed = specs[0].seed  # latent states of each human's first episode, for the report's t-SNE
        return run_specs(specs, [self._agents[h.id] for h in self.humans], self.intents, self.make_env, self.n_envs,
                         self.log_root / name, assistant, {"track": self.track, **(metadata or {})},
                         partner_window=partner_window,
                         record_features=lambda spec: spec.seed == first_seed)

    def unassisted(self) -> list[dict]:
        if self._unassisted is None:
            self._unassisted, _ = self.run("unassisted", metadata={"condition": "unassisted"})
        return self._unassisted

    def run_key(self, art_id: str) -> str:
        identity = {"format": EVAL_FORMAT, "code": TRAINING_CODE_VERSION, "assistant": art_id,
                    "humans": self.human_ids, "episodes": self.episodes, "eval_seed": self.eval_seed,
                    "env": self.env_record}
        return content_key(identity)

    def evaluate(self, name: str, seed: int, art_id: str) -> dict[str, Any]:
        """One assistant's evaluation, stored (or the stored one, `cached`)."""
        store = self.store
        key = self.run_key(art_id)
        done = store.finished("evaluation", key)
        if done is not None:
            result = store.read_json(done.id, "eval.json")["result"]
            # the request names this evaluation again: its alias comes back to it
            store.tag(done.id, self.alias(name, seed, art_id, bool(result.get("held_out"))))
            return dict(result, id=done.id, cached=True)
        unassisted = self.unassisted()
        assistant, _, trained_on, window = load_assistant(store, art_id, self.obs_space, self.act_space, self.device)
        if tuple(trained_on) != tuple(self.intents):
            raise UsageError(f"assistant {art_id[:12]} was trained on {'-'.join(trained_on)}, not {self.pair}")
        assisted, step_logs = self.run(f"{name}-seed{seed}-{art_id[:12]}", assistant, {
            "condition": "assisted", "method": name, "assistant_seed": seed, "assistant": art_id},
            partner_window=window)
        latents = _latents_npz(assisted)
        art = store.get(art_id)
        # held out: humans of populations the assistant was not trained with (its inputs say which)
        held_out = not set(self.population_ids) <= set(art.inputs)
        result = {"method": name, "seed": seed, "assistant": art_id, "assistant_env_step": art.labels.get("env_step"),
                  "track": self.track, "pair": self.pair,
                  "populations": self.population_ids, "held_out": held_out, "episodes_per_human": self.episodes,
                  "eval_seed": self.eval_seed, **summarise(self.humans, unassisted, assisted, self.intents)}
        inputs = [art_id, *dict.fromkeys(self.human_ids), self.bundle.track_id, *self.population_ids]
        labels = {"track": self.track, "pair": self.pair, "method": name, "seed": seed, "run_key": key}
        with store.create("evaluation", inputs=inputs, config=self.env_record, seed=self.eval_seed,
                          labels=labels) as writer:
            writer.add_json("eval.json", {"result": result, "unassisted": [stored_row(r) for r in unassisted],
                                          "assisted": [stored_row(r) for r in assisted]})
            writer.add_bytes("steps.npz", _steps_npz(assisted, step_logs))
            if latents is not None:
                writer.add_bytes("latents.npz", latents)
            for condition, rows in (("unassisted", unassisted), ("assisted", assisted)):
                for r in rows:
                    writer.add_file(_log_name(condition, r), r["log"])
        store.tag(writer.artifact.id, self.alias(name, seed, art_id, held_out))
        return dict(result, id=writer.artifact.id, cached=False)

    def alias(self, name: str, seed: int, art_id: str, held_out: bool) -> str:
        """`eval/<track>/<pair>/<method>/seed<k>`, with `/checkpoint-<id>` for an assistant that
        its run's alias does not name (an earlier checkpoint must not take the final's alias) and
        `/humans-<ids>` for held-out humans."""
        suffix = self.held_out_suffix if held_out else ""
        if self.store.refs().get(assistant_alias(self.track, self.pair, name, seed)) != art_id:
            suffix = f"/checkpoint-{art_id[:12]}{suffix}"
        return f"eval/{self.track}/{self.pair}/{name}/seed{seed}{suffix}"


def _log_name(condition: str, row: Mapping[str, Any]) -> str:
    """Where an episode's MCAP log lies inside the evaluation artifact."""
    return f"episodes/{condition}/human{row['human']:03d}-seed{row['seed']}.mcap"


def stored_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """An episode row as stored: its log named by its place in the artifact, not a temp path, and
    its latent features in `latents.npz`."""
    return {k: v for k, v in row.items() if k not in ("log", "features")}


def _latents_npz(rows: Sequence[dict]) -> bytes | None:
    """`latents.npz` of the episodes that kept the assistant's latent features: `features`
    (T, F), the true intent `label` (T,) and `episode` (T,: index into eval.json's `assisted`)."""
    kept = [(k, r) for k, r in enumerate(rows) if r.get("features") is not None]
    if not kept:
        return None
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        features=np.concatenate([r["features"] for _, r in kept]).astype(np.float32),
        label=np.concatenate([np.full(len(r["features"]), r["label"], np.int8) for _, r in kept]),
        episode=np.concatenate([np.full(len(r["features"]), k, np.int32) for k, r in kept]),
    )
    return buffer.getvalue()


def _evaluate(store, track_ref, pair, names, seeds, humans_refs, episodes, eval_seed, n_envs, device, progress,
              assistant_refs=None):

    intents = parse_pair(pair)
    if len(set(names)) != len(names):
        raise UsageError(f"a method is named twice: {', '.join(names)}")
    track = load_track_bundle(store, track_ref, EnvConfig().dt).track.name
    found = (named_assistants(store, track, pair, assistant_refs) if assistant_refs
             else find_assistants(store, track, pair, names, seeds))
    env_record = {k: store.get(found[0][2]).config[k] for k in ENV_SECTIONS}
    for name, seed, art_id in found[1:]:
        if {k: store.get(art_id).config[k] for k in ENV_SECTIONS} != env_record:
            raise UsageError(f"{name} seed {seed} was trained in another env config than {found[0][0]} seed "
                             f"{found[0][1]}; evaluate them separately")
    results = []
    with store.scratch_dir("eval") as tmp:
        run = _EvalRun(store, track_ref, pair, intents, env_record, humans_refs, episodes, eval_seed, n_envs,
                       device, Path(tmp))
        for k, (name, seed, art_id) in enumerate(found):
            if progress:
                progress({"stage": f"{name} seed {seed}", "done": k, "total": len(found)})
            results.append(run.evaluate(name, seed, art_id))
    return {"evaluations": results}
