"""`d2a intent-swap`: the human's intent flips mid-episode (paper appendix, "intent swap").

A trial starts with a human of one intent of the pair; at a random step inside the swap window it
is replaced by the *comparably trained* human of the other intent (the checkpoint of the other
population at the same training step), which starts from a blank recurrent state. Both
directions are run (`trials` each), unassisted and with every assistant, on the same trials.

Reported per assistant and direction:

- `accuracy_since_swap`: the per-step intent accuracy against the *current* true intent, by time
  since the swap (bins of one control step, `dt` = 0.1 s), averaged over trials: from
  `-PRE_S` before the swap to the longest trial's end;
- `recovery_s`: the time after the swap at which that mean accuracy first reaches
  `RECOVERY_LEVEL` (90 %) and stays there for `HOLD_S` (or until the curve ends), None if never;
  per trial the same on its own 0/1 sequence (`trial_recovery_s`, and their median);
- the `eval` metrics (progress, collision, intervention, speed) of the trials, assisted and
  unassisted, and their paired change.

Each (method, seed) is an artifact of kind `intent-swap` (alias
`intent-swap/<track>/<pair>/<method>/seed<k>`) holding the trials, the curves and every episode as
an MCAP log.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.artifacts import Store, content_key
from d2a_core.errors import UsageError
from d2a_core.pipelines.evaluate import find_assistants, run_specs, stored_row
from d2a_core.sim.race_env import EnvConfig, RaceEnv
from d2a_core.training.code_version import TRAINING_CODE_VERSION
from d2a_core.run_inputs import ENV_SECTIONS, load_populations, load_track_bundle, parse_pair
from d2a_core.stored_agents import load_assistant, load_human
from d2a_core.training.shared_rollout import EpisodeSpec

SWAP_FORMAT = 1
RECOVERY_LEVEL = 0.9
HOLD_S = 1.0
PRE_S = 2.0
METRICS = ("progress_m", "collision", "intervention", "mean_speed_m_s")
SEED_BASE = 70_000_019

ProgressFn = Callable[[dict[str, Any]], None]


def matched_pairs(populations: Sequence[dict[str, Any]]) -> list[tuple[int, int]]:
    """(index in population 0, index in population 1) of checkpoints trained for the same number
    of env steps: the comparably trained humans of the two intents."""
    steps_b = {c["env_step"]: k for k, c in enumerate(populations[1]["checkpoints"])}
    pairs = [(k, steps_b[c["env_step"]]) for k, c in enumerate(populations[0]["checkpoints"])
             if c["env_step"] in steps_b]
    if not pairs:
        raise UsageError("the two populations share no training step: no comparably trained humans to swap")
    return pairs


def trial_specs(populations: Sequence[dict[str, Any]], trials: int, window_steps: tuple[int, int],
                seed: int) -> list[EpisodeSpec]:
    """`trials` per direction: a random matched pair, a random swap step inside the window, a
    fresh env seed. Human indices count population 0's checkpoints first, then population 1's."""
    pairs = matched_pairs(populations)
    offset = len(populations[0]["checkpoints"])
    rng = np.random.default_rng([seed, 7])
    specs = []
    for direction in (0, 1):
        for j in range(trials):
            a, b = pairs[int(rng.integers(len(pairs)))]
            first, second = (a, offset + b) if direction == 0 else (offset + b, a)
            swap = int(rng.integers(window_steps[0], window_steps[1] + 1))
            specs.append(EpisodeSpec(seed=SEED_BASE + 1000 * seed + 100 * direction + j, human=first, label=direction,
                                     swap_step=swap, swap_human=second, swap_label=1 - direction))
    return specs


def recovery_time(accuracy: np.ndarray, dt: float, level: float = RECOVERY_LEVEL, hold_s: float = HOLD_S) -> float | None:
    """Seconds after the swap (index 0 of `accuracy`) until accuracy first reaches `level` and
    stays there for `hold_s` (or to the end of the series); None when it never does."""
    hold = max(1, int(round(hold_s / dt)))
    ok = np.asarray(accuracy, float) >= level
    for k in range(len(ok)):
        if ok[k:k + hold].all():
            return round(k * dt, 6)
    return None


def swap_curves(rows: Sequence[dict], logs: Sequence[dict], dt: float, intents: Sequence[str]) -> dict[str, Any]:
    """Per direction: mean accuracy by time since the swap, its recovery time, and per-trial
    recovery times. `rows` and `logs` are the assisted trials and their per-step logs."""
    out: dict[str, Any] = {}
    pre = int(round(PRE_S / dt))
    for direction in (0, 1):
        name = f"{intents[direction]}-to-{intents[1 - direction]}"
        series, trial_recovery, before_swap = [], [], 0
        for row, log in zip(rows, logs):
            if row["label"] != direction or not log["y_hat"]:
                continue
            correct = (np.array(log["y_hat"]) == np.array(log["labels"])).astype(float)
            swap = row["swap_step"]
            if swap >= len(correct):  # the episode ended (a crash) before its swap: nothing to recover from
                before_swap += 1
                continue
            series.append((correct, swap))
            trial_recovery.append(recovery_time(correct[swap:], dt))
        if not series:
            out[name] = None if not before_swap else {
                "time_s": [], "accuracy": [], "trials": 0, "recovery_s": None, "trial_recovery_s": [],
                "median_trial_recovery_s": None, "recovered_trials": 0, "ended_before_swap": before_swap}
            continue
        length = max(len(c) - s for c, s in series)
        grid = np.full((len(series), pre + length), np.nan)
        for k, (correct, swap) in enumerate(series):
            steps = np.arange(max(0, swap - pre), len(correct))
            grid[k, steps - (swap - pre)] = correct[steps]
        with np.errstate(invalid="ignore"):
            mean = np.nanmean(grid, axis=0)
        times = (np.arange(grid.shape[1]) - pre) * dt
        reached = [r for r in trial_recovery if r is not None]
        out[name] = {
            "time_s": np.round(times, 6).tolist(),
            "accuracy": [None if np.isnan(v) else round(float(v), 6) for v in mean],
            "trials": len(series),
            "recovery_s": recovery_time(mean[pre:], dt),
            "trial_recovery_s": trial_recovery,
            "median_trial_recovery_s": round(float(np.median(reached)), 6) if reached else None,
            "recovered_trials": len(reached),
            "ended_before_swap": before_swap,
        }
    return out


def _metric_block(unassisted: Sequence[dict], assisted: Sequence[dict]) -> dict[str, Any]:
    base = {(r["human"], r["seed"]): r for r in unassisted}
    pairs = [(base[(r["human"], r["seed"])], r) for r in assisted]
    block: dict[str, Any] = {}
    for m in METRICS:
        u = [x[m] for x, _ in pairs]
        a = [y[m] for _, y in pairs]
        block[m] = {"unassisted": round(float(np.mean(u)), 6), "assisted": round(float(np.mean(a)), 6),
                    "delta_mean": round(float(np.mean(np.subtract(a, u))), 6),
                    "delta_std": round(float(np.std(np.subtract(a, u))), 6)}
    return block


def intent_swap(store: Store, track_ref: str, pair: str, method: str = "dream2assist", baselines: Sequence[str] = (),
                seeds: Sequence[int] | None = None, humans: Sequence[str] | None = None, trials: int = 10,
                window_s: tuple[float, float] = (3.0, 8.0), eval_seed: int = 0, n_envs: int = 8,
                device: str = "cpu", progress: ProgressFn | None = None) -> dict[str, Any]:
    """Run the intent-swap trials for `method` and `baselines`; see the module docstring."""
    if trials < 1:
        raise UsageError(f"--trials must be at least 1, got {trials}")
    if not 0 <= window_s[0] <= window_s[1]:
        raise UsageError(f"--window must be two times 0 <= start <= end (s), got {window_s[0]} {window_s[1]}")
    with store.lease():
        return _intent_swap(store, track_ref, pair, [method, *baselines], seeds, humans, trials, window_s, eval_seed,
                            n_envs, device, progress)


def _intent_swap(store, track_ref, pair, names, seeds, humans_refs, trials, window_s, eval_seed, n_envs, device,
                 progress):
    from d2a_core.config.schema import Config

    intents = parse_pair(pair)
    track = load_track_bundle(store, track_ref, EnvConfig().dt).track.name
    found = find_assistants(store, track, pair, names, seeds)
    env_record = {k: store.get(found[0][2]).config[k] for k in ENV_SECTIONS}
    for name, seed, art_id in found[1:]:
        if {k: store.get(art_id).config[k] for k in ENV_SECTIONS} != env_record:
            raise UsageError(f"{name} seed {seed} was trained in another env config; run intent-swap separately")
    cfg = Config.model_validate(env_record)
    dt = cfg.env.dt
    bundle = load_track_bundle(store, track_ref, dt)
    populations = load_populations(store, bundle, intents, humans_refs)
    pops = [pop for _, pop in populations]
    window = (int(round(window_s[0] / dt)), int(round(window_s[1] / dt)))
    specs = trial_specs(pops, trials, window, eval_seed)
    human_ids = [c["id"] for pop in pops for c in pop["checkpoints"]]
    used = sorted({s.human for s in specs} | {s.swap_human for s in specs})

    def make_env() -> RaceEnv:
        return bundle.env(cfg)

    probe = make_env()
    obs_space, act_space = probe.observation_space, probe.action_space
    probe.close()
    agents: list[Any] | None = None
    unassisted: list[dict] | None = None
    results = []
    with store.scratch_dir("intent-swap") as tmp:
        logs_root = Path(tmp)
        for k, (name, seed, art_id) in enumerate(found):
            identity = {"format": SWAP_FORMAT, "code": TRAINING_CODE_VERSION, "assistant": art_id,
                        "specs": [vars(s) for s in specs], "humans": human_ids, "env": env_record}
            key = content_key(identity)
            done = store.finished("intent-swap", key)
            if done is not None:
                results.append(dict(store.read_json(done.id, "swap.json")["result"], id=done.id, cached=True))
                continue
            if progress:
                progress({"stage": f"{name} seed {seed}", "done": k, "total": len(found)})
            if agents is None:
                loaded = {i: load_human(store, human_ids[i], obs_space, act_space, device) for i in used}
                agents = [loaded.get(i) for i in range(len(human_ids))]
                unassisted, _ = run_specs(specs, agents, intents, make_env, n_envs, logs_root / "unassisted", None,
                                          {"condition": "unassisted", "track": track, "experiment": "intent-swap"})
            assistant, _, trained_on, partner_window = load_assistant(store, art_id, obs_space, act_space, device)
            if tuple(trained_on) != tuple(intents):
                raise UsageError(f"assistant {art_id[:12]} was trained on {'-'.join(trained_on)}, not {pair}")
            assisted, step_logs = run_specs(specs, agents, intents, make_env, n_envs, logs_root / f"{name}-{seed}",
                                            assistant, {"condition": "assisted", "method": name, "assistant": art_id,
                                                        "track": track, "experiment": "intent-swap"},
                                            partner_window=partner_window)
            result = {"method": name, "seed": seed, "assistant": art_id, "track": track, "pair": pair,
                      "trials_per_direction": trials, "window_s": list(window_s), "eval_seed": eval_seed,
                      "dt": dt, "recovery_level": RECOVERY_LEVEL, "hold_s": HOLD_S,
                      "directions": swap_curves(assisted, step_logs, dt, intents),
                      "metrics": {f"{intents[d]}-to-{intents[1 - d]}": _metric_block(
                          [r for r in unassisted if r["label"] == d], [r for r in assisted if r["label"] == d])
                          for d in (0, 1)}}
            with store.create("intent-swap", inputs=[art_id, *[human_ids[i] for i in used], bundle.track_id,
                                                     *(pid for pid, _ in populations)],
                              config=env_record, seed=eval_seed,
                              labels={"track": track, "pair": pair, "method": name, "seed": seed,
                                      "run_key": key}) as writer:
                writer.add_json("swap.json", {"result": result, "specs": [vars(s) for s in specs],
                                              "unassisted": [stored_row(r) for r in unassisted],
                                              "assisted": [stored_row(r) for r in assisted]})
                for condition, rows in (("unassisted", unassisted), ("assisted", assisted)):
                    for r in rows:
                        writer.add_file(f"episodes/{condition}/trial-seed{r['seed']}.mcap", r["log"])
            store.tag(writer.artifact.id, f"intent-swap/{track}/{pair}/{name}/seed{seed}")
            results.append(dict(result, id=writer.artifact.id, cached=False))
    return {"intent_swaps": results}
