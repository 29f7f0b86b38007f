"""Shared test fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from d2a_test_helpers import copy_store, run_cli

# Under pytest-xdist each worker has a core: one torch/OpenMP thread per worker and per CLI
# subprocess it starts (they inherit the environment). Left at torch's default (a thread per
# core) the workers' thread pools spin against each other: the suite took 21 min instead of 12
# on 2 cores, with 2.7x the CPU time.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def pytest_configure(config):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture
def store_dir(tmp_path: Path) -> Path:
    return tmp_path / "store"


@pytest.fixture(scope="session")
def pair_store_template(tmp_path_factory) -> Path:
    """A smoke store with the straightaway and pass/stay populations of 4 checkpoints each, made
    once per session; copy it (`copy_store`) before changing it."""
    store = tmp_path_factory.mktemp("pair-template") / "store"
    res = run_cli("make-track", "straightaway", "--preset", "smoke", "--json", store=store)
    assert res.code == 0, res.stderr
    res = run_cli("train-humans", "--intent", "pass", "--intent", "stay", "--track", "straightaway",
                  "--preset", "smoke", "--set", "humans.checkpoints=4", "--json", store=store)
    assert res.code == 0, res.stderr
    return store


@pytest.fixture(scope="session")
def trained_assistants(pair_store_template, tmp_path_factory):
    """(store, result JSON) of `train-assistant` with every implemented method on a copy of the
    pair store (smoke), made once per session."""
    from d2a_core.training.methods import method_names

    store = copy_store(pair_store_template, tmp_path_factory.mktemp("assistants"))
    methods = method_names(implemented_only=True)
    res = run_cli("train-assistant", "--track", "straightaway", "--pair", "pass-stay",
                  *(a for m in methods for a in ("--method", m)), "--preset", "smoke", "--json", store=store)
    assert res.code == 0, res.stderr
    return store, res.json
