"""Compiled geometry: segment shapes, the shipped tracks' promised properties, no self-overlap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from d2a_core.tracks import Track, TrackSpec, compile_spec, find_road_overlap


def _spec(segments: list[dict], **extra) -> TrackSpec:
    data = {
        "name": "probe",
        "sample_spacing_m": 0.5,
        "segments": segments,
        "width": {"left": 5.0, "right": 5.0},
        "finish_s": 10.0,
        "start_grid": {"ego": {"s": 1.0}, "opponent": {"s": 5.0}},
    }
    data.update(extra)
    return TrackSpec.model_validate(data)


def _circumradius(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    a = np.linalg.norm(p1 - p0, axis=1)
    b = np.linalg.norm(p2 - p1, axis=1)
    c = np.linalg.norm(p2 - p0, axis=1)
    cross = np.abs((p1 - p0)[:, 0] * (p2 - p0)[:, 1] - (p1 - p0)[:, 1] * (p2 - p0)[:, 0])
    return a * b * c / (2.0 * cross)


def test_arc_curvature_is_one_over_radius_in_the_points_too() -> None:
    radius = 25.0
    track = compile_spec(
        _spec([{"straight": {"length": 20.0}}, {"arc": {"radius": radius, "angle_deg": 120.0, "direction": "right"}},
               {"straight": {"length": 20.0}}])
    )
    on_arc = (track.s > 21.0) & (track.s < 20.0 + radius * math.radians(120.0) - 1.0)
    assert np.allclose(track.curvature[on_arc], -1.0 / radius, atol=1e-12)
    # The sampled points themselves lie on a circle of that radius (not just the stored field).
    points = np.stack([track.x, track.y], axis=1)[on_arc]
    radii = _circumradius(points[:-2], points[1:-1], points[2:])
    assert np.allclose(radii, radius, rtol=1e-6)
    # A right turn of 120 degrees.
    assert track.heading[-1] - track.heading[0] == pytest.approx(-math.radians(120.0), abs=1e-12)


def test_straight_then_quarter_circle_ends_where_geometry_says() -> None:
    track = compile_spec(
        _spec([{"straight": {"length": 30.0}}, {"arc": {"radius": 40.0, "angle_deg": 90.0, "direction": "left"}}],
              start_pose={"x": 5.0, "y": -3.0, "heading_deg": 90.0})
    )
    # Heading north from (5, -3): 30 m up, then a left quarter circle of R 40 ends 40 m west, 40 m north.
    assert track.x[-1] == pytest.approx(5.0 - 40.0, abs=1e-9)
    assert track.y[-1] == pytest.approx(-3.0 + 30.0 + 40.0, abs=1e-9)
    assert track.length == pytest.approx(30.0 + 20.0 * math.pi, abs=1e-9)


def test_transition_curvature_is_linear_and_heading_is_its_integral() -> None:
    track = compile_spec(
        _spec([{"straight": {"length": 10.0}}, {"transition": {"length": 40.0, "end_curvature": 0.05}},
               {"arc": {"radius": 20.0, "angle_deg": 30.0, "direction": "left"}}])
    )
    inside = (track.s > 10.0) & (track.s < 50.0)
    assert np.allclose(track.curvature[inside], 0.05 * (track.s[inside] - 10.0) / 40.0, atol=1e-12)
    # Heading change over the clothoid is the area under its curvature: 0.05 * 40 / 2 = 1 rad.
    assert track.heading_at(50.0) - track.heading_at(10.0) == pytest.approx(1.0, abs=1e-4)
    # Chord directions agree with the stored headings (positions integrate the heading).
    chord = np.arctan2(np.diff(track.y), np.diff(track.x))
    middle = 0.5 * (track.heading[1:] + track.heading[:-1])
    assert np.max(np.abs(np.angle(np.exp(1j * (chord - middle))))) < 1e-4


@pytest.mark.parametrize("name", ["straightaway", "hairpin"])
def test_heading_is_continuous(name: str, request: pytest.FixtureRequest) -> None:
    track: Track = request.getfixturevalue(name)
    steps = np.abs(np.diff(track.heading))
    # Per sample the heading can change at most |curvature| * spacing (no jumps at segment joins).
    assert np.all(steps <= np.abs(track.curvature).max() * track.spacing + 1e-9)
    assert np.max(np.abs(np.diff(track.x)) + np.abs(np.diff(track.y))) <= 2 * track.spacing


def test_straightaway_is_flat_370_m_with_a_right_concrete_wall(straightaway: Track) -> None:
    assert straightaway.finish_s == pytest.approx(370.0, abs=1.0)
    assert straightaway.length >= straightaway.finish_s
    assert straightaway.elevation_range == 0.0
    assert np.all(straightaway.curvature == 0.0)
    width = straightaway.w_left + straightaway.w_right
    assert np.all((width >= 12.0 - 1e-9) & (width <= 15.0 + 1e-9))
    right_walls = [b for b in straightaway.barriers if b.side == "right" and b.kind == "concrete"]
    assert right_walls, "the straightaway needs a concrete barrier on the right"
    wall = right_walls[0]
    assert wall.s_start <= 0.0 + 1e-9 and wall.s_end >= straightaway.finish_s
    # The wall is outside the right edge, i.e. right of the road (negative e beyond -w_right).
    _, e = straightaway.to_frenet(wall.points[:, 0], wall.points[:, 1])
    assert np.all(e < -straightaway.width_at(wall.s)[1])
    assert straightaway.start_grid.opponent.s - straightaway.start_grid.ego.s >= 2 * 4.6


def test_hairpin_length_width_and_hills(hairpin: Track) -> None:
    assert hairpin.finish_s == pytest.approx(960.0, abs=1.0)
    assert hairpin.length >= hairpin.finish_s
    assert hairpin.elevation_range >= 10.0
    assert np.max(np.abs(hairpin.grade)) < 0.12
    # The grade is the slope of z (finite differences agree).
    assert np.allclose(np.gradient(hairpin.z, hairpin.spacing), hairpin.grade, atol=2e-3)
    width = hairpin.w_left + hairpin.w_right
    assert np.all((width >= 10.0 - 1e-9) & (width <= 14.0 + 1e-9))
    assert len(hairpin.barriers) >= 3


def test_hairpin_has_a_true_hairpin_and_several_sharp_turns(hairpin: Track) -> None:
    # Some 100 m window turns >= 150 degrees, with its tightest radius in 15-25 m.
    window = int(round(100.0 / hairpin.spacing))
    turn = np.abs(hairpin.heading[window:] - hairpin.heading[:-window])
    best = int(np.argmax(turn))
    assert math.degrees(turn[best]) >= 150.0
    tightest = 1.0 / np.max(np.abs(hairpin.curvature[best : best + window]))
    assert 15.0 <= tightest <= 25.0
    # Several sharp turns: count separate stretches tighter than R 40 m.
    sharp = np.abs(hairpin.curvature) > 1.0 / 40.0
    starts = np.count_nonzero(sharp[1:] & ~sharp[:-1]) + int(sharp[0])
    assert starts >= 3


@pytest.mark.parametrize("name", ["straightaway", "hairpin"])
def test_no_self_intersection(name: str, request: pytest.FixtureRequest) -> None:
    track: Track = request.getfixturevalue(name)
    left, right = track.edges()
    assert find_road_overlap(track.s, left, right) is None
    # Independent clearance check: edge and barrier points of parts more than 40 m apart along the
    # track are at least 10 m apart in the plane.
    every = max(1, int(round(2.0 / track.spacing)))
    points = [left[::every, :2], right[::every, :2]] + [b.points[::every, :2] for b in track.barriers]
    at_s = [track.s[::every], track.s[::every]] + [b.s[::every] for b in track.barriers]
    xy, s = np.concatenate(points), np.concatenate(at_s)
    distance = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
    far_apart = np.abs(s[:, None] - s[None, :]) > 40.0
    assert np.min(distance[far_apart], initial=np.inf) > 10.0


def test_overlap_finder_detects_a_crossing() -> None:
    # Two straight roads crossing like an X must be reported (guards the clearance test above).
    s = np.arange(0.0, 201.0)
    first = s < 100.0
    # Road A runs east along y = 0; road B then runs north along x = 50 from y = -50, through A.
    centre = np.where(first[:, None], np.stack([s, 0 * s], 1), np.stack([50 + 0 * s, s - 150.0], 1))
    normal = np.where(first[:, None], [0.0, 1.0], [-1.0, 0.0])
    left, right = centre + 3.0 * normal, centre - 3.0 * normal
    assert find_road_overlap(s, left, right) is not None


def test_barriers_follow_the_road_edge_at_their_offset(hairpin: Track) -> None:
    for barrier in hairpin.barriers:
        s, e = hairpin.to_frenet(barrier.points[:, 0], barrier.points[:, 1], barrier.s)
        w_left, w_right = hairpin.width_at(barrier.s)
        expected = (w_left + barrier.offset) if barrier.side == "left" else -(w_right + barrier.offset)
        assert np.allclose(s, barrier.s, atol=1e-6)
        assert np.allclose(e, expected, atol=1e-6)
        assert np.allclose(barrier.points[:, 2], hairpin.z_at(barrier.s), atol=1e-5)
