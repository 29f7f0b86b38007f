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


def test_training_run_keys_are_those_of_every_stored_run():
    """Stored populations and assistants are found again by their run key: its composition must
    never change without a new RUN_FORMAT or training-code version. The identities below are the
    ones the two training commands have always hashed; the hex digests pin them."""
    from types import SimpleNamespace

    from d2a_core.artifacts import content_key
    from d2a_core.training.code_version import TRAINING_CODE_VERSION
    from d2a_core.training.run_state import RUN_FORMAT, training_run_key

    bundle = SimpleNamespace(track_id="t" * 64, replay_ids=["r1", "r2"])
    humans = training_run_key("humans", bundle, {"dreamer": {"units": 128}}, 3, intent="pass")
    assert humans == content_key({"format": RUN_FORMAT, "kind": "humans", "code": TRAINING_CODE_VERSION,
                                  "track": "t" * 64, "replays": ["r1", "r2"], "intent": "pass",
                                  "config": {"dreamer": {"units": 128}}, "seed": 3})
    assistant = training_run_key("assistant", bundle, {"assistant": {"env_steps": 60000}}, 0,
                                 populations=["p1", "p2"], pair="pass-stay", method="dream2assist")
    assert assistant == content_key({"format": RUN_FORMAT, "kind": "assistant", "code": TRAINING_CODE_VERSION,
                                     "track": "t" * 64, "replays": ["r1", "r2"], "populations": ["p1", "p2"],
                                     "pair": "pass-stay", "method": "dream2assist",
                                     "config": {"assistant": {"env_steps": 60000}}, "seed": 0})
    if (RUN_FORMAT, TRAINING_CODE_VERSION) == (1, 4):
        assert humans == "c039998c8e3dc1f22115fbf5e5d21a09df1fbfe6ac0677170ca4268a7d202fac"
        assert assistant == "e52923ca3cf7b66218f982813f1d573ed09d38394cc6d464e65b859d5a9182e4"
