"""The intent criteria and the expert rule (evaluation.criteria) on crafted checkpoint metrics."""

from __future__ import annotations

import pytest

from d2a_core.evaluation.criteria import choose_expert, criterion_value, meets_intent, performance_fractions


def metrics(ret=0.0, finished=1.0, ahead=0.0, never=0.0, held_left=0.0, held_right=0.0):
    return {"return": ret, "finished": finished, "finished_ahead": ahead, "finished_never_ahead": never,
            "held_left": held_left, "held_right": held_right}


def test_criteria_thresholds():
    assert meets_intent("pass", metrics(ahead=0.8)) and not meets_intent("pass", metrics(ahead=0.75))
    assert meets_intent("stay", metrics(never=0.9)) and not meets_intent("stay", metrics(never=0.5, ahead=0.5))
    assert meets_intent("left", metrics(held_left=0.7)) and not meets_intent("left", metrics(held_left=0.69))
    # holding the side but not finishing (the parked driver that runs out of time) fails
    assert not meets_intent("right", metrics(finished=0.2, held_right=0.95))
    assert criterion_value("right", metrics(held_right=0.4)) == 0.4
    with pytest.raises(ValueError):
        criterion_value("overtake", metrics())


def test_the_expert_is_the_best_checkpoint_that_meets_the_intent_not_the_last():
    # a pass run that learnt to pass at 3, peaked at 4, then collapsed off the road at 5
    run = [metrics(ret=-900, finished=0.0), metrics(ret=100, ahead=0.1), metrics(ret=300, ahead=0.85),
           metrics(ret=420, ahead=0.95), metrics(ret=500, finished=0.0, ahead=0.0)]
    checkpoints = [{"metrics": m} for m in run]
    assert choose_expert("pass", checkpoints) == 3
    # ties go to the later checkpoint
    tied = [{"metrics": metrics(ret=300, ahead=0.9)}, {"metrics": metrics(ret=300, ahead=0.9)}]
    assert choose_expert("pass", tied) == 1
    # none meets it: the highest return, whatever its index
    assert choose_expert("pass", [{"metrics": metrics(ret=5)}, {"metrics": metrics(ret=9)}, {"metrics": metrics(ret=1)}]) == 1
    with pytest.raises(ValueError):
        choose_expert("pass", [])


def test_a_left_driver_that_parks_on_its_side_is_not_the_expert():
    """The right seed-1 run of 2026-11-30: its last checkpoint hangs back on its side and times
    out; an earlier one passes on its side and finishes."""
    passing = metrics(ret=250, finished=1.0, held_right=0.9)
    parked = metrics(ret=320, finished=0.2, held_right=0.3)
    assert choose_expert("right", [{"metrics": passing}, {"metrics": parked}]) == 0


def test_performance_runs_from_the_weakest_checkpoint_to_the_expert():
    cps = [{"metrics": metrics(ret=r)} for r in (-8000.0, -4000.0, 200.0, 400.0, -7000.0)]
    perf = performance_fractions(cps, expert=3)
    assert perf == pytest.approx([0.0, 4000 / 8400, 8200 / 8400, 1.0, 1000 / 8400], abs=1e-6)
    # a later checkpoint may beat the expert's return when it failed the intent: above 1
    assert performance_fractions(cps, expert=2)[3] > 1.0
    assert performance_fractions([{"metrics": metrics(ret=5.0)}], expert=0) == [1.0]
