"""The single entry point `build_track`, and the smooth knot profiles behind elevation and width."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from d2a_core.errors import NotFoundError, SpecError, UsageError
from d2a_core.tracks import TracksConfig, build_track, load_track_source, save_track
from d2a_core.tracks.interpolation import KnotProfile


def test_builds_each_source_kind(tracks_dir: Path, oval_csv: Path, tmp_path: Path) -> None:
    spec_track = build_track(tracks_dir / "straightaway.yaml")
    assert spec_track.source["kind"] == "spec" and spec_track.source["file"] == "straightaway.yaml"
    csv_track = build_track(oval_csv, start_m=10.0, length_m=300.0)
    assert csv_track.source["kind"] == "csv" and csv_track.length == pytest.approx(300.0)
    save_track(spec_track, tmp_path / "s.npz")
    assert build_track(tmp_path / "s.npz").finish_s == spec_track.finish_s


def test_config_reaches_the_sources(oval_csv: Path) -> None:
    config = TracksConfig.model_validate({"csv": {"sample_spacing_m": 2.0, "fine_spacing_m": 0.5}})
    track = build_track(oval_csv, config=config)
    assert track.spacing == pytest.approx(2.0, rel=5e-3)  # adjusted so samples end at the end


def test_usage_errors(tracks_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="apply only to centreline CSV"):
        build_track(tracks_dir / "hairpin.yaml", start_m=10.0)
    other = tmp_path / "track.json"
    other.write_text("{}", encoding="utf-8")
    with pytest.raises(UsageError, match=r"track\.json: unknown track source type '\.json'"):
        build_track(other)
    with pytest.raises(SpecError):
        build_track(tmp_path / "missing.yaml")


def test_knot_profile_is_c1_monotone_and_held_outside() -> None:
    knots = [(0.0, 0.0), (100.0, 5.0), (150.0, 12.0), (200.0, 12.0), (300.0, 2.0)]
    profile = KnotProfile(knots)
    s = np.linspace(-50.0, 350.0, 40001)
    z = profile.value(s)
    slope = profile.derivative(s)
    assert np.allclose(profile.value(np.array([k[0] for k in knots])), [k[1] for k in knots])
    # Shape preserving: no overshoot past the flat top or below the start.
    assert z.max() <= 12.0 + 1e-12 and z.min() >= 0.0 - 1e-12
    assert np.all(np.diff(z[(s >= 150) & (s <= 200)]) == pytest.approx(0.0, abs=1e-12))
    # C1: the derivative matches finite differences and has no jumps at interior knots.
    inside = (s > 0.5) & (s < 299.5)
    assert np.allclose(np.gradient(z, s)[inside], slope[inside], atol=1e-3)
    for k in (100.0, 150.0, 200.0):
        assert profile.derivative(k - 1e-9) == pytest.approx(profile.derivative(k + 1e-9), abs=1e-6)
    # Held constant outside the knots.
    assert profile.value(-10.0) == 0.0 and profile.value(400.0) == 2.0 and profile.derivative(400.0) == 0.0


def test_track_source_carries_the_raw_file_and_a_description(tracks_dir: Path, oval_csv: Path) -> None:
    source = load_track_source("hairpin")  # a bare name resolves to the shipped spec
    assert source.path.resolve() == (tracks_dir / "hairpin.yaml").resolve()
    assert source.suffix == ".yaml" and source.raw == (tracks_dir / "hairpin.yaml").read_bytes()
    assert source.track.name == "hairpin" and "hairpin.yaml" in source.description
    cut = load_track_source(oval_csv, start_m=100.0, length_m=250.0, name="oval-cut")
    assert cut.suffix == ".csv" and cut.raw == oval_csv.read_bytes()
    assert cut.track.name == "oval-cut" and cut.track.metadata()["name"] == "oval-cut"
    assert "100" in cut.description and "250" in cut.description


def test_unknown_name_suggests_close_matches() -> None:
    with pytest.raises(NotFoundError, match=r"'hairpn'.*did you mean hairpin"):
        load_track_source("hairpn")
    with pytest.raises(UsageError, match="track name"):
        load_track_source("straightaway", name="bad name")
