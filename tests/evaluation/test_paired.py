"""Paired evaluation: the panel, intent F1, and summaries joined on the episode spec."""

from __future__ import annotations

import random

import numpy as np
import pytest

from d2a_core.evaluation.paired import f1_macro, intent_confusion, paired_summary, panel


def population(intent, returns, expert):
    cps = [{"id": f"{intent}{k}", "env_step": 1000 * (k + 1), "metrics": {"return": r}} for k, r in enumerate(returns)]
    return {"intent": intent, "expert": f"{intent}{expert}", "checkpoints": cps}


def test_panel_takes_the_weakest_by_performance_and_the_expert():
    pops = [population("pass", [5, -100, 40, 0, 90, 60, 80, -10], expert=6),
            population("stay", [3, 2, 1], expert=0)]
    humans = panel(pops, ("pass", "stay"), weakest=5)
    assert [h.id for h in humans] == ["pass1", "pass7", "pass3", "pass0", "pass2", "pass6", "stay2", "stay1", "stay0"]
    assert [h.role for h in humans].count("expert") == 2 and humans[5].performance == 1.0
    assert humans[0].performance == 0.0 and humans[6].label == 1
    # the highest return is not the expert's here (pass4 = 90 > 80): its performance exceeds 1
    assert "pass4" not in [h.id for h in humans]


def test_f1_by_hand():
    # true pass: 8 right, 2 wrong; true stay: 5 right, 5 wrong
    counts = np.array([[8, 2], [5, 5]])
    f_pass = 2 * 8 / (13 + 10)
    f_stay = 2 * 5 / (7 + 10)
    assert f1_macro(counts) == pytest.approx((f_pass + f_stay) / 2)
    assert f1_macro(np.array([[10, 0], [0, 4]])) == 1.0
    rows = [{"label": 0, "intent_counts": [8, 2]}, {"label": 1, "intent_counts": [5, 5]}, {"label": 1}]
    np.testing.assert_array_equal(intent_confusion(rows, 2), counts)


def row(human, seed, progress, label, **extra):
    base = {"human": human, "seed": seed, "label": label, "progress_m": progress, "intervention": 0.0, "return": 0.0}
    for metric in ("finished", "finished_ahead", "finished_never_ahead", "collision", "off_track", "held_left",
                   "held_right"):
        base[metric] = 0.0
    return {**base, **extra}


def test_summary_pairs_by_spec_not_by_order():
    pops = [population("pass", [0, 10, 20], expert=2), population("stay", [0, 10], expert=1)]
    humans = panel(pops, ("pass", "stay"), weakest=1)  # pass0 (weak), pass2 (expert), stay0 (weak), stay1 (expert)
    unassisted = [row(h, s, 100.0 + 10 * h + s, humans[h].label) for h in range(4) for s in range(3)]
    assisted = [row(h, s, 100.0 + 10 * h + s + (5.0 if humans[h].role == "weak" else -2.0), humans[h].label,
                    intent_counts=[3, 1] if humans[h].label == 0 else [0, 4], intervention=0.5)
                for h in range(4) for s in range(3)]
    random.Random(0).shuffle(assisted)
    out = paired_summary(humans, unassisted, assisted, ("pass", "stay"))
    assert out["pairs"] == 12
    assert out["pass/weak/progress_gain"] == pytest.approx(5.0) and out["stay/weak/progress_gain"] == pytest.approx(5.0)
    assert out["pass/expert/progress_gain"] == pytest.approx(-2.0)
    assert out["pass/expert/progress_ratio"] == pytest.approx((3 * 111 - 6) / (3 * 111), abs=1e-6)
    assert out["pass/weak/intervention"] == 0.5
    # each intent's own criterion, unassisted and assisted
    assert out["pass/weak/criterion_unassisted"] == 0.0 and out["stay/expert/criterion_assisted"] == 0.0
    # the estimate's accuracy by intent and role: pass drivers 3 of 4 steps, stay drivers all
    assert out["pass/weak/intent_accuracy"] == 0.75 and out["stay/expert/intent_accuracy"] == 1.0
    assert out["intent_confusion"] == [[18, 6], [0, 24]]
    assert out["intent_accuracy"] == pytest.approx(42 / 48)


def test_summary_reports_each_intents_own_criterion():
    pops = [population("pass", [0, 10], expert=1), population("stay", [0, 10], expert=1)]
    humans = panel(pops, ("pass", "stay"), weakest=1)  # pass0, pass1 (expert), stay0, stay1 (expert)
    # the pass expert finishes ahead in 2 of 2 alone and 0 of 2 assisted (the assistant blocks it);
    # the stay expert never gets ahead either way; finished_never_ahead does not count for pass
    unassisted = [row(h, s, 100.0, humans[h].label, finished_ahead=float(h == 1), finished_never_ahead=float(h != 1))
                  for h in range(4) for s in range(2)]
    assisted = [row(h, s, 100.0, humans[h].label, finished_never_ahead=1.0) for h in range(4) for s in range(2)]
    out = paired_summary(humans, unassisted, assisted, ("pass", "stay"))
    assert out["pass/expert/criterion_unassisted"] == 1.0 and out["pass/expert/criterion_assisted"] == 0.0
    assert out["pass/weak/criterion_unassisted"] == 0.0 and out["pass/weak/criterion_assisted"] == 0.0
    assert out["stay/expert/criterion_unassisted"] == 1.0 and out["stay/expert/criterion_assisted"] == 1.0
