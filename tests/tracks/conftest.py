"""Shared fixtures: the shipped tracks compiled once per test session."""

from __future__ import annotations

from pathlib import Path

import pytest

from d2a_core.tracks import Track, build_track

REPO = Path(__file__).resolve().parents[2]
TRACKS_DIR = REPO / "tracks"
FIXTURES = Path(__file__).resolve().parent / "fixtures"
OVAL_CSV = FIXTURES / "oval_chicane.csv"


@pytest.fixture(scope="session")
def straightaway() -> Track:
    return build_track(TRACKS_DIR / "straightaway.yaml")


@pytest.fixture(scope="session")
def hairpin() -> Track:
    return build_track(TRACKS_DIR / "hairpin.yaml")


@pytest.fixture(scope="session")
def oval() -> Track:
    return build_track(OVAL_CSV)


@pytest.fixture(scope="session")
def oval_csv() -> Path:
    return OVAL_CSV


@pytest.fixture(scope="session")
def tracks_dir() -> Path:
    return TRACKS_DIR
