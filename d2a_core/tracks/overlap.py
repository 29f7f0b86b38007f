"""Does a road (or a barrier) cross itself? Exact segment-intersection tests on edge polylines.

The road's outline is one closed ring: the left edge forward, the end cap, the right edge
backward, the start cap. If the edges do not fold (checked separately from curvature) the road
overlaps itself exactly when two non-adjacent ring segments intersect. Barriers must not cross
any part of that ring except the stretch of their own edge they run beside, nor stand on the road.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from d2a_core.tracks.frenet import CentrelineFrame

_BLOCK = 256
# A barrier with zero offset sits exactly on the edge; only points clearly inside count as on the road.
_ON_ROAD_TOLERANCE_M = 1e-6


@dataclass(frozen=True)
class Crossing:
    """Two polyline pieces that intersect: where (s) and on what (`left`, `right`, `cap`, `barrier[k]`)."""

    what_a: str
    s_a: float
    what_b: str
    s_b: float


def _cross(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    return ax * by - ay * bx


def _intersect_pairs(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Elementwise: does segment p0[k]-p1[k] intersect (or touch) segment q0[k]-q1[k]?"""
    da = p1 - p0
    db = q1 - q0
    o1 = _cross(da[:, 0], da[:, 1], q0[:, 0] - p0[:, 0], q0[:, 1] - p0[:, 1])
    o2 = _cross(da[:, 0], da[:, 1], q1[:, 0] - p0[:, 0], q1[:, 1] - p0[:, 1])
    o3 = _cross(db[:, 0], db[:, 1], p0[:, 0] - q0[:, 0], p0[:, 1] - q0[:, 1])
    o4 = _cross(db[:, 0], db[:, 1], p1[:, 0] - q0[:, 0], p1[:, 1] - q0[:, 1])
    # Bounding boxes must overlap too, so collinear but disjoint segments do not count.
    boxes = (
        (np.minimum(p0[:, 0], p1[:, 0]) <= np.maximum(q0[:, 0], q1[:, 0]))
        & (np.minimum(q0[:, 0], q1[:, 0]) <= np.maximum(p0[:, 0], p1[:, 0]))
        & (np.minimum(p0[:, 1], p1[:, 1]) <= np.maximum(q0[:, 1], q1[:, 1]))
        & (np.minimum(q0[:, 1], q1[:, 1]) <= np.maximum(p0[:, 1], p1[:, 1]))
    )
    return (o1 * o2 <= 0.0) & (o3 * o4 <= 0.0) & boxes


def _intersections(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray, rows: slice) -> np.ndarray:
    """Boolean matrix: segment p[rows] intersects (or touches) segment q[:].

    Only pairs whose midpoints are closer than their half lengths summed can meet, which prunes
    almost every pair before the exact orientation test.
    """
    a0, a1 = p0[rows], p1[rows]
    mid_a, mid_b = 0.5 * (a0 + a1), 0.5 * (q0 + q1)
    half_a = 0.5 * np.hypot(*(a1 - a0).T)
    half_b = 0.5 * np.hypot(*(q1 - q0).T)
    d2 = (mid_a[:, None, 0] - mid_b[None, :, 0]) ** 2 + (mid_a[:, None, 1] - mid_b[None, :, 1]) ** 2
    near = d2 <= (half_a[:, None] + half_b[None, :]) ** 2 * (1.0 + 1e-9) + 1e-12
    hits = np.zeros(near.shape, dtype=bool)
    i, j = np.nonzero(near)
    if len(i):
        hits[i, j] = _intersect_pairs(a0[i], a1[i], q0[j], q1[j])
    return hits


def _subsample(n: int, step: int) -> np.ndarray:
    index = np.arange(0, n, step)
    return index if index[-1] == n - 1 else np.append(index, n - 1)


@dataclass
class _Ring:
    start: np.ndarray  # (m, 2) segment start points
    end: np.ndarray
    s: np.ndarray  # (m,) s at each segment's middle
    side: list[str]  # per segment: left, right or cap


def _road_ring(s: np.ndarray, left: np.ndarray, right: np.ndarray, step: int) -> _Ring:
    index = _subsample(len(s), step)
    ring = np.concatenate([left[index], right[index][::-1]])
    ring_s = np.concatenate([s[index], s[index][::-1]])
    start, end = ring, np.roll(ring, -1, axis=0)
    mid_s = 0.5 * (ring_s + np.roll(ring_s, -1))
    k = len(index)
    side = ["left"] * (k - 1) + ["cap"] + ["right"] * (k - 1) + ["cap"]
    return _Ring(start, end, mid_s, side)


def find_road_overlap(s: np.ndarray, left: np.ndarray, right: np.ndarray, step: int = 1) -> Crossing | None:
    """First crossing of two non-adjacent pieces of the road outline, or None.

    Args:
        s: (n,) sample positions; left, right: (n, 2+) edge points at those samples.
        step: use every `step`-th sample (the ends are always kept).
    """
    ring = _road_ring(s, left[:, :2], right[:, :2], step)
    m = len(ring.start)
    index = np.arange(m)
    for first in range(0, m, _BLOCK):
        rows = slice(first, min(first + _BLOCK, m))
        hits = _intersections(ring.start, ring.end, ring.start, ring.end, rows)
        i = index[rows, None]
        gap = np.abs(i - index[None, :])
        adjacent = (gap <= 1) | (gap == m - 1)
        hits &= ~adjacent & (index[None, :] > i)
        if hits.any():
            a, b = np.argwhere(hits)[0]
            a += first
            return Crossing(ring.side[a], float(ring.s[a]), ring.side[b], float(ring.s[b]))
    return None


def find_barrier_crossing(
    s: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    barriers: list[tuple[str, np.ndarray, np.ndarray]],
    step: int = 1,
) -> Crossing | None:
    """First place a barrier crosses the road outline away from the edge it runs beside, or None.

    Args:
        barriers: (side, s (m,), points (m, 2+)) per barrier.
    """
    ring = _road_ring(s, left[:, :2], right[:, :2], step)
    ring_side = np.array(ring.side)
    for k, (side, barrier_s, points) in enumerate(barriers):
        index = _subsample(len(barrier_s), step)
        start, end = points[index][:-1, :2], points[index][1:, :2]
        mid_s = 0.5 * (barrier_s[index][:-1] + barrier_s[index][1:])
        hits = _intersections(start, end, ring.start, ring.end, slice(None))
        # Its own edge (same side, within its s range plus one ring piece) it may touch.
        reach = step * float(s[1] - s[0]) + 1e-9
        own = (ring_side == side) & (ring.s >= barrier_s[0] - reach) & (ring.s <= barrier_s[-1] + reach)
        hits &= ~own[None, :]
        if hits.any():
            a, b = np.argwhere(hits)[0]
            return Crossing(f"barrier[{k}]", float(mid_s[a]), ring.side[b], float(ring.s[b]))
    return None


def find_barrier_on_road(
    frame: CentrelineFrame,
    s: np.ndarray,
    w_left: np.ndarray,
    w_right: np.ndarray,
    barriers: list[tuple[np.ndarray, np.ndarray]],
    step: int = 1,
) -> Crossing | None:
    """First barrier point that lies on the road surface (of any part of the track), or None.

    Catches a barrier that runs inside another part of the road without crossing its edges.

    Args:
        frame: the track's Frenet frame; s, w_left, w_right: per-sample arrays.
        barriers: (s (m,), points (m, 2+)) per barrier.
    """
    for k, (barrier_s, points) in enumerate(barriers):
        index = _subsample(len(barrier_s), step)
        on_s, on_e = frame.project_array(points[index, 0], points[index, 1])
        inside = (
            (on_s >= s[0])
            & (on_s <= s[-1])
            & (on_e < np.interp(on_s, s, w_left) - _ON_ROAD_TOLERANCE_M)
            & (on_e > -np.interp(on_s, s, w_right) + _ON_ROAD_TOLERANCE_M)
        )
        if inside.any():
            a = int(np.argmax(inside))
            return Crossing(f"barrier[{k}]", float(barrier_s[index][a]), "the road", float(on_s[a]))
    return None
