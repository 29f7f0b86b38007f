"""Sequence replay: windows are contiguous within one environment's stream, mark episode starts,
never wrap across the write position, are reproducible from the seed, and survive save/load."""

from __future__ import annotations

import numpy as np
import pytest

from d2a_core.agents.dreamer.config import DreamerConfig
from d2a_core.agents.dreamer.replay import SequenceReplay
from d2a_core.config.section import record
from d2a_core.errors import TrainingError, UsageError


def _fill(replay: SequenceReplay, steps: int, envs: int = 3, seed: int = 0) -> None:
    """Streams of episodes of random length 2..9, tagged with env, episode id and a step counter."""
    rng = np.random.default_rng(seed)
    episode = np.arange(envs) * 1000
    remaining = np.zeros(envs, int)
    for t in range(steps):
        first = remaining == 0
        episode = np.where(first, episode + 1, episode)
        remaining = np.where(first, rng.integers(2, 10, envs), remaining) - 1
        replay.add(
            {
                "obs": rng.normal(size=(envs, 2)).astype(np.float32),
                "is_first": first,
                "episode": episode.copy(),
                "env": np.arange(envs),
                "counter": np.full(envs, t),
            }
        )


def test_windows_respect_episode_boundaries_and_streams():
    replay = SequenceReplay(capacity=3 * 200, seed=0)
    _fill(replay, 150)
    batch = replay.sample(64, 12)
    assert batch["obs"].shape == (64, 12, 2)
    # One environment per window, consecutive steps.
    assert (batch["env"] == batch["env"][:, :1]).all()
    assert (np.diff(batch["counter"], axis=1) == 1).all()
    # Every change of episode inside a window is marked by is_first; the window start too.
    changes = np.diff(batch["episode"], axis=1) != 0
    assert (batch["is_first"][:, 1:][changes]).all()
    assert batch["is_first"][:, 0].all()
    # And no is_first inside a window without an episode change.
    assert not (batch["is_first"][:, 1:] & ~changes).any()


def test_windows_never_cross_the_write_position_after_wrapping():
    replay = SequenceReplay(capacity=2 * 50, seed=1)
    _fill(replay, 173, envs=2)  # wrapped more than three times
    assert len(replay) == 100
    for _ in range(20):
        batch = replay.sample(32, 10)
        assert (np.diff(batch["counter"], axis=1) == 1).all()
        assert batch["counter"].min() >= 173 - 50  # only the newest 50 steps per stream


def test_sampling_is_deterministic_given_the_seed():
    a, b, c = SequenceReplay(300, seed=7), SequenceReplay(300, seed=7), SequenceReplay(300, seed=8)
    for replay in (a, b, c):
        _fill(replay, 90)
    first, second, other = a.sample(8, 5), b.sample(8, 5), c.sample(8, 5)
    assert all(np.array_equal(first[k], second[k]) for k in first)
    assert not np.array_equal(first["counter"], other["counter"])


def test_state_round_trip_continues_the_same_samples(tmp_path):
    replay = SequenceReplay(300, seed=3)
    _fill(replay, 120)
    replay.sample(4, 6)  # advance the RNG
    path = tmp_path / "replay.npz"
    replay.save(path)
    restored = SequenceReplay.load(path)
    for _ in range(3):
        expected, got = replay.sample(4, 6), restored.sample(4, 6)
        assert all(np.array_equal(expected[k], got[k]) for k in expected)
    _fill(replay, 5, seed=9)
    _fill(restored, 5, seed=9)
    assert np.array_equal(replay.sample(4, 6)["counter"], restored.sample(4, 6)["counter"])


def test_errors_for_inconsistent_steps_and_too_little_data():
    replay = SequenceReplay(100, seed=0)
    assert not replay.can_sample(4)
    with pytest.raises(TrainingError):
        replay.sample(2, 4)
    replay.add({"obs": np.zeros((2, 3)), "is_first": np.ones(2, bool)})
    with pytest.raises(UsageError, match="fields"):
        replay.add({"obs": np.zeros((2, 3))})
    with pytest.raises(UsageError, match="obs"):
        replay.add({"obs": np.zeros((2, 4)), "is_first": np.ones(2, bool)})


def test_recent_windows_lie_in_the_newest_steps_and_a_zero_fraction_samples_as_before():
    uniform, mixed, zero = (SequenceReplay(capacity=3 * 400, seed=4) for _ in range(3))
    for replay in (uniform, mixed, zero):
        _fill(replay, 300)
    plain = uniform.sample(32, 10)
    unchanged = zero.sample(32, 10, recent_fraction=0.0, recent_steps=60)
    assert all(np.array_equal(plain[k], unchanged[k]) for k in plain)
    batch = mixed.sample(32, 10, recent_fraction=0.5, recent_steps=3 * 40)  # newest 40 steps per stream
    newest = 299
    assert (batch["counter"][:16] >= newest - 39).all() and (batch["counter"][:16] <= newest).all()
    assert (np.diff(batch["counter"], axis=1) == 1).all()
    # the other half is uniform: over 16 windows of 300 steps some start well before the recent span
    assert (batch["counter"][16:, 0] < newest - 39).any()
    # a recent span shorter than a window still yields whole windows, the newest ones
    short = mixed.sample(8, 10, recent_fraction=1.0, recent_steps=3)
    assert (short["counter"][:, -1] == newest).all()


def test_the_replay_keys_stay_out_of_run_records_at_their_defaults():
    assert not {"replay_recent_fraction", "replay_recent_steps", "replay_terminal_fraction"} & set(record(DreamerConfig()))
    assert record(DreamerConfig(replay_recent_fraction=0.5))["replay_recent_fraction"] == 0.5


def test_terminal_windows_hold_a_terminal_step_anywhere_in_the_window():
    def fill(replay):
        rng = np.random.default_rng(1)
        for t in range(500):  # wraps the 3 x 150 ring; terminals at every 37th step of stream 1 only
            replay.add({"obs": rng.normal(size=(3, 2)).astype(np.float32), "counter": np.full(3, t),
                        "env": np.arange(3), "is_terminal": (np.arange(3) == 1) & (t % 37 == 36)})

    plain, zero, ending = (SequenceReplay(capacity=3 * 150, seed=2) for _ in range(3))
    for replay in (plain, zero, ending):
        fill(replay)
    reference = plain.sample(40, 12)
    assert all(np.array_equal(reference[k], v) for k, v in zero.sample(40, 12, terminal_fraction=0.0).items())
    batch = ending.sample(40, 12, terminal_fraction=0.25)
    assert batch["is_terminal"][:10].any(axis=1).all() and (batch["env"][:10] == 1).all()
    assert (np.diff(batch["counter"], axis=1) == 1).all()  # still contiguous, never across the write position
    assert batch["counter"].min() >= 500 - 150  # only steps still in the ring
    places = np.argmax(batch["is_terminal"][:10], axis=1)
    assert len(set(places.tolist())) > 3  # the terminal step is not always at the same place
    # no terminal stored yet: uniform windows, no error
    empty = SequenceReplay(capacity=100, seed=0)
    for _ in range(20):
        empty.add({"obs": np.zeros((1, 2), np.float32), "is_terminal": np.zeros(1, bool)})
    assert empty.sample(4, 5, terminal_fraction=1.0)["obs"].shape == (4, 5, 2)


def test_replay_fractions_are_validated():
    with pytest.raises(ValueError, match="must not exceed 1"):
        DreamerConfig(replay_recent_fraction=0.6, replay_terminal_fraction=0.5)
