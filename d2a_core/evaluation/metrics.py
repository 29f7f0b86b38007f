"""Per-episode metrics computed from the env's `info` dicts (no re-simulation).

An episode's infos are the reset info followed by one info per step. Metrics:

- `progress_m`: distance along the track from the start;
- `return`: the sum of the rewards received (the episode's own objective);
- `return_<intent>`: the return the same episode earns under each intent's objective;
- `collision`, `collision_car`, `collision_barrier`, `off_track`, `finished`: 0/1 outcomes;
- `finished_ahead`: finished with ds > 0; `finished_never_ahead`: finished with ds < 0 on every
  step (what a pass and a stay driver are after);
- `mean_speed_m_s`; `overtakes`: times ds went from behind (< 0) to ahead (>= 0) while the
  opponent was racing; `ahead_at_end`: ds > 0 on the last step; `share_left`: share of steps spent
  left of the opponent (de > 0);
- `held_left`, `held_right`: share of steps spent on that side of the opponent *while racing it*:
  no more than `HOLD_BEHIND_M` behind it. A car that keeps its side by dropping back and hanging
  behind ("parking") is not holding a side; this is what the left/right criteria count;
- `intervention`: mean L2 norm of the assistant's action, when one drove.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from d2a_core.objectives.rewards import INTENTS

METRIC_NAMES = ("progress_m", "return", *(f"return_{i}" for i in INTENTS), "collision", "collision_car",
                "collision_barrier", "off_track", "finished", "finished_ahead", "finished_never_ahead", "mean_speed_m_s", "overtakes", "ahead_at_end",
                "share_left", "held_left", "held_right", "steps", "intervention")
# how far behind the opponent a car may be and still count as holding its side (the grid gap is
# 15 m); the same distance as the reward's default `side_max_behind_m`
HOLD_BEHIND_M = 30.0


def episode_metrics(infos: Sequence[dict[str, Any]], rewards: Sequence[float]) -> dict[str, float]:
    """Metrics of one finished episode (see the module docstring)."""
    if len(infos) < 2 or len(rewards) != len(infos) - 1:
        raise ValueError("need the reset info plus one info and one reward per step")
    steps = infos[1:]
    last = steps[-1]
    ds = np.array([i["ds"] for i in infos])
    racing = np.array([bool(i["opponent_racing"]) for i in infos])
    overtakes = int(np.sum((ds[:-1] < 0) & (ds[1:] >= 0) & racing[1:]))
    out = {
        "progress_m": float(last["progress"]),
        "return": float(np.sum(rewards)),
        "collision": float(last["collision"]),
        "collision_car": float(last["collision_car"]),
        "collision_barrier": float(last["collision_barrier"]),
        "off_track": float(last["off_track"]),
        "finished": float(last["finished"]),
        "finished_ahead": float(bool(last["finished"]) and last["ds"] > 0),
        "finished_never_ahead": float(bool(last["finished"]) and bool(np.all(ds < 0))),
        "mean_speed_m_s": float(np.mean([i["speed"] for i in steps])),
        "overtakes": float(overtakes),
        "ahead_at_end": float(last["ds"] > 0),
        "share_left": float(np.mean([i["de"] > 0 for i in steps])),
        "held_left": float(np.mean([i["de"] > 0 and i["ds"] >= -HOLD_BEHIND_M for i in steps])),
        "held_right": float(np.mean([i["de"] < 0 and i["ds"] >= -HOLD_BEHIND_M for i in steps])),
        "steps": float(len(steps)),
    }
    for intent in INTENTS:
        out[f"return_{intent}"] = float(sum(i["reward_terms"]["task"] + i["reward_terms"][intent] for i in steps))
    interventions = [float(np.linalg.norm(i["assistant_action"])) for i in steps if "assistant_action" in i]
    out["intervention"] = float(np.mean(interventions)) if interventions else 0.0
    return out


def aggregate(episodes: Sequence[dict[str, float]]) -> dict[str, float]:
    """Mean of each metric over episodes (rates for the 0/1 outcomes), plus the episode count."""
    if not episodes:
        return {"episodes": 0}
    out: dict[str, float] = {"episodes": len(episodes)}
    for name in episodes[0]:
        values = [e[name] for e in episodes]
        out[name] = float(np.mean(values))
        if name in ("return", "progress_m"):
            out[f"{name}_std"] = float(np.std(values))
    return {k: (round(v, 6) if isinstance(v, float) and math.isfinite(v) else v) for k, v in out.items()}
