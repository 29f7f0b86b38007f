"""What it means for a driver to meet its intent, and which checkpoint of a population is the
expert. Defined once here; `train-humans`, the docs and the evaluation use these.

Criteria, over a checkpoint's unassisted evaluation episodes (rates are shares of episodes,
`held_*` a mean over episodes of the share of steps):

- pass:  finishes ahead of the opponent in >= 80 % (`finished_ahead`);
- stay:  finishes without ever getting ahead in >= 80 % (`finished_never_ahead`);
- left / right: finishes in >= 80 % and holds its side of the opponent on >= 70 % of its steps
  (`held_left` / `held_right`: on that side and no more than `HOLD_BEHIND_M` behind it, so a
  driver that keeps its side by dropping back and hanging behind does not qualify).

The expert. The paper takes the last checkpoint; a last checkpoint that parks or crashes more
than an earlier one is no expert. Rule: among the checkpoints that meet the criterion, the one
with the highest mean return under its own objective (ties: the later one); when none meets it,
the highest-return checkpoint, and the population says `expert_meets_intent: false`.
`train-humans` applies it to the evenly spaced checkpoints; the snapshots it adds afterwards to
fill the imperfect span (`training.imperfect_fill`) are not candidates.

Performance. A checkpoint's performance is its mean evaluation return under its own objective,
as a fraction of the way from the population's weakest checkpoint (0) to the expert (1):
`(R - R_min) / (R_expert - R_min)`. Returns are often negative (a crash pays the forfeit), so a
plain ratio `R / R_expert` has no meaning; this one does, and it is what "x % of the expert's
performance" means in the evaluation protocol (imperfect humans below ~75 %).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from d2a_core.evaluation.metrics import HOLD_BEHIND_M

FINISH_RATE = 0.8
HOLD_SHARE = 0.7
EXPERT_RULE = "highest mean return among checkpoints meeting the intent criterion (else highest return)"

__all__ = ["CRITERION_KEY", "CRITERION_METRIC", "EXPERT_RULE", "HOLD_BEHIND_M", "choose_expert", "criterion_value",
           "meets_intent", "performance_fractions"]


CRITERION_METRIC = {"pass": "finished_ahead", "stay": "finished_never_ahead", "left": "held_left",
                    "right": "held_right"}
"""The evaluation metric each intent's criterion thresholds."""

CRITERION_KEY = "intent_criterion"
"""Where `d2a eval` stores a human's `criterion_value` (per human, unassisted, assisted, change),
and the report reads it."""


def criterion_value(intent: str, metrics: Mapping[str, float]) -> float:
    """The one number a seeds x intents table shows: the rate the criterion thresholds
    (for left/right the side share, which only counts together with the finish rate)."""
    if intent not in CRITERION_METRIC:
        raise ValueError(f"unknown intent {intent!r}")
    return float(metrics[CRITERION_METRIC[intent]])


def meets_intent(intent: str, metrics: Mapping[str, float]) -> bool:
    """Whether aggregated evaluation metrics meet the intent's criterion (module docstring)."""
    if intent in ("pass", "stay"):
        return criterion_value(intent, metrics) >= FINISH_RATE
    return float(metrics["finished"]) >= FINISH_RATE and criterion_value(intent, metrics) >= HOLD_SHARE


def choose_expert(intent: str, checkpoints: Sequence[Mapping[str, Any]]) -> int:
    """Index of the expert among `checkpoints` (each with `metrics`), by the rule above."""
    if not checkpoints:
        raise ValueError("a population needs at least one checkpoint")
    meeting = [i for i, c in enumerate(checkpoints) if meets_intent(intent, c["metrics"])]
    candidates = meeting or list(range(len(checkpoints)))
    # max over (return, index): the highest return, and the later checkpoint on a tie
    return max(candidates, key=lambda i: (float(checkpoints[i]["metrics"]["return"]), i))


def performance_fractions(checkpoints: Sequence[Mapping[str, Any]], expert: int) -> list[float]:
    """Each checkpoint's performance (module docstring): 0 the weakest, 1 the expert."""
    returns = [float(c["metrics"]["return"]) for c in checkpoints]
    low, top = min(returns), returns[expert]
    if top <= low:  # the expert is (one of) the weakest: nothing to scale by
        return [1.0 if r >= top else 0.0 for r in returns]
    return [round((r - low) / (top - low), 6) for r in returns]
