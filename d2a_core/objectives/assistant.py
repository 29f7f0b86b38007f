"""The assistant's reward (paper section 3.3 "Assistive Agent Objectives", equation 6).

Notation: `a_H` the human's action, `a_A` the assistant's, both in the env's action units
([steer, accel] in [-1, 1]); `y_hat` the assistant's own inferred intent at that step; `r_hat*`
the reward that the expert world model `W*_{y_hat}` predicts for the current state and the
blended action; `a*` a sample of the expert actor `pi*_{y_hat}`. Every constant comes from
`AssistantRewardConfig`; a method (`d2a_core.training.methods`) sets `alpha_r` and `alpha_a`.

The paper's formula:

    r^A_t = r^task_t + r^interv_t + alpha_r * r_hat*_t(y_hat_t) + alpha_a * ||a_H + a_A - a*_t(y_hat_t)||_2
    r^interv_t = -||a_A||_2

and what this module computes:

    r^A_t = r^task_t - w_interv * ||a_A||_2 + alpha_r * r_hat*_t(y_hat_t) - alpha_a * ||b - a*_t(y_hat_t)||_2
    b = clip(a_H + a_A, -1, 1)          (the action the car executed)

**The sign of the action term.** The paper prints `+ alpha_a ||...||`, which pays the assistant
for moving the car *away* from the expert; its text says the term rewards "actions that bring
the sub-optimal human closer to the optimal human". So here it is a penalty on the distance;
`expert_action_penalty: false` restores the print.

**The blended action.** The paper writes `a_H + a_A`; the car executes `clip(a_H + a_A, -1, 1)`
and the expert's actor samples inside [-1, 1]. A push past the limit changes nothing on the car
(the intervention term already charges its size), so the distance is taken from the executed
action; `clip_blend: false` restores the unclipped sum.

**w_interv.** The paper's intervention term has unit weight (`r^interv = -||a_A||_2`), the
default here; a small sweep of it: docs/experiments/assistant-reward.md.

**What r_hat* contains.** The expert was trained on `r^H = r^task + r^y`, so `r_hat*` predicts the
task terms too: with `alpha_r = 1` a crash is charged once by `r^task` and once more through the
expert's prediction. That is the paper's form, kept.

Every term is returned separately (`AssistantRewardTerms`), so the return of any weighting can
be recomputed from logged terms with `combine`.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np
from pydantic import Field

from d2a_core.config.section import Section


class AssistantRewardConfig(Section):
    """Weights of the assistant's reward (paper equation 6)."""

    # a crash that also charges full-strength intervention to the time limit: measured on one
    # population build (docs/experiments/assistant-safety.md), not a default, retired with its code
    retired = {"crash_forfeit": False}

    w_interv: float = Field(1.0, ge=0, description="weight of the intervention norm ||a_A||_2 (the paper's: 1)")
    alpha_r: float = Field(1.0, ge=0, description="weight of the expert world model's reward r_hat*(y_hat)")
    alpha_a: float = Field(
        0.0, ge=0, description="weight of the distance ||a_H + a_A - a*(y_hat)||_2 to the expert's action"
    )
    expert_action_penalty: bool = Field(
        True,
        description="the action term is a penalty on the distance to the expert; false: the paper's printed +alpha_a",
    )
    clip_blend: bool = Field(
        True, description="measure the distance from clip(a_H + a_A, -1, 1), the executed action; false: the raw sum"
    )


class AssistantRewardTerms(NamedTuple):
    """Every term of one step for a batch of environments, each of shape (N,), unweighted.

    `expert_reward` and `expert_distance` are NaN where no expert was queried (a method whose
    weight for that term is zero need not query one)."""

    task: np.ndarray  # r^task
    intervention: np.ndarray  # ||a_A||_2
    expert_reward: np.ndarray  # r_hat*(y_hat)
    expert_distance: np.ndarray  # ||b - a*(y_hat)||_2
    total: np.ndarray  # r^A under the config the terms were made with

    def as_dict(self) -> dict[str, np.ndarray]:
        return self._asdict()


def _weighted(weight: float, term: np.ndarray, name: str) -> np.ndarray:
    """weight * term, where a zero weight ignores the term (which may then be NaN: not computed)."""
    if weight == 0.0:
        return np.zeros_like(term)
    if np.isnan(term).any():
        raise ValueError(f"assistant reward: {name} has weight {weight} but was not computed (NaN)")
    return weight * term


def combine(
    task: np.ndarray,
    intervention: np.ndarray,
    expert_reward: np.ndarray,
    expert_distance: np.ndarray,
    cfg: AssistantRewardConfig,
) -> np.ndarray:
    """r^A from unweighted terms (N,): the module docstring's formula under `cfg`."""
    action_sign = -1.0 if cfg.expert_action_penalty else 1.0
    return (
        np.asarray(task, np.float64)
        - cfg.w_interv * np.asarray(intervention, np.float64)
        + _weighted(cfg.alpha_r, np.asarray(expert_reward, np.float64), "r_hat*")
        + action_sign * _weighted(cfg.alpha_a, np.asarray(expert_distance, np.float64), "||b - a*||")
    )


def assistant_reward(
    task: np.ndarray,
    assistant_action: np.ndarray,
    human_action: np.ndarray,
    expert_reward: Optional[np.ndarray],
    expert_action: Optional[np.ndarray],
    cfg: AssistantRewardConfig,
) -> AssistantRewardTerms:
    """The assistant's reward of one step for N environments.

    task (N,): r^task; assistant_action, human_action (N, A): a_A and a_H in env units;
    expert_reward (N,): r_hat*(y_hat), expert_action (N, A): a*(y_hat), both already taken from
    the expert of each env's inferred intent (`pick_intent`); either may be None when its weight
    is zero (its term is then NaN in the result)."""
    task = np.asarray(task, np.float64).reshape(-1)
    n = task.shape[0]
    a_assist = np.asarray(assistant_action, np.float64).reshape(n, -1)
    a_human = np.asarray(human_action, np.float64).reshape(n, -1)
    if a_assist.shape != a_human.shape:
        raise ValueError(f"assistant reward: action shapes differ: a_A {a_assist.shape}, a_H {a_human.shape}")
    intervention = np.linalg.norm(a_assist, axis=-1)
    if expert_reward is None:
        r_star = np.full(n, np.nan)
    else:
        r_star = np.asarray(expert_reward, np.float64).reshape(n)
    if expert_action is None:
        distance = np.full(n, np.nan)
    else:
        a_star = np.asarray(expert_action, np.float64).reshape(a_human.shape)
        blended = a_human + a_assist
        if cfg.clip_blend:
            blended = np.clip(blended, -1.0, 1.0)
        distance = np.linalg.norm(blended - a_star, axis=-1)
    total = combine(task, intervention, r_star, distance, cfg)
    return AssistantRewardTerms(task, intervention, r_star, distance, total)


def totals_by_intent(
    task: np.ndarray,
    assistant_action: np.ndarray,
    human_action: np.ndarray,
    expert_rewards: np.ndarray,
    expert_actions: np.ndarray,
    cfg: AssistantRewardConfig,
) -> np.ndarray:
    """r^A (K, N) as it would be had each of the K intents of the pair been inferred: row k uses
    the expert of intent k (`expert_rewards` (K, N), `expert_actions` (K, N, A)). The replay keeps
    these so that a learner can take the reward under its current estimate instead of the one it
    had when the step was collected (`DreamerConfig.reward_relabel_head`)."""
    rewards, actions = np.asarray(expert_rewards), np.asarray(expert_actions)
    return np.stack([assistant_reward(task, assistant_action, human_action, rewards[k], actions[k], cfg).total
                     for k in range(rewards.shape[0])])


def pick_intent(per_intent: np.ndarray, intent_index: np.ndarray) -> np.ndarray:
    """Per env, the value of the expert of its inferred intent: `per_intent` (K, N, ...) holds
    one value per intent of the pair, `intent_index` (N,) the inferred intent y_hat in [0, K)."""
    values = np.asarray(per_intent)
    index = np.asarray(intent_index, np.int64).reshape(-1)
    if values.ndim < 2 or values.shape[1] != index.shape[0]:
        raise ValueError(f"pick_intent: values {values.shape} do not match {index.shape[0]} environments")
    if index.size and (index.min() < 0 or index.max() >= values.shape[0]):
        raise ValueError(f"pick_intent: intent index outside [0, {values.shape[0]})")
    return values[index, np.arange(index.shape[0])]
