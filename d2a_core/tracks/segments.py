"""Plan-view centreline of a spec's segments: exact heading, curvature and integrated positions.

Every segment kind is a piece whose curvature is linear in s (straight: 0 -> 0, arc: k -> k,
transition: previous end curvature -> target), so the heading is a quadratic in s and is exact.
Positions are the integral of (cos, sin) of the heading, done with Gauss-Legendre quadrature
between consecutive samples (errors ~1e-12 m for the sample spacings used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from d2a_core.tracks.spec import Segment, StartPose

_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(8)


@dataclass(frozen=True)
class CurvaturePiece:
    """One segment: curvature goes linearly from `k_start` to `k_end` over `length`."""

    index: int
    s_start: float
    length: float
    k_start: float
    k_end: float
    heading_start: float

    def heading(self, u: np.ndarray) -> np.ndarray:
        """Heading (rad) at local distance u in [0, length]."""
        return self.heading_start + self.k_start * u + (self.k_end - self.k_start) * u * u / (2.0 * self.length)

    def curvature(self, u: np.ndarray) -> np.ndarray:
        return self.k_start + (self.k_end - self.k_start) * (u / self.length)

    @property
    def heading_end(self) -> float:
        return float(self.heading(np.array(self.length)))


def curvature_pieces(segments: list[Segment], start_pose: StartPose) -> list[CurvaturePiece]:
    """Turn spec segments into curvature pieces with continuous heading."""
    pieces: list[CurvaturePiece] = []
    s = 0.0
    heading = math.radians(start_pose.heading_deg)
    k_previous = 0.0
    for index, segment in enumerate(segments):
        if segment.straight is not None:
            k0 = k1 = 0.0
        elif segment.arc is not None:
            k0 = k1 = segment.arc.curvature
        else:
            assert segment.transition is not None
            k0, k1 = k_previous, segment.transition.end_curvature
        piece = CurvaturePiece(index, s, segment.length, k0, k1, heading)
        pieces.append(piece)
        s += piece.length
        heading = piece.heading_end
        k_previous = k1
    return pieces


def _integrate_direction(piece: CurvaturePiece, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Integrals of cos and sin of the heading over [a_i, b_i] (local distances)."""
    half = 0.5 * (b - a)
    mid = 0.5 * (b + a)
    u = mid[:, None] + half[:, None] * _GAUSS_NODES[None, :]
    theta = piece.heading(u)
    return (half * (np.cos(theta) @ _GAUSS_WEIGHTS), half * (np.sin(theta) @ _GAUSS_WEIGHTS))


@dataclass
class PlanCentreline:
    """Samples of the plan-view centreline and which segment each sample lies on."""

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    curvature: np.ndarray
    segment_index: np.ndarray


def sample_centreline(pieces: list[CurvaturePiece], start_pose: StartPose, spacing: float) -> PlanCentreline:
    """Sample the centreline at uniform s (spacing adjusted slightly so the last sample is the end)."""
    total = pieces[-1].s_start + pieces[-1].length
    n = max(2, int(round(total / spacing)) + 1)
    s = np.linspace(0.0, total, n)
    x = np.empty(n)
    y = np.empty(n)
    heading = np.empty(n)
    curvature = np.empty(n)
    segment_index = np.empty(n, dtype=np.int64)
    px, py = start_pose.x, start_pose.y
    starts = np.array([p.s_start for p in pieces])
    owner = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(pieces) - 1)
    for piece in pieces:
        mask = owner == piece.index
        u = np.clip(s[mask] - piece.s_start, 0.0, piece.length)
        # Integrate from the piece start through each sample, then on to the piece end.
        stops = np.concatenate([u, [piece.length]])
        begins = np.concatenate([[0.0], stops[:-1]])
        dx, dy = _integrate_direction(piece, begins, stops)
        cx, cy = px + np.cumsum(dx), py + np.cumsum(dy)
        x[mask], y[mask] = cx[:-1], cy[:-1]
        heading[mask] = piece.heading(u)
        curvature[mask] = piece.curvature(u)
        segment_index[mask] = piece.index
        px, py = cx[-1], cy[-1]
    # The last sample is the end of the last piece, which the loop above assigned with u = length.
    return PlanCentreline(s, x, y, heading, curvature, segment_index)
