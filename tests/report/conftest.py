"""Fixtures of the report tests: the synthetic store of `report_store.py`, built once per module."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from report_store import make_store


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> tuple[Path, dict[str, Any]]:
    root = tmp_path_factory.mktemp("report") / "store"
    return root, make_store(root)
