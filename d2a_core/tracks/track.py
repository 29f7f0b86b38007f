"""The compiled track: uniform centreline samples, barriers, finish line, start grid and Frenet queries.

Conventions: `s` is the horizontal distance along the centreline (0 at the first sample), `e` the
lateral offset (positive to the left of travel). Headings are radians counter-clockwise from +x and
are stored unwrapped (continuous along the track), so differences are meaningful without wrapping.
Beyond the ends the centreline continues straight along the end heading; width, elevation and
heading are held at their end values there, curvature and grade are 0.

Every query accepts a Python/numpy scalar (fast path, returns floats) or arrays (returns arrays).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from d2a_core.tracks.config import FrenetSearchConfig
from d2a_core.tracks.frenet import CentrelineFrame

Side = Literal["left", "right"]

SAMPLE_FIELDS = ("s", "x", "y", "z", "heading", "curvature", "w_left", "w_right", "grade")
_SCALAR_TYPES = (float, int, np.floating, np.integer)
# Relative tolerance on the uniformity of s samples.
_UNIFORM_TOLERANCE = 1e-9


@dataclass(frozen=True)
class GridSlot:
    """A start position in Frenet coordinates (car centre)."""

    s: float
    e: float


@dataclass(frozen=True)
class StartGrid:
    ego: GridSlot
    opponent: GridSlot


@dataclass
class Barrier:
    """A wall along one side: `points` (m, 3) is the base of its road-facing side at centreline `s` (m,)."""

    side: Side
    kind: str
    height: float
    offset: float
    s: np.ndarray
    points: np.ndarray
    e: np.ndarray = field(repr=False)

    @property
    def s_start(self) -> float:
        return float(self.s[0])

    @property
    def s_end(self) -> float:
        return float(self.s[-1])


def _as_samples(name: str, value: Any, n: int | None) -> np.ndarray:
    """A private, read-only float64 copy (the fast paths cache these values as lists)."""
    array = np.array(value, dtype=np.float64, copy=True)
    if array.ndim != 1 or (n is not None and len(array) != n):
        raise ValueError(f"track field {name} must be a 1-D array of {n} samples, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"track field {name} contains non-finite values")
    array.setflags(write=False)
    return array


class Track:
    """A compiled track. Build it with `compile_spec`, `load_centreline_csv` or `track_file.load_track`.

    Args:
        name: track name.
        s, x, y, z, heading, curvature, w_left, w_right, grade: per-sample arrays (n >= 2); s must be
            uniform from 0 (`s[i] = i * spacing`), widths > 0.
        barriers: walls along the road.
        finish_s: s of the finish line, in (0, length].
        start_grid: ego and opponent start slots.
        source: JSON-able description of where the track came from (stored in the artifact).
        frenet_config: search tunables for `to_frenet`.
    """

    def __init__(
        self,
        name: str,
        *,
        s: np.ndarray,
        x: np.ndarray,
        y: np.ndarray,
        z: np.ndarray,
        heading: np.ndarray,
        curvature: np.ndarray,
        w_left: np.ndarray,
        w_right: np.ndarray,
        grade: np.ndarray,
        barriers: Sequence[Barrier],
        finish_s: float,
        start_grid: StartGrid,
        source: dict[str, Any] | None = None,
        frenet_config: FrenetSearchConfig | None = None,
    ) -> None:
        self.name = name
        self.s = _as_samples("s", s, None)
        n = len(self.s)
        if n < 2:
            raise ValueError("a track needs at least 2 samples")
        self.x = _as_samples("x", x, n)
        self.y = _as_samples("y", y, n)
        self.z = _as_samples("z", z, n)
        self.heading = _as_samples("heading", heading, n)
        self.curvature = _as_samples("curvature", curvature, n)
        self.w_left = _as_samples("w_left", w_left, n)
        self.w_right = _as_samples("w_right", w_right, n)
        self.grade = _as_samples("grade", grade, n)
        self.spacing = float(self.s[-1]) / (n - 1)
        if self.s[0] != 0.0 or not self.spacing > 0:
            raise ValueError("track s must start at 0 and increase")
        if np.max(np.abs(self.s - np.arange(n) * self.spacing)) > _UNIFORM_TOLERANCE * max(1.0, float(self.s[-1])):
            raise ValueError("track s samples must be uniformly spaced")
        if np.any(self.w_left <= 0) or np.any(self.w_right <= 0):
            raise ValueError("track half widths must be > 0")
        if not 0.0 < finish_s <= self.s[-1] + 1e-9:
            raise ValueError(f"finish_s {finish_s} must lie in (0, {self.s[-1]}]")
        self.barriers = list(barriers)
        self.finish_s = float(finish_s)
        self.start_grid = start_grid
        self.source = dict(source or {})
        self._frame = CentrelineFrame(self.spacing, self.x, self.y, self.heading, frenet_config)
        self._inv_spacing = 1.0 / self.spacing
        self._n = n
        self._lz, self._lheading = self.z.tolist(), self.heading.tolist()
        self._lcurvature, self._lgrade = self.curvature.tolist(), self.grade.tolist()
        self._lw_left, self._lw_right = self.w_left.tolist(), self.w_right.tolist()
        left, right = self.edges()
        self._edge_table = np.concatenate([left, right], axis=1)  # (n, 6): left xyz, right xyz
        self._edge_steps = np.diff(self._edge_table, axis=0)

    # ----- summary ----------------------------------------------------------------------------------

    @property
    def length(self) -> float:
        """Length of the centreline (s of the last sample), metres."""
        return float(self.s[-1])

    @property
    def n_samples(self) -> int:
        return self._n

    @property
    def elevation_range(self) -> float:
        """max(z) - min(z), metres."""
        return float(self.z.max() - self.z.min())

    # ----- per-s lookups ----------------------------------------------------------------------------

    def _lerp(self, values: list[float], s: float, outside: float | None) -> float:
        """Linear interpolation in a per-sample list; beyond the ends `outside` (or the end value)."""
        u = s * self._inv_spacing
        if u <= 0.0 or u >= self._n - 1:
            if outside is not None and (u < 0.0 or u > self._n - 1):
                return outside
            return values[0] if u <= 0.0 else values[-1]
        i = int(u)
        a = values[i]
        return a + (u - i) * (values[i + 1] - a)

    def _lerp_array(self, values: np.ndarray, s: Any, outside: float | None) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        result = np.interp(s, self.s, values)
        if outside is not None:
            result = np.where((s < 0.0) | (s > self.s[-1]), outside, result)
        return result

    def heading_at(self, s: Any) -> Any:
        """Centreline heading (rad, unwrapped) at s."""
        if isinstance(s, _SCALAR_TYPES):
            return self._lerp(self._lheading, float(s), None)
        return self._lerp_array(self.heading, s, None)

    def curvature_at(self, s: Any) -> Any:
        """Signed curvature (1/m, positive left) at s; 0 beyond the ends."""
        if isinstance(s, _SCALAR_TYPES):
            return self._lerp(self._lcurvature, float(s), 0.0)
        return self._lerp_array(self.curvature, s, 0.0)

    def grade_at(self, s: Any) -> Any:
        """Road grade dz/ds (rise over horizontal run) at s; 0 beyond the ends."""
        if isinstance(s, _SCALAR_TYPES):
            return self._lerp(self._lgrade, float(s), 0.0)
        return self._lerp_array(self.grade, s, 0.0)

    def z_at(self, s: Any) -> Any:
        """Centreline elevation (m) at s (the road has no camber: z does not depend on e)."""
        if isinstance(s, _SCALAR_TYPES):
            return self._lerp(self._lz, float(s), None)
        return self._lerp_array(self.z, s, None)

    def width_at(self, s: Any) -> tuple[Any, Any]:
        """(w_left, w_right): half widths from the centreline to the left and right road edges."""
        if isinstance(s, _SCALAR_TYPES):
            s = float(s)
            return self._lerp(self._lw_left, s, None), self._lerp(self._lw_right, s, None)
        return self._lerp_array(self.w_left, s, None), self._lerp_array(self.w_right, s, None)

    # ----- Frenet -----------------------------------------------------------------------------------

    def to_frenet(self, x: Any, y: Any, s_hint: Any = None) -> tuple[Any, Any]:
        """(s, e) of world point(s). With `s_hint` (e.g. last step's s) the search is local: a few
        exact projections near the hint, microseconds for a scalar. Without it the nearest sample
        over the whole track seeds the search. Arrays are handled by `to_frenet_array`."""
        if isinstance(x, _SCALAR_TYPES) and isinstance(y, _SCALAR_TYPES):
            return self._frame.project(float(x), float(y), None if s_hint is None else float(s_hint))
        return self.to_frenet_array(x, y, s_hint)

    def to_frenet_array(self, x: Any, y: Any, s_hint: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised `to_frenet`: arrays of any (equal) shape; returns arrays of that shape."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        hint = None if s_hint is None else np.broadcast_to(np.asarray(s_hint, dtype=float), x.shape).ravel()
        s, e = self._frame.project_array(x.ravel(), y.ravel(), hint)
        return s.reshape(x.shape), e.reshape(x.shape)

    def from_frenet(self, s: Any, e: Any) -> tuple[Any, Any, Any]:
        """World (x, y, z) of Frenet point(s); the exact inverse of `to_frenet` on the road."""
        if isinstance(s, _SCALAR_TYPES) and isinstance(e, _SCALAR_TYPES):
            s = float(s)
            px, py = self._frame.point(s, float(e))
            return px, py, self._lerp(self._lz, s, None)
        s, e = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(e, dtype=float))
        px, py = self._frame.point_array(s, e)
        return px, py, self._lerp_array(self.z, s, None)

    def edge_points(self, s: float, lookahead_offsets: Sequence[float] | np.ndarray) -> np.ndarray:
        """World (x, y, z) of the left and right road edges at s + each offset: shape (2, K, 3),
        index 0 the left edge, 1 the right edge.

        Edge points are linearly interpolated between the sampled edges (within ~w * dheading^2 / 8,
        under a millimetre, of `from_frenet(s, w)`), and extrapolated along the end chords beyond the
        ends, which keeps this cheap enough for every control step (~7 us for 10 offsets).
        """
        if type(lookahead_offsets) is not np.ndarray or lookahead_offsets.ndim != 1:
            lookahead_offsets = np.asarray(lookahead_offsets, dtype=float).ravel()
        u = (float(s) + lookahead_offsets) * self._inv_spacing
        i = u.astype(np.int64)
        if i.min() < 0 or i.max() > self._n - 2:
            np.clip(i, 0, self._n - 2, out=i)
        points = self._edge_table[i]
        points += (u - i)[:, None] * self._edge_steps[i]
        return points.reshape(-1, 2, 3).transpose(1, 0, 2)

    # ----- geometry for the world and logs ------------------------------------------------------------

    def centreline_points(self) -> np.ndarray:
        """(n, 3) centreline samples."""
        return np.stack([self.x, self.y, self.z], axis=1)

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) edge polylines, (n, 3) each, point i of both at sample i."""
        nx, ny = -np.sin(self.heading), np.cos(self.heading)
        left = np.stack([self.x + self.w_left * nx, self.y + self.w_left * ny, self.z], axis=1)
        right = np.stack([self.x - self.w_right * nx, self.y - self.w_right * ny, self.z], axis=1)
        return left, right

    def finish_line_points(self) -> np.ndarray:
        """(2, 3): the finish line's left and right edge points."""
        w_left, w_right = self.width_at(self.finish_s)
        px, py, pz = self.from_frenet(np.array([self.finish_s, self.finish_s]), np.array([w_left, -w_right]))
        return np.stack([px, py, pz], axis=1)

    def barrier_polylines(self) -> list[tuple[np.ndarray, float]]:
        """[(base points (m, 3), height)] per barrier, as `RaceWorld` and `StaticScene` take them."""
        return [(barrier.points, barrier.height) for barrier in self.barriers]

    # ----- persistence ------------------------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        """JSON-able description stored beside the arrays in the track file."""
        return {
            "name": self.name,
            "length_m": self.length,
            "spacing_m": self.spacing,
            "finish_s": self.finish_s,
            "elevation_range_m": self.elevation_range,
            "start_grid": {
                role: {"s": slot.s, "e": slot.e}
                for role, slot in (("ego", self.start_grid.ego), ("opponent", self.start_grid.opponent))
            },
            "barriers": [
                {"side": b.side, "type": b.kind, "height": b.height, "offset": b.offset,
                 "s_start": b.s_start, "s_end": b.s_end}
                for b in self.barriers
            ],
            "source": self.source,
        }

    def __repr__(self) -> str:
        return (
            f"Track({self.name!r}, length={self.length:.1f} m, finish_s={self.finish_s:.1f}, "
            f"samples={self._n}, barriers={len(self.barriers)}, elevation_range={self.elevation_range:.1f} m)"
        )


def heading_wrap(angle: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi
