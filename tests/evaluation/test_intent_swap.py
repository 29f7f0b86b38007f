"""Intent-swap trials and curves: matched humans, the swap window, alignment and recovery time."""

from __future__ import annotations

import numpy as np
import pytest

from d2a_core.errors import UsageError
from d2a_core.pipelines.intent_swap import PRE_S, matched_pairs, recovery_time, swap_curves, trial_specs


def pop(steps):
    return {"checkpoints": [{"id": f"c{s}", "env_step": s} for s in steps]}


def test_comparably_trained_humans_share_the_training_step():
    assert matched_pairs([pop([10, 20, 30]), pop([20, 30, 40])]) == [(1, 0), (2, 1)]
    with pytest.raises(UsageError, match="no training step"):
        matched_pairs([pop([10]), pop([20])])


def test_trials_cover_both_directions_inside_the_window():
    specs = trial_specs([pop([10, 20]), pop([10, 20])], trials=6, window_steps=(30, 80), seed=3)
    assert len(specs) == 12 and [s.label for s in specs] == [0] * 6 + [1] * 6
    for s in specs:
        assert 30 <= s.swap_step <= 80 and s.swap_label == 1 - s.label
        # the second human is the other population's checkpoint of the same training step
        assert (s.human < 2) != (s.swap_human < 2) and s.human % 2 == s.swap_human % 2
    assert len({s.seed for s in specs}) == 12
    assert trial_specs([pop([10, 20]), pop([10, 20])], 6, (30, 80), 3) == specs  # seeded


def test_recovery_needs_the_level_held():
    dt = 0.1
    assert recovery_time([0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1], dt) == pytest.approx(0.2)
    assert recovery_time([1, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1], dt) == pytest.approx(0.2)  # 1 step is no recovery
    assert recovery_time([0, 0, 0, 1, 1], dt) == pytest.approx(0.3)  # held until the series ends
    assert recovery_time([0, 0, 0], dt) is None


def test_curves_are_aligned_to_each_trials_swap():
    """Two pass-to-stay trials swapping at different steps, each right 3 steps after its swap:
    the mean curve is 1 before the swap, 0 for 3 steps, then 1; recovery 0.3 s."""
    dt = 0.1
    rows, logs = [], []
    for swap, length in ((30, 60), (45, 80)):
        labels = [0] * swap + [1] * (length - swap)
        y_hat = [0] * (swap + 3) + [1] * (length - swap - 3)
        rows.append({"label": 0, "swap_step": swap})
        logs.append({"labels": labels, "y_hat": y_hat})
    out = swap_curves(rows, logs, dt, ("pass", "stay"))
    curve = out["pass-to-stay"]
    pre = int(PRE_S / dt)
    assert curve["time_s"][pre] == 0.0 and curve["time_s"][0] == -PRE_S
    acc = np.array(curve["accuracy"], dtype=float)
    assert (acc[:pre] == 1).all() and (acc[pre:pre + 3] == 0).all() and (acc[pre + 3:] == 1).all()
    assert curve["recovery_s"] == pytest.approx(0.3) and curve["trial_recovery_s"] == [0.3, 0.3]
    assert curve["trials"] == 2 and out["stay-to-pass"] is None


def test_trials_that_end_before_their_swap_are_counted_not_curved():
    """A trial whose episode ended (a crash) before its swap step has nothing to recover from."""
    dt = 0.1
    rows = [{"label": 1, "swap_step": 50}, {"label": 1, "swap_step": 20}]
    logs = [{"labels": [1] * 30, "y_hat": [1] * 30},  # ended at step 30, before its swap at 50
            {"labels": [1] * 20 + [0] * 20, "y_hat": [1] * 25 + [0] * 15}]
    curve = swap_curves(rows, logs, dt, ("pass", "stay"))["stay-to-pass"]
    assert curve["trials"] == 1 and curve["ended_before_swap"] == 1
    assert curve["recovery_s"] == pytest.approx(0.5)
    only_early = swap_curves(rows[:1], logs[:1], dt, ("pass", "stay"))["stay-to-pass"]
    assert only_early["trials"] == 0 and only_early["recovery_s"] is None and only_early["ended_before_swap"] == 1
