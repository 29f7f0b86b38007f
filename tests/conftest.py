"""Shared test fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from d2a_test_helpers import run_cli


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture
def store_dir(tmp_path: Path) -> Path:
    return tmp_path / "store"
