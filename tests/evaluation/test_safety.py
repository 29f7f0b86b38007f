"""The safety rule: with assistance, no group may collide, nor leave the track, more often by more
than 0.05."""

from __future__ import annotations

from d2a_core.evaluation.safety import SAFETY_MARGIN, breaks_rule, safety_flags


def _result(changes: dict[tuple[str, str], tuple[float, float | None]]) -> dict:
    intents: dict = {}
    for (intent, group), (collision, off_track) in changes.items():
        stats = {"collision": {"mean": collision, "std": 0.0}, "progress_m": {"mean": 3.0, "std": 1.0}}
        if off_track is not None:
            stats["off_track"] = {"mean": off_track, "std": 0.0}
        intents.setdefault(intent, {"intent_f1": 0.9})[group] = stats
    return {"intents": intents}


def test_the_margin_and_the_flags():
    assert SAFETY_MARGIN == 0.05
    assert not breaks_rule(0.05) and breaks_rule(0.0501) and not breaks_rule(None)
    result = _result({("pass", "imperfect"): (0.3, 0.0), ("pass", "near_perfect"): (0.05, 0.9),
                      ("stay", "imperfect"): (-0.2, -0.4), ("stay", "near_perfect"): (0.06, 0.06)})
    assert safety_flags(result) == [
        {"intent": "pass", "group": "imperfect", "metric": "collision", "change": 0.3},
        {"intent": "pass", "group": "near_perfect", "metric": "off_track", "change": 0.9},
        {"intent": "stay", "group": "near_perfect", "metric": "collision", "change": 0.06},
        {"intent": "stay", "group": "near_perfect", "metric": "off_track", "change": 0.06},
    ]
    assert safety_flags({"intents": {}}) == []


def test_an_evaluation_without_off_track_rates_is_checked_on_collisions():
    # evaluations stored before the off-track rate was recorded still load and get their flags
    result = _result({("pass", "imperfect"): (0.2, None), ("stay", "imperfect"): (0.0, None)})
    assert safety_flags(result) == [{"intent": "pass", "group": "imperfect", "metric": "collision", "change": 0.2}]
