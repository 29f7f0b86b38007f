"""Paired episodes: the same humans, env seeds and opponents, driven unassisted and assisted.

An assistant's effect is a difference between two runs of the *same* episode, so episodes are
identified by what defines them (`EpisodeSpec`: env seed, human checkpoint, intent), not by the
order they end in; both conditions run the same spec list and rows are joined on (human, seed).
The humans act with their actor's mode, so an unassisted episode is a deterministic function of
its spec.

The panel (paper, evaluation protocol): for each intent of the pair the `weakest` checkpoints of
its population by performance (return scaled from the weakest, 0, to the expert, 1) and the
expert. Pure functions here; running episodes is `training.shared_rollout`'s job.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from d2a_core.evaluation.criteria import performance_fractions

WEAKEST = 5
"""Imperfect humans per intent in the panel (the paper's protocol: the five weakest checkpoints)."""


@dataclass(frozen=True)
class PanelHuman:
    """One human of the evaluation panel."""

    id: str  # the human checkpoint's artifact id
    intent: str
    label: int  # index of the intent in the pair
    role: str  # "weak" or "expert"
    performance: float
    env_step: int


def panel(populations: Sequence[Mapping[str, Any]], intents: Sequence[str], weakest: int = WEAKEST) -> list[PanelHuman]:
    """The panel of a pair from its populations' JSON (`population.json`, one per intent, in pair
    order): per intent the `weakest` lowest-performance checkpoints other than the expert, then
    the expert."""
    out: list[PanelHuman] = []
    for label, (intent, pop) in enumerate(zip(intents, populations)):
        checkpoints = list(pop["checkpoints"])
        expert_index = next(k for k, c in enumerate(checkpoints) if c["id"] == pop["expert"])
        # recomputed from the evaluated returns (populations made before `performance` was stored lack it)
        performance = performance_fractions(checkpoints, expert_index)
        others = sorted((k for k in range(len(checkpoints)) if k != expert_index),
                        key=lambda k: (performance[k], checkpoints[k]["env_step"]))
        for k in [*others[:weakest], expert_index]:
            c = checkpoints[k]
            role = "expert" if k == expert_index else "weak"
            out.append(PanelHuman(c["id"], intent, label, role, round(float(performance[k]), 6), c["env_step"]))
    return out


def f1_macro(counts: np.ndarray) -> float:
    """Macro-averaged F1 of a confusion matrix `counts[true, predicted]` (classes never true
    and never predicted are left out)."""
    counts = np.asarray(counts, np.float64)
    scores = []
    for k in range(counts.shape[0]):
        tp = counts[k, k]
        predicted, actual = counts[:, k].sum(), counts[k, :].sum()
        if predicted == 0 and actual == 0:
            continue
        scores.append(2 * tp / (predicted + actual) if predicted + actual else 0.0)
    return float(np.mean(scores)) if scores else float("nan")


def intent_confusion(rows: Sequence[Mapping[str, Any]], classes: int) -> np.ndarray:
    """Per-step confusion matrix [true, inferred] summed over episodes that carry `intent_counts`."""
    counts = np.zeros((classes, classes), np.int64)
    for row in rows:
        if row.get("intent_counts") is not None:
            counts[row["label"]] += np.asarray(row["intent_counts"], np.int64)
    return counts


def _mean(values: Sequence[float]) -> float | None:
    values = [v for v in values if v is not None]
    return round(float(np.mean(values)), 6) if values else None


def paired_summary(humans: Sequence[PanelHuman], unassisted: Sequence[Mapping[str, Any]],
                   assisted: Sequence[Mapping[str, Any]], intents: Sequence[str]) -> dict[str, Any]:
    """What assistance changed, per intent and role, on episodes paired by (human, seed).

    `humans` is the panel; rows carry `human` as an index into it. Per intent: the mean progress
    unassisted and assisted and the mean paired gain of the weak humans; the expert's progress
    ratio assisted / unassisted; finish and criterion-relevant rates of both conditions. Overall:
    the per-step intent F1 and accuracy of the assisted episodes (when the assistant infers one)."""
    base = {(r["human"], r["seed"]): r for r in unassisted}
    pairs = [(base[(r["human"], r["seed"])], r) for r in assisted if (r["human"], r["seed"]) in base]
    out: dict[str, Any] = {"pairs": len(pairs)}
    for label, intent in enumerate(intents):
        for role in ("weak", "expert"):
            chosen = [(u, a) for u, a in pairs if humans[a["human"]].label == label and humans[a["human"]].role == role]
            if not chosen:
                continue
            key = f"{intent}/{role}"
            u_prog = [u["progress_m"] for u, _ in chosen]
            a_prog = [a["progress_m"] for _, a in chosen]
            out[f"{key}/progress_unassisted"] = _mean(u_prog)
            out[f"{key}/progress_assisted"] = _mean(a_prog)
            out[f"{key}/progress_gain"] = _mean([a - u for u, a in zip(u_prog, a_prog)])
            for metric in ("finished", "finished_ahead", "finished_never_ahead", "collision", "off_track",
                           "held_left", "held_right", "return"):
                out[f"{key}/{metric}_unassisted"] = _mean([u[metric] for u, _ in chosen])
                out[f"{key}/{metric}_assisted"] = _mean([a[metric] for _, a in chosen])
            out[f"{key}/intervention"] = _mean([a["intervention"] for _, a in chosen])
            if role == "expert":
                total_u = float(np.sum(u_prog))
                out[f"{key}/progress_ratio"] = round(float(np.sum(a_prog)) / total_u, 6) if total_u > 0 else None
    counts = intent_confusion(assisted, len(intents))
    if counts.sum():
        out["intent_f1"] = round(f1_macro(counts), 6)
        out["intent_accuracy"] = round(float(np.trace(counts) / counts.sum()), 6)
        out["intent_confusion"] = counts.tolist()
    return out
