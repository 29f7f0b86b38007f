"""Each reward term against the paper's formula on crafted states."""

from __future__ import annotations

import pytest

from d2a_core.objectives import RewardConfig
from d2a_core.objectives import StepQuantities, reward_terms

CFG = RewardConfig()


def q(**kw):
    base = dict(s=100.0, s_prev=98.0, ds=-10.0, ds_prev=-11.0, de=1.5, collision=False, off_track=False,
                finished=False)
    base.update(kw)
    return StepQuantities(**base)


def test_paper_constants_are_the_defaults():
    assert (CFG.c_pass, CFG.pass_window_m, CFG.c_stay, CFG.stay_window_m, CFG.c_margin) == (10, 800, -2, 50, 0.3)
    assert CFG.collision < 0 and CFG.bounds < 0 and CFG.finish > 0


def test_pass_term_gains_on_the_opponent():
    t = reward_terms(q(ds=-10.0, ds_prev=-11.0), CFG)
    assert t.pass_ == pytest.approx(10 * 1.0)           # 10 * (ds_t - ds_{t-1})
    t = reward_terms(q(ds=5.0, ds_prev=6.5), CFG)
    assert t.pass_ == pytest.approx(10 * -1.5)          # losing ground is penalised
    # outside the +-800 m window on both steps: nothing
    assert reward_terms(q(ds=-900.0, ds_prev=-905.0), CFG).pass_ == 0.0
    # window met on either step counts
    assert reward_terms(q(ds=-799.0, ds_prev=-801.0), CFG).pass_ == pytest.approx(20.0)
    # no progress term in pass
    assert reward_terms(q(s=200.0, s_prev=100.0, ds=-10.0, ds_prev=-10.0), CFG).pass_ == 0.0


def test_stay_term_is_progress_minus_closing_in_within_50m():
    t = reward_terms(q(s=102.0, s_prev=100.0, ds=-30.0, ds_prev=-31.0), CFG)
    assert t.stay == pytest.approx(2.0 + (-2.0) * 1.0)
    t = reward_terms(q(s=102.0, s_prev=100.0, ds=-60.0, ds_prev=-61.0), CFG)
    assert t.stay == pytest.approx(2.0)                 # farther than 50 m: progress only
    t = reward_terms(q(s=102.0, s_prev=100.0, ds=-49.0, ds_prev=-51.0), CFG)
    assert t.stay == pytest.approx(2.0 - 2.0 * 2.0)


def test_left_and_right_are_passing_plus_side_bias():
    t = reward_terms(q(ds=-10.0, ds_prev=-11.0, de=1.5), CFG)
    assert t.left == pytest.approx(1.0 + (1.5 + 0.3))
    assert t.right == pytest.approx(1.0 - (1.5 + 0.3))
    t = reward_terms(q(ds=0.0, ds_prev=0.0, de=-2.0), CFG)
    assert t.left == pytest.approx(-1.7) and t.right == pytest.approx(1.7)


def test_side_term_stops_when_the_opponent_has_finished():
    """After the opponent's race is over only the passing part remains, so a parked car cannot
    keep earning its side bias until the time limit; the paper's literal formula on request."""
    done = reward_terms(q(ds=-10.0, ds_prev=-11.0, de=5.0, opponent_racing=False), CFG)
    assert done.left == pytest.approx(1.0) and done.right == pytest.approx(1.0)
    literal = RewardConfig(side_only_while_racing=False)
    done = reward_terms(q(ds=-10.0, ds_prev=-11.0, de=5.0, opponent_racing=False), literal)
    assert done.left == pytest.approx(1.0 + 5.3) and done.right == pytest.approx(1.0 - 5.3)


def test_task_terms_and_human_reward():
    t = reward_terms(q(collision=True), CFG)
    assert t.collision == CFG.collision and t.task == CFG.collision
    t = reward_terms(q(off_track=True), CFG)
    assert t.bounds == CFG.bounds and t.task == CFG.bounds
    t = reward_terms(q(finished=True), CFG)
    assert t.finish == CFG.finish
    assert t.human("pass") == pytest.approx(t.task + t.pass_)
    assert t.human(None) == t.task
    custom = RewardConfig(c_pass=3.0, collision=-50.0)
    assert reward_terms(q(collision=True), custom).human("pass") == pytest.approx(-50.0 + 3.0)


def test_a_crash_forfeits_the_rest_of_the_race():
    t = reward_terms(q(collision=True, remaining_m=250.0), CFG)
    assert t.collision == pytest.approx(CFG.collision + CFG.forfeit_per_m * 250.0)
    t = reward_terms(q(off_track=True, remaining_m=40.0), CFG)
    assert t.bounds == pytest.approx(CFG.bounds + CFG.forfeit_per_m * 40.0)
    # a pass episode that ends in a crash returns c_pass * s_ego + const, whatever the opponent
    # did meanwhile: (pass terms so far) + forfeit, with the opponent at s_limit at the time limit
    s_limit, start_gap = 900.0, -5.0
    for s_ego, s_opp in ((30.0, 40.0), (30.0, 120.0), (200.0, 260.0)):
        passing = CFG.c_pass * ((s_ego - s_opp) - start_gap)
        total = passing + reward_terms(q(collision=True, remaining_m=s_limit - s_opp), CFG).task
        assert total == pytest.approx(CFG.collision + CFG.c_pass * (s_ego - s_limit - start_gap))
    assert reward_terms(q(finished=True, remaining_m=0.0), CFG).task == CFG.finish
    assert reward_terms(q(remaining_m=100.0), CFG).task == 0.0
