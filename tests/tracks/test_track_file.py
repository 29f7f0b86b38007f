"""Saving and loading a compiled track: exact round trip, stable bytes, clear errors."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from d2a_core.errors import SpecError
from d2a_core.tracks import Track, build_track, load_track, save_track
from d2a_core.tracks.track import SAMPLE_FIELDS


def _assert_same(a: Track, b: Track) -> None:
    for name in SAMPLE_FIELDS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.name == b.name and a.finish_s == b.finish_s and a.start_grid == b.start_grid
    assert a.source == b.source and a.metadata() == b.metadata()
    assert len(a.barriers) == len(b.barriers)
    for p, q in zip(a.barriers, b.barriers):
        assert (p.side, p.kind, p.height, p.offset) == (q.side, q.kind, q.height, q.offset)
        assert np.array_equal(p.s, q.s) and np.array_equal(p.points, q.points) and np.array_equal(p.e, q.e)


def test_save_load_round_trip_is_exact(hairpin: Track, tmp_path: Path) -> None:
    path = tmp_path / "hairpin.npz"
    save_track(hairpin, path)
    loaded = load_track(path)
    _assert_same(hairpin, loaded)
    # Queries behave identically.
    assert loaded.to_frenet(250.0, -100.0, 330.0) == hairpin.to_frenet(250.0, -100.0, 330.0)
    assert loaded.elevation_range == hairpin.elevation_range


def test_csv_track_round_trip_and_builder_reads_npz(oval: Track, tmp_path: Path) -> None:
    path = tmp_path / "oval.npz"
    save_track(oval, path)
    _assert_same(oval, build_track(path))


def test_same_track_gives_same_bytes(straightaway: Track, tmp_path: Path) -> None:
    first, second = tmp_path / "a.npz", tmp_path / "b.npz"
    save_track(straightaway, first)
    save_track(straightaway, second)
    assert first.read_bytes() == second.read_bytes()
    # It is an ordinary npz: plain numpy can read the arrays without pickle.
    with np.load(first, allow_pickle=False) as archive:
        assert np.array_equal(archive["x"], straightaway.x)


def test_bad_track_files_raise_spec_error(tmp_path: Path, straightaway: Track) -> None:
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip")
    with pytest.raises(SpecError, match="garbage.npz"):
        load_track(garbage)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.zeros(3))
    with pytest.raises(SpecError, match=r"foreign\.npz: not a d2a track file"):
        load_track(foreign)
    # A file missing one of its arrays.
    good = tmp_path / "good.npz"
    save_track(straightaway, good)
    broken = tmp_path / "broken.npz"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(broken, "w") as dst:
        for item in src.infolist():
            if item.filename != "heading.npy":
                dst.writestr(item, src.read(item.filename))
    with pytest.raises(SpecError, match=r"broken\.npz: corrupt track file"):
        load_track(broken)
    with pytest.raises(SpecError, match=r"missing\.npz"):
        load_track(tmp_path / "missing.npz")
