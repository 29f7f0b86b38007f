"""The collision safety rule: a group may not collide more with assistance by more than 0.05."""

from __future__ import annotations

from d2a_core.evaluation.safety import COLLISION_MARGIN, breaks_collision_rule, collision_flags


def _result(changes: dict[tuple[str, str], float]) -> dict:
    intents: dict = {}
    for (intent, group), change in changes.items():
        intents.setdefault(intent, {"intent_f1": 0.9})[group] = {"collision": {"mean": change, "std": 0.0},
                                                                 "progress_m": {"mean": 3.0, "std": 1.0}}
    return {"intents": intents}


def test_the_margin_and_the_flags():
    assert COLLISION_MARGIN == 0.05
    assert not breaks_collision_rule(0.05) and breaks_collision_rule(0.0501) and not breaks_collision_rule(None)
    result = _result({("pass", "imperfect"): 0.3, ("pass", "near_perfect"): 0.05,
                      ("stay", "imperfect"): -0.2, ("stay", "near_perfect"): 0.06})
    assert collision_flags(result) == [
        {"intent": "pass", "group": "imperfect", "collision_change": 0.3},
        {"intent": "stay", "group": "near_perfect", "collision_change": 0.06},
    ]
    assert collision_flags({"intents": {}}) == []
