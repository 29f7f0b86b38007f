"""A small synthetic store for the report tests (`make_store`; the fixture is in conftest.py): artifacts of the formats `train-humans`,
`train-assistant`, `eval` and `intent-swap` write, made directly with `Store.create` (no training),
with values chosen so that the report's cells can be computed by hand.

Straightaway, pass-stay. Dream2Assist seeds 0, 1, 2 and Dreamer seed 0. Each evaluation has three
imperfect and one near-perfect human per intent; the change in progress of Dream2Assist seed `s`
for imperfect human `n` is `10 s + n` (so per-seed means 2, 12, 22; pooled mean 12), Dreamer's is
-5 for everyone. Decoys the report must not read: an evaluation no alias points to (superseded), a
`human` checkpoint and a `track` artifact.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import Writer

from d2a_core.artifacts import Store

TRACK, PAIR, INTENTS = "straightaway", "pass-stay", ("pass", "stay")
D2A_SEEDS = (0, 1, 2)
SMOKE_ASSISTANT = {"env_steps": 240, "num_envs": 2, "checkpoints": 2, "panel_weakest": 1, "panel_episodes": 1,
                   "eval_envs": 2, "log_every": 60}
SMOKE_HUMANS = {"env_steps": 240, "num_envs": 2, "checkpoints": 2, "eval_episodes": 2, "eval_envs": 2, "log_every": 60}
EPISODES = 2
METRICS = ("progress_m", "return", "collision", "intervention", "mean_speed_m_s")


def _jsonl(rows: list[dict[str, Any]]) -> bytes:
    return "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows).encode()


def _npz(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def _mcap(steps: int, dt: float) -> bytes:
    """A minimal episode log: /state/ego (gap, speed, actions) and /state/assistant (intent probabilities)."""
    buffer = io.BytesIO()
    writer = Writer(buffer)
    writer.start()
    channels = {name: writer.register_channel(topic=f"/state/{name}", message_encoding="json", schema_id=0)
                for name in ("ego", "assistant")}
    for k in range(steps):
        t = round(k * dt, 6)
        p_pass = 0.2 if k < 3 else 0.9
        messages = {
            "ego": {"t": t, "ds": -10.0 + 2.0 * k, "speed": 20.0 + 0.5 * k,
                    "assistant_action": {"steer": 0.1 * np.sin(k), "accel": 0.3},
                    "human_action": {"steer": 0.05, "accel": 0.6}},
            "assistant": {"t": t, "intent_probs": {"pass": p_pass, "stay": 1.0 - p_pass}},
        }
        for name, message in messages.items():
            writer.add_message(channels[name], log_time=int(round(t * 1e9)), data=json.dumps(message).encode(),
                               publish_time=int(round(t * 1e9)))
    writer.finish()
    return buffer.getvalue()


def delta(method: str, seed: int, group: str, number: int, intent: str) -> dict[str, float]:
    # dreamer's evaluation predates the intent criterion (no `intent_criterion`), as old stores do
    if method == "dreamer":
        return {"progress_m": -5.0, "return": -1.0, "collision": 0.0, "intervention": 0.02, "mean_speed_m_s": -0.5}
    # ... and the off-track rate, as evaluations before it was recorded
    if group == "near_perfect":  # the assistant makes these crash more: the safety rule is broken
        # pass: by colliding more; stay: by leaving the track more
        return {"progress_m": -1.0, "return": 0.5, "collision": 0.1 if intent == "pass" else 0.0,
                "off_track": 0.2 if intent == "stay" else 0.0, "intervention": 0.2, "mean_speed_m_s": 0.1,
                "intent_criterion": -0.5}
    sign = 1.0 if intent == "pass" else 0.5
    return {"progress_m": sign * (10.0 * seed + number), "return": 2.0 + seed, "collision": -0.1, "off_track": -0.05,
            "intervention": 0.3, "mean_speed_m_s": 1.0 + 0.1 * number, "intent_criterion": 0.1 * seed}


def _evaluation(store: Store, method: str, seed: int, assistant: str, populations: list[str], human_ids: dict,
                heldout_f1: float | None = None, eval_seed: int = 0) -> tuple[str, dict]:
    humans, assisted, unassisted = [], [], []
    steps: dict[str, list] = {k: [] for k in ("episode", "label", "human_action", "assistant_action", "y_hat",
                                              "p_true")}
    logs: dict[str, bytes] = {}
    for label, intent in enumerate(INTENTS):
        for group, numbers in (("imperfect", (1, 2, 3)), ("near_perfect", (1,))):
            for number in numbers:
                d = delta(method, seed, group, number, intent)
                index = len(humans)
                humans.append({"id": human_ids[(intent, group, number)], "intent": intent, "label": label,
                               "group": group, "number": number, "performance": 0.25 * number, "env_step": 60 * number,
                               "episodes": EPISODES, "unassisted": {m: 0.0 for m in METRICS},
                               "assisted": dict(d), "delta": dict(d)})
                for j in range(EPISODES):
                    row = {"human": index, "seed": 50_000_017 + j, "label": label, "intent": intent,
                           "progress_m": 100.0 + d["progress_m"], "collision": 0.0, "intervention": 0.3,
                           "return": d["return"], "mean_speed_m_s": 20.0}
                    k = len(assisted)
                    assisted.append(row)
                    unassisted.append(dict(row, progress_m=100.0, intervention=0.0))
                    n = 6
                    steps["episode"].append(np.full(n, k, np.int32))
                    steps["label"].append(np.full(n, label, np.int8))
                    steps["human_action"].append(np.full((n, 2), 0.5, np.float32))
                    steps["assistant_action"].append(np.tile(np.float32([0.1, -0.2]), (n, 1)))
                    steps["y_hat"].append(np.array([1 - label, label, label, label, label, label], np.int8))
                    steps["p_true"].append(np.linspace(0.4, 0.9, n).astype(np.float32))
                    if method == "dream2assist" and intent == "pass" and group == "imperfect" and number == 3:
                        logs[f"episodes/assisted/human{index:03d}-seed{row['seed']}.mcap"] = _mcap(8, 0.1)
    f1 = {"dream2assist": 0.9 - 0.1 * seed, "dreamer": None}[method] if heldout_f1 is None else heldout_f1
    result = {"method": method, "seed": seed, "assistant": assistant, "track": TRACK, "pair": PAIR,
              "populations": populations, "episodes_per_human": EPISODES, "eval_seed": eval_seed,
              "intents": {i: {"intent_f1": None if f1 is None else f1} for i in INTENTS}, "humans": humans,
              "intent_f1": f1, "intent_confusion": None if f1 is None else [[9, 1], [1, 9]]}
    labels = {"track": TRACK, "pair": PAIR, "method": method, "seed": seed, "run_key": f"{method}-{seed}-{eval_seed}"}
    with store.create("evaluation", inputs=[assistant, *populations], config={"env": {"dt": 0.1}}, seed=eval_seed,
                      labels=labels) as w:
        w.add_json("eval.json", {"result": result, "unassisted": unassisted, "assisted": assisted})
        arrays = {k: np.concatenate(v) for k, v in steps.items()}
        if method == "dreamer":
            arrays = {k: v for k, v in arrays.items() if k not in ("y_hat", "p_true")}
        w.add_bytes("steps.npz", _npz(**arrays))
        if seed == 0 and heldout_f1 is None:
            rng = np.random.default_rng(1 if method == "dreamer" else 2)
            labels_t = np.repeat(np.int8([0, 1]), 40)
            shift = 0.0 if method == "dreamer" else 3.0
            features = rng.normal(size=(80, 8)) + shift * labels_t[:, None]
            w.add_bytes("latents.npz", _npz(features=features.astype(np.float32), label=labels_t,
                                            episode=np.repeat(np.int32([0, 6]), 40)))
        for name, data in sorted(logs.items()):
            w.add_bytes(name, data)
    return w.artifact.id, result


def _curve(env_steps: int, start: float, slope: float, extra: dict[str, float] | None = None) -> list[dict]:
    return [{"env_step": s, "episode/progress_m": start + slope * s, "episode/return": -10.0 + 0.01 * s,
             **{k: v + 0.0001 * s for k, v in (extra or {}).items()}} for s in range(60, env_steps + 1, 60)]


def make_store(root: Path) -> dict[str, Any]:
    """Build the synthetic store at `root`; returns the ids by role."""
    store = Store(root)
    ids: dict[str, Any] = {"evaluations": {}, "assistants": {}, "runs": {}, "swaps": {}, "populations": {}}
    with store.create("track", labels={"name": TRACK}) as w:
        w.add_bytes("track.npz", b"not read by the report")
    ids["track"] = w.artifact.id
    store.tag(ids["track"], f"track/{TRACK}")
    human_ids = {}
    for intent in INTENTS:
        checkpoints = []
        for group, numbers in (("imperfect", (1, 2, 3)), ("near_perfect", (1,))):
            for number in numbers:
                with store.create("human", inputs=[ids["track"]], labels={"intent": intent, "group": group,
                                                                          "number": number}) as w:
                    w.add_bytes("agent.pt", b"not read by the report")
                human_ids[(intent, group, number)] = w.artifact.id
                checkpoints.append({"id": w.artifact.id, "env_step": 60 * len(checkpoints) + 60,
                                    "metrics": {"return": 10.0 * len(checkpoints), "progress_m": 50.0},
                                    "meets_intent": True, "criterion": 1.0, "performance": 0.25 * number})
        pop = {"intent": intent, "track": TRACK, "track_id": ids["track"], "seed": 0, "expert": checkpoints[-1]["id"],
               "expert_env_step": 240, "expert_meets_intent": True, "training_code_version": 4,
               "checkpoints": checkpoints}
        with store.create("population", inputs=[c["id"] for c in checkpoints],
                          config={"humans": dict(SMOKE_HUMANS, checkpoints=4)}, seed=0,
                          labels={"intent": intent, "track": TRACK}) as w:
            w.add_json("population.json", pop)
            w.add_bytes("curve.jsonl", _jsonl(_curve(240, 20.0 if intent == "pass" else 10.0, 0.1)))
        ids["populations"][intent] = w.artifact.id
        store.tag(w.artifact.id, f"humans/{TRACK}/{intent}")
    populations = [ids["populations"][i] for i in INTENTS]
    runs = [("dream2assist", s) for s in D2A_SEEDS] + [("dreamer", 0)]
    for method, seed in runs:
        name = f"{TRACK}/{PAIR}/{method}/seed{seed}"
        labels = {"track": TRACK, "pair": PAIR, "method": method, "seed": seed}
        with store.create("assistant", inputs=[ids["track"], *populations], config={"assistant": SMOKE_ASSISTANT},
                          seed=seed, labels={**labels, "env_step": 240, "fraction": 1.0}) as w:
            w.add_bytes("agent.pt", b"not read by the report")
        assistant = ids["assistants"][(method, seed)] = w.artifact.id
        store.tag(assistant, f"assistants/{name}")
        extra = {"episode/intent_accuracy": 0.5 + 0.1 * seed} if method != "dreamer" else None
        run = {"method": method, "track": TRACK, "pair": PAIR, "intents": list(INTENTS), "seed": seed, "id": assistant,
               "populations": populations, "checkpoints": [{"id": assistant, "env_step": 240, "metrics": {}}]}
        with store.create("assistant-run", inputs=[assistant, *populations], config={"assistant": SMOKE_ASSISTANT},
                          seed=seed, labels={**labels, "run_key": f"run-{method}-{seed}"}) as w:
            w.add_json("run.json", run)
            w.add_bytes("curve.jsonl", _jsonl(_curve(240, 30.0 + seed, 0.05, extra)))
        ids["runs"][(method, seed)] = w.artifact.id
        store.tag(w.artifact.id, f"assistant-runs/{name}")
        if method == "dream2assist" and seed == 0:  # superseded: made first, then replaced by a rerun
            ids["superseded"], _ = _evaluation(store, method, seed, assistant, populations, human_ids, eval_seed=9)
            store.tag(ids["superseded"], f"eval/{name}")
        ids["evaluations"][(method, seed)], _ = _evaluation(store, method, seed, assistant, populations, human_ids)
        store.tag(ids["evaluations"][(method, seed)], f"eval/{name}")
        if (method, seed) in (("dream2assist", 0), ("dream2assist", 1), ("dreamer", 0)):
            ids["swaps"][(method, seed)] = _swap(store, method, seed, assistant)
            store.tag(ids["swaps"][(method, seed)], f"intent-swap/{name}")
    held, _ = _evaluation(store, "dream2assist", 0, ids["assistants"][("dream2assist", 0)], populations, human_ids,
                          heldout_f1=0.6, eval_seed=1)
    store.tag(held, f"eval/{TRACK}/{PAIR}/dream2assist/seed0/humans-abcd1234-ef567890")
    ids["heldout"] = held
    return ids


RECOVERY = {("dream2assist", 0): 1.5, ("dream2assist", 1): 2.5, ("dreamer", 0): None}


def _swap(store: Store, method: str, seed: int, assistant: str) -> str:
    times = [round(-1.0 + 0.1 * k, 6) for k in range(51)]
    recovery = RECOVERY[(method, seed)]

    def accuracy(t: float) -> float:
        if t < 0:
            return 1.0
        return 1.0 if recovery is not None and t >= recovery else 0.2

    directions = {}
    for d in ("pass-to-stay", "stay-to-pass"):
        directions[d] = {"time_s": times, "accuracy": [accuracy(t) for t in times], "trials": 4,
                         "recovery_s": recovery, "trial_recovery_s": [recovery, recovery, None, recovery],
                         "median_trial_recovery_s": recovery, "recovered_trials": 3 if recovery is not None else 0}
    metrics = {d: {m: {"unassisted": 50.0, "assisted": 55.0, "delta_mean": 5.0 if m == "progress_m" else 0.0,
                       "delta_std": 1.0} for m in ("progress_m", "collision", "intervention", "mean_speed_m_s")}
               for d in directions}
    result = {"method": method, "seed": seed, "assistant": assistant, "track": TRACK, "pair": PAIR,
              "trials_per_direction": 4, "window_s": [3.0, 8.0], "dt": 0.1, "recovery_level": 0.9, "hold_s": 1.0,
              "directions": directions, "metrics": metrics}
    with store.create("intent-swap", inputs=[assistant], config={"env": {"dt": 0.1}}, seed=0,
                      labels={"track": TRACK, "pair": PAIR, "method": method, "seed": seed}) as w:
        w.add_json("swap.json", {"result": result, "specs": [], "unassisted": [], "assisted": []})
    return w.artifact.id
