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


def test_retired_replay_and_update_settings_load_at_their_former_defaults_only():
    """Records written while these were settings (at their defaults: left out of records, or, for
    those every record held, always written) validate as before and record the same; any other
    value names the retired key."""
    constants = {"discrete_actor_grad": "reinforce", "continuous_actor_grad": "backprop", "precision": "float32"}
    stored = {"replay_recent_fraction": 0.0, "replay_recent_steps": 5000, "replay_terminal_fraction": 0.0,
              "model_updates": 1, "return_norm_scope": "all", "terminal_weight": 1.0, **constants}
    config = DreamerConfig.model_validate(stored)
    assert config == DreamerConfig()
    assert {k: record(config)[k] for k in constants} == constants  # the ids of runs made with them hold
    assert not (set(stored) - set(constants)) & set(record(config))
    for key, value in (("model_updates", 4), ("replay_recent_fraction", 0.5), ("return_norm_scope", "running"),
                       ("continuous_actor_grad", "reinforce"), ("precision", "bfloat16"), ("terminal_weight", 20.0)):
        with pytest.raises(ValueError, match=f"'{key}' is a retired setting"):
            DreamerConfig.model_validate({key: value})
