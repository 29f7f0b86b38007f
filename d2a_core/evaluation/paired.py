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

from d2a_core.evaluation.criteria import criterion_value, performance_fractions

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


IMPERFECT_TARGETS = (0.0, 0.2, 0.4, 0.6, 0.8)
"""Performance levels of the imperfect humans: every 20 % of the expert's, up to at least 75 %."""
NEAR_PERFECT = 0.75
"""Performance from which a checkpoint is near-perfect (the paper's 75 % threshold)."""


@dataclass(frozen=True)
class TestHuman:
    """A human under test in `d2a eval`: a checkpoint, its group and its number in the group."""

    id: str
    intent: str
    label: int
    group: str  # "imperfect" (numbered 1-5, as in the paper's figures) or "near_perfect"
    number: int
    performance: float
    env_step: int


def select_humans(population: Mapping[str, Any], intent: str, label: int) -> list[TestHuman]:
    """The paper's rule (its appendix, "checkpoints at every 20 % performance increment up to at
    least 75 % of maximum, or the bottom five if none are under this threshold"), with performance
    as `evaluation.criteria` defines it (0: the weakest checkpoint, 1: the expert):

    - imperfect: for each level of `IMPERFECT_TARGETS` in turn, the checkpoint not yet taken
      (the expert never) whose performance is nearest to it; when no checkpoint is below
      `NEAR_PERFECT`, the five weakest instead;
    - near-perfect: every other checkpoint at or above `NEAR_PERFECT`, the expert included.

    Both groups are numbered by performance, weakest first."""
    checkpoints = list(population["checkpoints"])
    expert = next(k for k, c in enumerate(checkpoints) if c["id"] == population["expert"])
    perf = performance_fractions(checkpoints, expert)
    others = [k for k in range(len(checkpoints)) if k != expert]
    if any(perf[k] < NEAR_PERFECT for k in others):
        imperfect: list[int] = []
        for target in IMPERFECT_TARGETS:
            free = [k for k in others if k not in imperfect]
            if not free:
                break
            imperfect.append(min(free, key=lambda k: (abs(perf[k] - target), perf[k], k)))
    else:
        imperfect = sorted(others, key=lambda k: (perf[k], k))[:len(IMPERFECT_TARGETS)]
    near = [k for k in range(len(checkpoints)) if k not in imperfect and (perf[k] >= NEAR_PERFECT or k == expert)]
    out = []
    for group, chosen in (("imperfect", imperfect), ("near_perfect", near)):
        for number, k in enumerate(sorted(chosen, key=lambda k: (perf[k], k)), start=1):
            c = checkpoints[k]
            out.append(TestHuman(c["id"], intent, label, group, number, round(float(perf[k]), 6), c["env_step"]))
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


def f1_of_class(counts: np.ndarray, k: int) -> float | None:
    """F1 of class `k` (one against the rest) in a confusion matrix `counts[true, predicted]`;
    None when the class is neither true nor predicted anywhere."""
    counts = np.asarray(counts, np.float64)
    denominator = counts[:, k].sum() + counts[k, :].sum()
    return float(2 * counts[k, k] / denominator) if denominator else None


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
    ratio assisted / unassisted; finish and criterion-relevant rates of both conditions, and the
    intent's own criterion (`criteria.criterion_value`) in both; the intent estimate's per-step
    accuracy on that intent and role's episodes. Overall:
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
            out[f"{key}/criterion_unassisted"] = _mean([criterion_value(intent, u) for u, _ in chosen])
            out[f"{key}/criterion_assisted"] = _mean([criterion_value(intent, a) for _, a in chosen])
            out[f"{key}/intervention"] = _mean([a["intervention"] for _, a in chosen])
            counts = intent_confusion([a for _, a in chosen], len(intents))
            if counts.sum():  # which drivers the intent estimate gets wrong
                out[f"{key}/intent_accuracy"] = round(float(counts[label, label] / counts.sum()), 6)
            if role == "expert":
                total_u = float(np.sum(u_prog))
                out[f"{key}/progress_ratio"] = round(float(np.sum(a_prog)) / total_u, 6) if total_u > 0 else None
    counts = intent_confusion(assisted, len(intents))
    if counts.sum():
        out["intent_f1"] = round(f1_macro(counts), 6)
        out["intent_accuracy"] = round(float(np.trace(counts) / counts.sum()), 6)
        out["intent_confusion"] = counts.tolist()
    return out
