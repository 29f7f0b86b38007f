"""Frenet coordinates: exact round trips, local search from hints, queries along s, edge points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from d2a_core.tracks import Track


def _random_road_points(track: Track, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.0, track.length, count)
    w_left, w_right = track.width_at(s)
    e = rng.uniform(-w_right, w_left)
    return s, e


@pytest.mark.parametrize("name", ["hairpin", "straightaway", "oval"])
def test_round_trip_vectorised(name: str, request: pytest.FixtureRequest) -> None:
    track: Track = request.getfixturevalue(name)
    s, e = _random_road_points(track, 5000, seed=1)
    if name == "oval":  # a full lap starts and ends at the same place: keep off that seam
        keep = (s > 10.0) & (s < track.length - 10.0)
        s, e = s[keep], e[keep]
    x, y, _ = track.from_frenet(s, e)
    s_back, e_back = track.to_frenet(x, y)  # global search, no hint
    assert np.max(np.abs(s_back - s)) < 1e-3
    assert np.max(np.abs(e_back - e)) < 1e-3


def test_round_trip_scalar_with_hints_including_arcs(hairpin: Track) -> None:
    s, e = _random_road_points(hairpin, 1500, seed=2)
    # Include the hairpin apex region densely: its inside and outside.
    s = np.concatenate([s, np.linspace(470.0, 515.0, 200)])
    e = np.concatenate([e, np.tile([-6.5, 6.5], 100)])
    on_arc = 0
    rng = np.random.default_rng(3)
    for s_true, e_true in zip(s.tolist(), e.tolist()):
        x, y, _ = hairpin.from_frenet(s_true, e_true)
        hint = s_true + float(rng.uniform(-8.0, 8.0))  # a car moves < 8 m per 0.1 s step
        s_back, e_back = hairpin.to_frenet(x, y, s_hint=hint)
        assert abs(s_back - s_true) < 1e-3 and abs(e_back - e_true) < 1e-3, (s_true, e_true, hint)
        on_arc += abs(hairpin.curvature_at(s_true)) > 1.0 / 20.0
    assert on_arc > 100


def test_e_is_the_lateral_distance_on_an_arc(hairpin: Track) -> None:
    # On the hairpin (R 18 m, right turn) the centre of curvature is on the right at distance 18 m;
    # a point at offset e is 18 + e from it (e positive = left = outside of a right turn).
    s0 = 495.0
    assert hairpin.curvature_at(s0) == pytest.approx(-1.0 / 18.0, rel=1e-6)
    cx, cy, _ = hairpin.from_frenet(s0, -18.0)
    for s in np.linspace(480.0, 505.0, 11):
        for e in (-6.0, 0.0, 6.0):
            x, y, _ = hairpin.from_frenet(float(s), e)
            assert math.hypot(x - cx, y - cy) == pytest.approx(18.0 + e, abs=3e-3)


def test_scalar_matches_vectorised(hairpin: Track) -> None:
    s, e = _random_road_points(hairpin, 200, seed=4)
    x, y, z = hairpin.from_frenet(s, e)
    for k in range(len(s)):
        px, py, pz = hairpin.from_frenet(float(s[k]), float(e[k]))
        assert (px, py, pz) == pytest.approx((x[k], y[k], z[k]), abs=1e-9)
        assert hairpin.to_frenet(px, py) == pytest.approx((s[k], e[k]), abs=1e-9)


def test_far_hint_still_converges_along_the_track(hairpin: Track) -> None:
    x, y, _ = hairpin.from_frenet(700.0, 2.0)
    for hint in (640.0, 760.0, 690.0):
        assert hairpin.to_frenet(x, y, s_hint=hint) == pytest.approx((700.0, 2.0), abs=1e-6)


def test_stale_hint_falls_back_to_a_global_search(hairpin: Track) -> None:
    # A hint on the other leg of the hairpin, or at the far end of the track (after a reset).
    for s_true, hint in ((440.0, 545.0), (3.0, 1000.0), (700.0, 0.0)):
        x, y, _ = hairpin.from_frenet(s_true, 1.0)
        assert hairpin.to_frenet(x, y, s_hint=hint) == pytest.approx((s_true, 1.0), abs=1e-6)
        s_vec, e_vec = hairpin.to_frenet(np.array([x]), np.array([y]), np.array([hint]))
        assert (s_vec[0], e_vec[0]) == pytest.approx((s_true, 1.0), abs=1e-6)


def test_beyond_the_ends_extends_straight(hairpin: Track) -> None:
    for s, e in ((-12.0, 3.0), (hairpin.length + 25.0, -4.0)):
        x, y, z = hairpin.from_frenet(s, e)
        assert hairpin.to_frenet(x, y) == pytest.approx((s, e), abs=1e-9)
        assert hairpin.to_frenet(x, y, s_hint=s) == pytest.approx((s, e), abs=1e-9)
    # Before the start: straight back along the start heading (east), so x decreases with s.
    x0, y0, _ = hairpin.from_frenet(0.0, 0.0)
    x1, y1, z1 = hairpin.from_frenet(-10.0, 0.0)
    heading = hairpin.heading_at(0.0)
    assert (x1 - x0, y1 - y0) == pytest.approx((-10.0 * math.cos(heading), -10.0 * math.sin(heading)), abs=1e-9)
    assert z1 == hairpin.z[0] and hairpin.grade_at(-10.0) == 0.0 and hairpin.curvature_at(-10.0) == 0.0
    s_vec, e_vec = hairpin.to_frenet(np.array([x1]), np.array([y1]))
    assert s_vec[0] == pytest.approx(-10.0) and e_vec[0] == pytest.approx(0.0, abs=1e-9)


def test_queries_along_s(hairpin: Track) -> None:
    s = np.linspace(0.0, hairpin.length, 777)
    # heading_at agrees with the direction of the centreline (finite differences of from_frenet).
    x, y, z = hairpin.from_frenet(s, np.zeros_like(s))
    step = 0.05
    xa, ya, za = hairpin.from_frenet(s + step, np.zeros_like(s))
    direction = np.arctan2(ya - y, xa - x)
    # Between samples the centreline is the chord, whose direction differs from the interpolated
    # heading by at most half the heading change over one sample.
    tolerance = 0.5 * hairpin.spacing * np.max(np.abs(hairpin.curvature)) + 1e-6
    assert np.max(np.abs(np.angle(np.exp(1j * (direction - hairpin.heading_at(s + step / 2)))))) < tolerance
    assert np.allclose((za - z) / step, hairpin.grade_at(s + step / 2), atol=2e-3)
    # Scalars and arrays give the same answers.
    for q in (0.0, 123.4, 495.0, hairpin.length):
        assert hairpin.heading_at(q) == pytest.approx(float(hairpin.heading_at(np.array([q]))[0]))
        assert hairpin.grade_at(q) == pytest.approx(float(hairpin.grade_at(np.array([q]))[0]))
        w_left, w_right = hairpin.width_at(q)
        assert w_left > 0 and w_right > 0
    assert hairpin.width_at(500.0) == pytest.approx((7.0, 7.0))
    assert hairpin.width_at(100.0) == pytest.approx((6.0, 6.0))


def test_edge_points_are_the_road_edges_ahead(hairpin: Track) -> None:
    offsets = np.array([0.0, 5.0, 10.0, 20.0, 40.0, 80.0])
    s0 = 450.0
    points = hairpin.edge_points(s0, offsets)
    assert points.shape == (2, len(offsets), 3)
    s_left, e_left = hairpin.to_frenet(points[0, :, 0], points[0, :, 1])
    s_right, e_right = hairpin.to_frenet(points[1, :, 0], points[1, :, 1])
    w_left, w_right = hairpin.width_at(s0 + offsets)
    assert np.allclose(s_left, s0 + offsets, atol=1e-2) and np.allclose(s_right, s0 + offsets, atol=1e-2)
    assert np.allclose(e_left, w_left, atol=1e-2) and np.allclose(e_right, -w_right, atol=1e-2)
    assert np.allclose(points[:, :, 2], hairpin.z_at(s0 + offsets), atol=1e-6)


def test_edge_points_beyond_the_end_continue_straight(straightaway: Track) -> None:
    s0 = straightaway.length - 5.0
    points = straightaway.edge_points(s0, [0, 10, 20, 30])  # plain ints work too
    assert np.all(np.isfinite(points))
    # The straightaway runs east: the edges continue east at their end widths.
    assert np.allclose(points[0, :, 0], s0 + np.array([0, 10, 20, 30]))
    assert np.allclose(points[0, :, 1], 6.5) and np.allclose(points[1, :, 1], -6.5)
