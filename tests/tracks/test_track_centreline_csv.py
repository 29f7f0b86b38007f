"""Racing-line CSV import: smoothing, closed-lap cuts with wrap-around, and located errors."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from d2a_core.errors import SpecError
from d2a_core.tracks import CentrelineCsvConfig, Track, load_centreline_csv, read_centreline_csv

FIXTURES = Path(__file__).resolve().parent / "fixtures"


def _generator():
    spec = importlib.util.spec_from_file_location("make_oval_chicane_csv", FIXTURES / "make_oval_chicane_csv.py")
    module = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def truth():
    """Ground-truth centreline of the fixture: (arc length, x, y) on a fine grid, and the lap length."""
    generator = _generator()
    s, x, y = generator.integrate(generator.curvature_pieces())
    return s, x, y, float(s[-1] + generator.STEP_M)


def _truth_point(truth, at: float) -> tuple[float, float]:
    s, x, y, lap = truth
    at = at % lap
    return float(np.interp(at, s, x)), float(np.interp(at, s, y))


def test_full_lap_is_closed_smooth_and_true_to_the_shape(oval: Track, truth) -> None:
    lap = truth[3]
    assert oval.source["closed_lap"] is True
    assert oval.length == pytest.approx(lap, abs=1.0)  # smoothing shortens the bends slightly
    # One full counter-clockwise lap turns the heading by 2 pi.
    assert oval.heading[-1] - oval.heading[0] == pytest.approx(2.0 * math.pi, abs=0.01)
    # Curvature is the shape's, not noise from centimetre rounding: R 60 on the bends, ~0 on the main straight.
    bend = (oval.s > 230.0) & (oval.s < 360.0)
    assert np.allclose(oval.curvature[bend], 1.0 / 60.0, rtol=0.03)
    straight = (oval.s > 20.0) & (oval.s < 180.0)
    assert np.max(np.abs(oval.curvature[straight])) < 1e-3
    # The chicane's R 40 arcs show up as curvature of about 1/40 of both signs.
    assert np.max(oval.curvature) == pytest.approx(1.0 / 40.0, rel=0.15)
    assert np.min(oval.curvature) < -0.5 / 40.0
    # Widths and elevation come through; grade is the slope of z.
    assert np.allclose(oval.w_left, 5.5) and np.allclose(oval.w_right, 5.0)
    assert oval.elevation_range == pytest.approx(3.0, abs=0.1)
    assert np.allclose(np.gradient(oval.z, oval.spacing), oval.grade, atol=1e-3)
    # The smoothed centreline stays within centimetres of the true one (bends a little inside, by
    # ~sigma^2 / 2R: 7.5 cm on the R 60 bends, ~12 cm in the chicane), and s drifts from the true arc length by well under a metre.
    _, tx, ty, _ = truth
    every = slice(None, None, 10)
    gap = np.hypot(oval.x[every, None] - tx[None, ::5], oval.y[every, None] - ty[None, ::5]).min(axis=1)
    assert np.max(gap) < 0.15
    for at in (50.0, 150.0, 420.0, 700.0):
        x, y, _ = oval.from_frenet(at, 0.0)
        assert math.dist((x, y), _truth_point(truth, at)) < 0.5


def test_cut_with_wrap_around(oval_csv: Path, oval: Track, truth) -> None:
    lap = truth[3]
    start, length = 700.0, 200.0  # from the last bend, over the lap's end, onto the main straight
    cut = load_centreline_csv(oval_csv, start_m=start, length_m=length)
    assert cut.length == pytest.approx(length, abs=1e-9)
    assert cut.finish_s == pytest.approx(length, abs=1e-9)
    assert math.dist((cut.x[0], cut.y[0]), _truth_point(truth, start)) < 0.3
    assert math.dist((cut.x[-1], cut.y[-1]), _truth_point(truth, start + length - lap)) < 0.6
    assert cut.y[-1] == pytest.approx(0.0, abs=0.05)  # ends on the main straight (y = 0)
    # No seam: heading continuous across the wrap, and the geometry is the full lap's.
    assert np.max(np.abs(np.diff(cut.heading))) < 2.0 * cut.spacing / 60.0
    full_s = oval.to_frenet(cut.x[0], cut.y[0])[0]
    for along in (0.0, 50.0, 150.0, 199.0):
        x, y, _ = cut.from_frenet(along, 1.0)
        wrapped = (full_s + along) % oval.length
        assert math.dist((x, y), oval.from_frenet(wrapped, 1.0)[:2]) < 0.02
    assert cut.source == pytest.approx({**cut.source, "start_m": start, "length_m": length})


def test_full_lap_cut_and_start_grid(oval_csv: Path) -> None:
    config = CentrelineCsvConfig(ego_start_s_m=8.0, opponent_gap_m=12.0, sample_spacing_m=1.0)
    track = load_centreline_csv(oval_csv, start_m=300.0, config=config)
    assert track.length == pytest.approx(track.source["lap_length_m"])
    assert track.spacing == pytest.approx(1.0, rel=1e-3)
    assert (track.start_grid.ego.s, track.start_grid.opponent.s) == (8.0, 20.0)


def _write(tmp_path: Path, text: str, name: str = "line.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _oval_lines(oval_csv: Path) -> list[str]:
    return oval_csv.read_text(encoding="utf-8").splitlines()


def test_open_section_does_not_wrap(tmp_path: Path, oval_csv: Path) -> None:
    # The first 150 points (~300 m, straight then part of a bend) without z: an open section.
    lines = [",".join(line.split(",")[:4]) for line in _oval_lines(oval_csv)[1:151]]
    path = _write(tmp_path, "x_m,y_m,w_tr_right_m,w_tr_left_m\n" + "\n".join(lines) + "\n", "open.csv")
    raw = read_centreline_csv(path)
    assert not raw.closed and raw.z is None
    track = load_centreline_csv(path, start_m=100.0, length_m=150.0)
    assert track.length == pytest.approx(150.0)
    assert (track.x[0], track.y[0]) == pytest.approx((100.0, 0.0), abs=0.05)
    assert np.all(track.z == 0.0) and np.all(track.grade == 0.0)
    with pytest.raises(SpecError, match=r"open\.csv: length: 250.0 m is beyond what remains after start 100.0 m"):
        load_centreline_csv(path, start_m=100.0, length_m=250.0)


@pytest.mark.parametrize(
    ("line_index", "replacement", "expected"),
    [
        (10, "20.00,abc,5.00,5.50,0.00", r"line\.csv:11: y_m: 'abc' is not a number"),
        (20, "40.00,0.00,5.00,5.50", r"line\.csv:21: expected 5 columns, got 4"),
        (30, "60.00,0.00,-1.00,5.50,0.00", r"line\.csv:31: w_tr_right_m: must be > 0"),
        (40, "80.00,0.00,5.00,nan,0.00", r"line\.csv:41: w_tr_left_m: must be finite"),
        (0, "# x_m, y_m, w_left, w_right", r"line\.csv:1: header must be"),
    ],
)
def test_bad_lines_are_located(tmp_path: Path, oval_csv: Path, line_index: int, replacement: str, expected: str) -> None:
    lines = _oval_lines(oval_csv)
    lines[line_index] = replacement
    with pytest.raises(SpecError, match=expected):
        load_centreline_csv(_write(tmp_path, "\n".join(lines) + "\n"))


def test_repeated_point_is_located(tmp_path: Path, oval_csv: Path) -> None:
    lines = _oval_lines(oval_csv)
    lines.insert(6, lines[5])
    with pytest.raises(SpecError, match=r"line\.csv:7: repeats the previous point"):
        load_centreline_csv(_write(tmp_path, "\n".join(lines) + "\n"))


def test_wrong_column_count_on_first_data_line(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match=r"line\.csv:2: expected 4 or 5 comma-separated columns"):
        load_centreline_csv(_write(tmp_path, "# a comment\n1,2,3\n"))


def test_too_few_points_and_empty(tmp_path: Path) -> None:
    text = "# x_m,y_m,w_tr_right_m,w_tr_left_m\n" + "".join(f"{k}.0,0.0,4.0,4.0\n" for k in range(5))
    with pytest.raises(SpecError, match=r"line\.csv: only 5 points, at least 10 are needed"):
        load_centreline_csv(_write(tmp_path, text))
    with pytest.raises(SpecError, match=r"empty\.csv: only 0 points"):
        load_centreline_csv(_write(tmp_path, "", "empty.csv"))
    with pytest.raises(SpecError, match=r"nowhere\.csv: cannot read"):
        load_centreline_csv(tmp_path / "nowhere.csv")


def test_cut_outside_the_lap(oval_csv: Path) -> None:
    with pytest.raises(SpecError, match=r"oval_chicane\.csv: length: 900.0 m is beyond the lap length"):
        load_centreline_csv(oval_csv, start_m=10.0, length_m=900.0)
    with pytest.raises(SpecError, match=r"oval_chicane\.csv: start: must be in \[0, "):
        load_centreline_csv(oval_csv, start_m=5000.0, length_m=100.0)
    with pytest.raises(SpecError, match=r"oval_chicane\.csv: length: must be > 0"):
        load_centreline_csv(oval_csv, start_m=0.0, length_m=-3.0)
    with pytest.raises(SpecError, match=r"oval_chicane\.csv: length: the section .* too short for the start grid"):
        load_centreline_csv(oval_csv, start_m=0.0, length_m=10.0)
