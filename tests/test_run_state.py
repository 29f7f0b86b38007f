"""A run's saved state: checksummed, read through the restricted unpickler, and a state written
before the checksum (a bare torch file) still resumes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from d2a_core.artifacts import Store
from d2a_core.errors import IntegrityError
from d2a_core.training.run_state import RunDir


def test_a_state_round_trips_and_a_bare_torch_state_from_before_the_checksum_loads(tmp_path):
    run = RunDir(Store(tmp_path / "store"), "ab" * 32)
    run.path.mkdir(parents=True)
    state = {"format": 1, "env_steps": 120, "agent": {"w": torch.arange(4.0)}, "replay": np.arange(6.0)}
    run.save_state(state)
    loaded = run.load_state("cpu")
    assert loaded["env_steps"] == 120 and torch.equal(loaded["agent"]["w"], state["agent"]["w"])
    assert np.array_equal(loaded["replay"], state["replay"])
    torch.save(state, run.state_path)  # how states were written before
    assert run.load_state("cpu")["env_steps"] == 120
    run.clear_state()
    assert run.load_state("cpu") is None


def test_a_state_that_is_not_a_dict_is_refused(tmp_path):
    run = RunDir(Store(tmp_path / "store"), "cd" * 32)
    run.path.mkdir(parents=True)
    run.save_state([1, 2, 3])  # type: ignore[arg-type]
    with pytest.raises(IntegrityError, match="not a run state"):
        run.load_state("cpu")
