"""Episode metrics from crafted info sequences."""

from __future__ import annotations

import pytest

from d2a_core.evaluation.metrics import METRIC_NAMES, aggregate, episode_metrics


def info(ds, de=1.0, progress=0.0, speed=20.0, finished=False, collision_car=False, racing=True, task=0.0):
    return {
        "ds": ds, "de": de, "progress": progress, "speed": speed, "finished": finished,
        "collision": collision_car, "collision_car": collision_car, "collision_barrier": False,
        "off_track": False, "opponent_racing": racing,
        "reward_terms": {"task": task, "pass": 1.0, "stay": 2.0, "left": 3.0, "right": 4.0},
    }


def episode(ds_values, **last):
    infos = [info(ds) for ds in ds_values]
    infos[-1] = info(ds_values[-1], **last)
    return infos, [1.0] * (len(infos) - 1)


def test_pass_episode_overtakes_and_finishes_ahead():
    infos, rewards = episode([-5.0, -2.0, 1.0, 4.0], finished=True, progress=370.0, task=100.0)
    m = episode_metrics(infos, rewards)
    assert set(m) == set(METRIC_NAMES)
    assert m["overtakes"] == 1 and m["ahead_at_end"] == 1 and m["finished"] == 1
    assert m["finished_ahead"] == 1 and m["finished_never_ahead"] == 0
    assert m["return"] == 3.0 and m["steps"] == 3 and m["progress_m"] == 370.0
    assert m["return_pass"] == pytest.approx(100.0 + 3 * 1.0)


def test_stay_episode_finishes_never_ahead():
    infos, rewards = episode([-30.0, -28.0, -29.0], finished=True)
    m = episode_metrics(infos, rewards)
    assert m["finished_never_ahead"] == 1 and m["finished_ahead"] == 0 and m["overtakes"] == 0


def test_ahead_once_is_not_never_ahead_and_a_crash_is_not_a_finish():
    infos, rewards = episode([-3.0, 1.0, -1.0], finished=True)
    assert episode_metrics(infos, rewards)["finished_never_ahead"] == 0
    infos, rewards = episode([-3.0, 2.0, 5.0], collision_car=True)
    m = episode_metrics(infos, rewards)
    assert m["finished_ahead"] == 0 and m["collision_car"] == 1 and m["ahead_at_end"] == 1


def test_overtakes_of_a_stopped_opponent_do_not_count():
    infos = [info(-3.0), info(2.0, racing=False), info(3.0, racing=False)]
    assert episode_metrics(infos, [0.0, 0.0])["overtakes"] == 0


def test_share_left_and_aggregate_rates():
    infos = [info(-5.0), info(-4.0, de=2.0), info(-3.0, de=-1.0), info(-2.0, de=0.5), info(-1.0, de=-0.2)]
    m = episode_metrics(infos, [0.0] * 4)
    assert m["share_left"] == 0.5
    a = aggregate([m, {**m, "share_left": 1.0, "return": 4.0}])
    assert a["episodes"] == 2 and a["share_left"] == 0.75 and a["return_std"] == 2.0


def test_bad_lengths_are_rejected():
    infos, rewards = episode([-1.0, 0.0])
    with pytest.raises(ValueError):
        episode_metrics(infos, rewards + [0.0])


def test_holding_a_side_means_racing_alongside_not_dropping_back():
    """A driver left of the opponent but far behind it ("parked" on its side) does not hold left."""
    alongside = [info(-5.0), info(-2.0, de=2.0), info(1.0, de=2.5), info(6.0, de=-1.0), info(9.0, de=-2.0)]
    m = episode_metrics(alongside, [0.0] * 4)
    assert m["held_left"] == 0.5 and m["held_right"] == 0.5
    parked = [info(-15.0), info(-25.0, de=2.0), info(-40.0, de=2.0), info(-80.0, de=2.0), info(-120.0, de=2.0)]
    m = episode_metrics(parked, [0.0] * 4)
    assert m["share_left"] == 1.0 and m["held_left"] == 0.25 and m["held_right"] == 0.0
