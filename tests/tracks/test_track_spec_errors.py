"""Bad track specs raise SpecError naming the file and the field (and line)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from d2a_core.errors import SpecError
from d2a_core.tracks import build_track, load_spec

VALID: dict[str, Any] = {
    "name": "mini",
    "sample_spacing_m": 0.5,
    "segments": [
        {"straight": {"length": 100.0}},
        {"transition": {"length": 10.0, "end_curvature": 0.02}},
        {"arc": {"radius": 50.0, "angle_deg": 45.0, "direction": "left"}},
        {"straight": {"length": 60.0}},
    ],
    "width": {"left": 5.0, "right": 5.0},
    "elevation": [[0.0, 0.0], [100.0, 2.0]],
    "barriers": [{"side": "right", "s_start": 0.0, "s_end": 100.0, "offset": 1.0, "height": 1.0}],
    "finish_s": 150.0,
    "start_grid": {"ego": {"s": 5.0, "e": -1.0}, "opponent": {"s": 20.0, "e": 1.0}},
}


def _write(tmp_path: Path, data: Any, name: str = "broken_track.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _error(tmp_path: Path, mutate) -> str:
    data = copy.deepcopy(VALID)
    mutate(data)
    path = _write(tmp_path, data)
    with pytest.raises(SpecError) as caught:
        load_spec(path)
    message = str(caught.value)
    assert "broken_track.yaml" in message
    assert caught.value.exit_code == 2
    return message


def test_valid_spec_loads(tmp_path: Path) -> None:
    spec = load_spec(_write(tmp_path, VALID))
    assert spec.total_length == pytest.approx(100 + 10 + 50 * 3.141592653589793 / 4 + 60)
    assert spec.segments[2].arc is not None and spec.segments[2].arc.curvature == pytest.approx(0.02)


def test_negative_arc_radius_names_the_field_path(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"][2]["arc"].update(radius=-5))
    assert "segments[2].arc.radius" in message
    assert "must be > 0" in message and "-5" in message


def test_unknown_field_is_rejected(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"][0]["straight"].update(lenght=3))
    assert "segments[0].straight.lenght" in message and "unknown field" in message


def test_missing_field_is_named(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d.pop("finish_s"))
    assert "finish_s" in message and "missing" in message


def test_bad_direction_is_named(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"][2]["arc"].update(direction="up"))
    assert "segments[2].arc.direction" in message and "'left' or 'right'" in message


def test_segment_with_two_kinds_is_rejected(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"][0].update(arc={"radius": 9, "angle_deg": 9, "direction": "left"}))
    assert "segments[0]" in message and "exactly one" in message


def test_non_increasing_elevation_knots(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d.update(elevation=[[0, 0], [50, 1], [40, 2]]))
    assert "elevation" in message and "increasing" in message


def test_non_positive_width(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["width"].update(left=[[0, 5.0], [50, 0.0]]))
    assert "width.left" in message and "> 0" in message


def test_finish_beyond_track_length(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d.update(finish_s=1000.0))
    assert "finish_s" in message and "track length" in message


def test_barrier_beyond_track_length(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["barriers"][0].update(s_end=999.0))
    assert "barriers[0].s_end" in message


def test_barrier_with_reversed_range(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["barriers"][0].update(s_start=80.0, s_end=20.0))
    assert "barriers[0]" in message and "s_end" in message


def test_opponent_must_start_ahead(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["start_grid"]["opponent"].update(s=2.0))
    assert "start_grid" in message and "ahead" in message


def test_start_slot_off_the_road(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["start_grid"]["ego"].update(e=-7.0))
    assert "start_grid.ego.e" in message and "on the road" in message


def test_non_numeric_value(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"][3]["straight"].update(length="long"))
    assert "segments[3].straight.length" in message and "number" in message


def test_non_finite_value(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"][3]["straight"].update(length=float("inf")))
    assert "segments[3].straight.length" in message and "finite" in message


def test_error_reports_the_yaml_line(tmp_path: Path) -> None:
    text = (
        "name: mini\n"
        "segments:\n"
        "  - straight: {length: 100}\n"
        "  - arc:\n"
        "      radius: -5\n"
        "      angle_deg: 90\n"
        "      direction: left\n"
        "width: {left: 5, right: 5}\n"
        "finish_s: 90\n"
        "start_grid: {ego: {s: 5}, opponent: {s: 20}}\n"
    )
    path = tmp_path / "lines.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SpecError, match=r"lines\.yaml:5: segments\[1\]\.arc\.radius: must be > 0"):
        load_spec(path)


def test_yaml_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "syntax.yaml"
    path.write_text("name: mini\nsegments:\n  - straight: {length: 100\nwidth: 3\n", encoding="utf-8")
    with pytest.raises(SpecError, match=r"syntax\.yaml:\d+:\d+: YAML syntax error"):
        load_spec(path)


def test_duplicate_key_is_reported(tmp_path: Path) -> None:
    text = yaml.safe_dump(VALID, sort_keys=False) + "finish_s: 120\n"
    path = tmp_path / "dupe.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SpecError, match=r"dupe\.yaml:\d+: finish_s: duplicate key"):
        load_spec(path)


def test_not_a_mapping_and_empty_and_missing(tmp_path: Path) -> None:
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n", encoding="utf-8")
    with pytest.raises(SpecError, match=r"list\.yaml: the spec must be a YAML mapping"):
        load_spec(listed)
    empty = tmp_path / "empty.yaml"
    empty.write_text("", encoding="utf-8")
    with pytest.raises(SpecError, match=r"empty\.yaml: the spec is empty"):
        load_spec(empty)
    with pytest.raises(SpecError, match=r"absent\.yaml: cannot read"):
        load_spec(tmp_path / "absent.yaml")


def test_arc_tighter_than_the_road_folds(tmp_path: Path) -> None:
    data = copy.deepcopy(VALID)
    data["segments"][2]["arc"]["radius"] = 4.0  # left half width is 5 m: the left edge folds
    with pytest.raises(SpecError) as caught:
        build_track(_write(tmp_path, data))
    message = str(caught.value)
    assert "broken_track.yaml" in message and "segments[2].arc.radius" in message and "fold" in message


def test_barrier_offset_counts_towards_folding(tmp_path: Path) -> None:
    data = copy.deepcopy(VALID)
    data["segments"][2]["arc"].update(radius=8.0, direction="right")
    data["segments"][1]["transition"]["end_curvature"] = -0.125
    data["barriers"][0].update(s_start=111.0, s_end=140.0, offset=3.5)  # on the arc: 5 + 3.5 > 8 - 1
    with pytest.raises(SpecError, match=r"segments\[2\]\.arc\.radius.*right side"):
        build_track(_write(tmp_path, data))


def test_self_crossing_layout_is_rejected(tmp_path: Path) -> None:
    data = copy.deepcopy(VALID)
    # A 300 degree loop brings the road back across its own start straight.
    data["segments"] = [
        {"straight": {"length": 100.0}},
        {"arc": {"radius": 30.0, "angle_deg": 300.0, "direction": "left"}},
        {"straight": {"length": 120.0}},
    ]
    data["barriers"] = []
    with pytest.raises(SpecError) as caught:
        build_track(_write(tmp_path, data))
    message = str(caught.value)
    assert "broken_track.yaml" in message and "overlaps itself" in message and "segments[" in message


def test_barrier_crossing_another_part_is_rejected(tmp_path: Path) -> None:
    data = copy.deepcopy(VALID)
    # A hairpin whose legs are 30 m apart: a barrier 22 m off the inside edge stands on the other leg.
    data["segments"] = [
        {"straight": {"length": 100.0}},
        {"arc": {"radius": 15.0, "angle_deg": 180.0, "direction": "left"}},
        {"straight": {"length": 100.0}},
    ]
    data["barriers"] = [{"side": "left", "s_start": 10.0, "s_end": 90.0, "offset": 22.0, "height": 1.0}]
    with pytest.raises(SpecError, match=r"broken_track\.yaml: segments: the track overlaps itself: barrier\[0\]"):
        build_track(_write(tmp_path, data))


def test_width_must_be_a_number_or_knots(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["width"].update(left="wide"))
    assert "width.left: must be a number or a list" in message and "width.left." not in message
    message = _error(tmp_path, lambda d: d["width"].update(right=[[0, 5.0], [40, "x"]]))
    assert "width.right: knot 1 must be a pair of numbers" in message


def test_segment_that_is_not_a_mapping(tmp_path: Path) -> None:
    message = _error(tmp_path, lambda d: d["segments"].append("straight"))
    assert "segments[4]: must be a mapping" in message
