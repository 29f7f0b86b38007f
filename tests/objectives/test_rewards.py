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
    assert t.right == pytest.approx(1.0 + (-1.5 + 0.3))   # the mirror of left
    t = reward_terms(q(ds=0.0, ds_prev=0.0, de=-2.0), CFG)
    assert t.left == pytest.approx(-1.7) and t.right == pytest.approx(2.3)


def test_right_is_the_mirror_of_left():
    """Mirroring the car's side (de -> -de) turns a left reward into the same right reward; the
    paper's literal print -(de + 0.3) on request."""
    for de in (-3.0, -0.3, 0.0, 0.7, 4.0):
        assert reward_terms(q(de=-de), CFG).right == pytest.approx(reward_terms(q(de=de), CFG).left)
    literal = RewardConfig(right_mirrors_left=False)
    assert reward_terms(q(ds=0.0, ds_prev=0.0, de=1.5), literal).right == pytest.approx(-1.8)


def test_side_term_stops_when_the_opponent_has_finished():
    """After the opponent's race is over only the passing part remains, so a parked car cannot
    keep earning its side bias until the time limit; the paper's literal formula on request."""
    done = reward_terms(q(ds=-10.0, ds_prev=-11.0, de=5.0, opponent_racing=False), CFG)
    assert done.left == pytest.approx(1.0) and done.right == pytest.approx(1.0)
    literal = RewardConfig(side_only_while_racing=False, right_mirrors_left=False, side_cap_m=None)
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


def test_task_reward_is_bounded_and_the_same_for_every_intent():
    """r^task (which the assistant shares) is the paper's sparse terms only: no distance term."""
    for remaining in (0.0, 50.0, 5_000.0):
        assert reward_terms(q(collision=True, remaining_m=remaining), CFG).task == CFG.collision
        assert reward_terms(q(off_track=True, remaining_m=remaining), CFG).task == CFG.bounds
    assert reward_terms(q(finished=True, remaining_m=0.0), CFG).task == CFG.finish
    assert reward_terms(q(remaining_m=100.0), CFG).task == 0.0


@pytest.mark.parametrize(
    "ds, remaining, expected_f",
    [
        (0.0, 2_000.0, -800.0),      # level with the opponent: the gap would fall to the window's edge
        (-50.0, 2_000.0, -750.0),    # behind: less of the window is left to lose
        (-50.0, 100.0, -100.0),      # the time limit comes first: only what the opponent still drives
        (30.0, 2_000.0, -830.0),     # ahead: the lead and then the window behind
        (900.0, 2_000.0, -1_600.0),  # far ahead: the whole window, never more
        (900.0, 50.0, 0.0),          # far ahead and the limit comes before the gap enters the window
        (-900.0, 2_000.0, 0.0),      # already out of the window behind: nothing left to lose
    ],
)
def test_crash_forfeit_hand_computed(ds, remaining, expected_f):
    """F = -|[ds - D, ds] intersect [-800, 800]|, paid at the intent's own passing rate."""
    t = reward_terms(q(ds=ds, ds_prev=ds, collision=True, remaining_m=remaining), CFG)
    assert t.forfeit_m == pytest.approx(expected_f)
    assert t.pass_ == pytest.approx(10.0 * expected_f)
    racing_it = ds >= -CFG.side_max_behind_m  # the side bias is paid only near the opponent
    assert t.left - (1.5 + 0.3) * racing_it == pytest.approx(1.0 * expected_f)  # de = 1.5
    assert t.right - (-1.5 + 0.3) * racing_it == pytest.approx(1.0 * expected_f)
    assert t.stay == pytest.approx(2.0)  # stay: progress only, no forfeit
    off = reward_terms(q(ds=ds, ds_prev=ds, off_track=True, remaining_m=remaining), CFG)
    assert off.pass_ == pytest.approx(t.pass_) and off.bounds == CFG.bounds


def test_a_crash_costs_exactly_the_penalty_more_than_stopping():
    """Stopping at the crash point and being passed step by step until the time limit pays the
    pass term on every metre of gap lost inside the window; crashing there pays the same forfeit
    plus r_collision (up to one step at the window's edge)."""
    dt_gap = 3.0  # the opponent's metres per step
    for ds0, remaining in ((0.0, 2_000.0), (-40.0, 300.0), (25.0, 1_000.0), (-790.0, 500.0)):
        stopped, ds, left = 0.0, ds0, remaining
        while left > 1e-9:
            step = min(dt_gap, left)
            stopped += reward_terms(q(ds=ds - step, ds_prev=ds), CFG).pass_
            ds, left = ds - step, left - step
        crashed = reward_terms(q(ds=ds0, ds_prev=ds0, collision=True, remaining_m=remaining), CFG).human("pass")
        assert crashed - CFG.collision == pytest.approx(stopped, abs=10.0 * dt_gap)


def test_the_forfeit_can_be_turned_off():
    literal = RewardConfig(forfeit=False)
    t = reward_terms(q(ds=0.0, ds_prev=0.0, collision=True, remaining_m=2_000.0), literal)
    assert t.forfeit_m == 0.0 and t.pass_ == 0.0 and t.human("pass") == CFG.collision


def test_side_term_only_while_racing_the_opponent_not_hanging_back():
    """A car more than side_max_behind_m behind, on its side, earns no side bias: only the
    passing term, which charges it for dropping back; within the range, the usual bias."""
    near = reward_terms(q(ds=-29.0, ds_prev=-28.0, de=3.0), CFG)
    assert near.left == pytest.approx(-1.0 + 2.5 + 0.3) and near.right == pytest.approx(-1.0 - 2.7)
    far = reward_terms(q(ds=-31.0, ds_prev=-30.0, de=3.0), CFG)
    assert far.left == pytest.approx(-1.0) and far.right == pytest.approx(-1.0)
    ahead = reward_terms(q(ds=120.0, ds_prev=119.0, de=3.0), CFG)
    assert ahead.left == pytest.approx(1.0 + 2.5 + 0.3)
    literal = RewardConfig(side_max_behind_m=None, side_cap_m=None)
    assert reward_terms(q(ds=-31.0, ds_prev=-30.0, de=3.0), literal).left == pytest.approx(-1.0 + 3.3)


def test_side_term_pays_the_lateral_gap_only_up_to_the_cap():
    """Beyond side_cap_m there is nothing more to earn by moving away from the opponent, so the
    road's edge is no longer the best place to be; below it the term is the paper's de + 0.3."""
    for de, left, right in ((1.0, 1.3, -0.7), (2.5, 2.8, -2.2), (4.5, 2.8, -4.2), (-6.0, -5.7, 2.8)):
        t = reward_terms(q(ds=0.0, ds_prev=0.0, de=de), CFG)
        assert t.left == pytest.approx(left) and t.right == pytest.approx(right)
    uncapped = reward_terms(q(ds=0.0, ds_prev=0.0, de=4.5), RewardConfig(side_cap_m=None))
    assert uncapped.left == pytest.approx(4.8)
    # right mirrors left: the same gap on the other side pays the same
    mirror = reward_terms(q(ds=0.0, ds_prev=0.0, de=-4.5), CFG)
    assert mirror.right == pytest.approx(reward_terms(q(ds=0.0, ds_prev=0.0, de=4.5), CFG).left)
