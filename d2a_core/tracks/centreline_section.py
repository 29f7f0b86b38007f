"""Turn a racing-line CSV into a `Track`: resample, smooth, cut a section, sample uniformly.

The raw points are resampled by chord length onto a fine uniform grid, smoothed with a Gaussian
along the lap (wrapping around for a closed lap, odd reflection at the ends of an open one, which
keeps straight ends straight), and differentiated there: heading from the tangent, curvature from
(x' y'' - y' x'') / |x'|^3, grade from dz/ds. Without smoothing, curvature from racing-line files
(points every metre, rounded to centimetres) is mostly noise.

`start_m` is measured along the file's points (chord length from the first point), so the cut
starts where a user reading the file expects; `length_m` is the length of the resulting
centreline. A closed lap wraps: a section may run past the last point into the first.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from d2a_core.errors import SpecError
from d2a_core.tracks.centreline_csv import RawCentreline, read_centreline_csv
from d2a_core.tracks.config import CentrelineCsvConfig, FrenetSearchConfig, TrackGeometryConfig
from d2a_core.tracks.limits import MAX_GRADE, MAX_SAMPLES
from d2a_core.tracks.overlap import find_road_overlap
from d2a_core.tracks.track import GridSlot, StartGrid, Track

# Lengths within this of a limit count as equal to it (float noise in user-given numbers).
_LENGTH_TOLERANCE_M = 1e-6


def _gaussian_kernel(sigma_samples: float) -> np.ndarray:
    if sigma_samples <= 0:
        return np.ones(1)
    half = int(math.ceil(4.0 * sigma_samples))
    offsets = np.arange(-half, half + 1)
    kernel = np.exp(-0.5 * (offsets / sigma_samples) ** 2)
    return kernel / kernel.sum()


def _smooth(values: np.ndarray, kernel: np.ndarray, closed: bool) -> np.ndarray:
    """Convolve a 1-D signal with a symmetric kernel, wrapping (closed) or odd-reflecting (open)."""
    half = len(kernel) // 2
    if half == 0:
        return values.copy()
    if closed:
        reps = half // len(values) + 1
        padded = np.concatenate([np.tile(values, reps)[-half:], values, np.tile(values, reps)[:half]])
    else:
        pad = min(half, len(values) - 1)
        # Odd reflection about each end point: v(-k) = 2 v(0) - v(k) keeps linear trends.
        head = 2.0 * values[0] - values[1 : pad + 1][::-1]
        tail = 2.0 * values[-1] - values[-pad - 1 : -1][::-1]
        edge_head = np.full(half - pad, head[0]) if half > pad else np.empty(0)
        edge_tail = np.full(half - pad, tail[-1]) if half > pad else np.empty(0)
        padded = np.concatenate([edge_head, head, values, tail, edge_tail])
    return np.convolve(padded, kernel, mode="valid")


def _derivative(values: np.ndarray, step: float, closed: bool) -> np.ndarray:
    if closed:
        return (np.roll(values, -1) - np.roll(values, 1)) / (2.0 * step)
    return np.gradient(values, step, edge_order=2)


class _FineLap:
    """The smoothed centreline on a fine grid: chord parameter u, arc length s and channels."""

    def __init__(self, raw: RawCentreline, config: CentrelineCsvConfig) -> None:
        self.closed = raw.closed
        self.lines = raw.lines
        channels = [raw.x, raw.y, raw.w_left, raw.w_right, raw.z if raw.z is not None else np.zeros_like(raw.x)]
        if raw.closed:  # close the polygon so interpolation covers the last-to-first step
            channels = [np.append(c, c[0]) for c in channels]
        u_raw = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(channels[0]), np.diff(channels[1])))])
        self.raw_length = float(u_raw[-1])
        count = max(int(math.ceil(self.raw_length / config.fine_spacing_m)), 8)
        if raw.closed:
            self.u = np.arange(count) * (self.raw_length / count)
        else:
            self.u = np.linspace(0.0, self.raw_length, count + 1)
        step = float(self.u[1] - self.u[0])
        kernel = _gaussian_kernel(config.smoothing_sigma_m / step)
        x, y, w_left, w_right, z = (_smooth(np.interp(self.u, u_raw, c), kernel, raw.closed) for c in channels)
        dx, dy, dz = (_derivative(c, step, raw.closed) for c in (x, y, z))
        ddx, ddy = _derivative(dx, step, raw.closed), _derivative(dy, step, raw.closed)
        speed = np.hypot(dx, dy)  # ds/du, close to 1
        increments = 0.5 * (speed[1:] + speed[:-1]) * step
        self.s = np.concatenate([[0.0], np.cumsum(increments)])
        # A closed lap's length includes the step from the last grid point back to the first.
        self.length = float(self.s[-1] + (0.5 * (speed[-1] + speed[0]) * step if raw.closed else 0.0))
        self.x, self.y, self.z = x, y, z
        self.w_left, self.w_right = w_left, w_right
        self.cos_heading, self.sin_heading = dx / speed, dy / speed
        self.curvature = (dx * ddy - dy * ddx) / speed**3
        self.grade = dz / speed

    def s_of_u(self, u: float) -> float:
        """Smoothed arc length at chord parameter u (u in [0, raw_length])."""
        if self.closed:
            return float(np.interp(u, np.append(self.u, self.raw_length), np.append(self.s, self.length)))
        return float(np.interp(u, self.u, self.s))

    def sample(self, s: np.ndarray, values: np.ndarray) -> np.ndarray:
        if self.closed:
            return np.interp(np.mod(s, self.length), self.s, values, period=self.length)
        return np.interp(s, self.s, values)


def _check_cut(lap: _FineLap, start_m: float, length_m: float | None, source: str) -> tuple[float, float]:
    """Validate the requested cut; returns (start s on the smoothed curve, length)."""
    if not (math.isfinite(start_m) and 0.0 <= start_m < lap.raw_length):
        raise SpecError(f"{source}: start: must be in [0, {lap.raw_length:.3f}) m along the points (got {start_m})")
    start_s = lap.s_of_u(start_m)
    available = lap.length if lap.closed else lap.length - start_s
    if length_m is None:
        return start_s, available
    if not (math.isfinite(length_m) and length_m > 0):
        raise SpecError(f"{source}: length: must be > 0 (got {length_m})")
    if length_m > available + _LENGTH_TOLERANCE_M:
        what = "the lap length" if lap.closed else f"what remains after start {start_m} m"
        raise SpecError(f"{source}: length: {length_m} m is beyond {what} ({available:.3f} m)")
    return start_s, min(length_m, available)


def load_centreline_csv(
    path: str | Path,
    start_m: float | None = None,
    length_m: float | None = None,
    config: CentrelineCsvConfig | None = None,
    name: str | None = None,
    frenet_config: FrenetSearchConfig | None = None,
    geometry: TrackGeometryConfig | None = None,
) -> Track:
    """Build a `Track` from a racing-line CSV, optionally a section `start_m .. start_m + length_m`.

    Args:
        path: the CSV file.
        start_m: where the section starts, metres along the file's points (default 0).
        length_m: centreline length of the section (default: to the end, or one full lap).
        config: smoothing, sampling and start-grid tunables.
        name: track name (default: the file's stem).
        frenet_config: search tunables handed to the track.

    The track has no barriers (the format has none); its finish line is at its end.

    Raises:
        SpecError: a bad file (see `read_centreline_csv`), a cut outside the lap, or a section
            too short for the start grid.
    """
    config = config or CentrelineCsvConfig()
    source = str(path)
    raw = read_centreline_csv(path, config)
    raw_length = float(np.sum(np.hypot(np.diff(raw.x), np.diff(raw.y))))
    if raw_length / config.fine_spacing_m > MAX_SAMPLES:  # checked before the grid is allocated
        raise SpecError(f"{source}: the line is {raw_length:.0f} m long: at tracks.csv.fine_spacing_m="
                        f"{config.fine_spacing_m} that is more than {MAX_SAMPLES} samples")
    lap = _FineLap(raw, config)
    start_s, length = _check_cut(lap, 0.0 if start_m is None else float(start_m), length_m, source)
    if length / config.sample_spacing_m > MAX_SAMPLES:
        raise SpecError(f"{source}: the section is {length:.0f} m long: at tracks.csv.sample_spacing_m="
                        f"{config.sample_spacing_m} that is more than {MAX_SAMPLES} samples")
    n = max(2, int(round(length / config.sample_spacing_m)) + 1)
    s = np.linspace(0.0, length, n)
    on_lap = start_s + s
    heading = np.unwrap(np.arctan2(lap.sample(on_lap, lap.sin_heading), lap.sample(on_lap, lap.cos_heading)))
    w_left, w_right = lap.sample(on_lap, lap.w_left), lap.sample(on_lap, lap.w_right)

    ego_s = config.ego_start_s_m
    opponent_s = ego_s + config.opponent_gap_m
    if opponent_s >= length:
        raise SpecError(
            f"{source}: length: the section ({length:.1f} m) is too short for the start grid "
            f"(opponent starts at s={opponent_s:.1f} m)"
        )
    track = Track(
        name or Path(path).stem,
        s=s,
        x=lap.sample(on_lap, lap.x),
        y=lap.sample(on_lap, lap.y),
        z=lap.sample(on_lap, lap.z),
        heading=heading,
        curvature=lap.sample(on_lap, lap.curvature),
        w_left=w_left,
        w_right=w_right,
        grade=lap.sample(on_lap, lap.grade),
        barriers=[],
        finish_s=length,
        start_grid=StartGrid(
            ego=GridSlot(ego_s, config.ego_start_e_m), opponent=GridSlot(opponent_s, config.opponent_start_e_m)
        ),
        source={
            "kind": "csv",
            "file": Path(path).name,
            "start_m": 0.0 if start_m is None else float(start_m),
            "length_m": length,
            "closed_lap": lap.closed,
            "lap_length_m": lap.length,
            "smoothing_sigma_m": config.smoothing_sigma_m,
        },
        frenet_config=frenet_config,
    )
    for role, slot in (("ego", track.start_grid.ego), ("opponent", track.start_grid.opponent)):
        w_l, w_r = track.width_at(slot.s)
        if not -w_r < slot.e < w_l:
            raise SpecError(f"{source}: start grid: the {role}'s lateral offset {slot.e} m is off the road at s={slot.s}")
    _check_section_geometry(track, lap, source, geometry or TrackGeometryConfig())
    return track


def _line_of(raw_lines: np.ndarray, lap: _FineLap, s_on_lap: float) -> int:
    """The CSV line nearest to a position on the lap (for error messages)."""
    fraction = (s_on_lap % lap.length) / lap.length if lap.length > 0 else 0.0
    return int(raw_lines[min(int(fraction * len(raw_lines)), len(raw_lines) - 1)])


def _check_section_geometry(track: Track, lap: _FineLap, source: str, geometry: TrackGeometryConfig) -> None:
    """The checks a compiled spec gets: no impossible climb, no road that overlaps itself."""
    start = float(track.source["start_m"])
    steep = np.flatnonzero(np.abs(track.grade) > MAX_GRADE)
    if len(steep):
        k = int(steep[np.argmax(np.abs(track.grade[steep]))])
        raise SpecError(f"{source}:{_line_of(lap.lines, lap, start + track.s[k])}: z_m: the road climbs "
                        f"{abs(track.grade[k]):.0%} at s={track.s[k]:.1f} m, steeper than {MAX_GRADE:.0%}")
    s = track.s
    # a full closed lap ends where it starts: leave out a road width at the end so that the two
    # ends, which meet by design, do not count as an overlap
    keep = len(s)
    if lap.closed and track.length >= lap.length - 1e-6:
        margin = 1.0 + float(np.max(track.w_left + track.w_right))
        keep = int(np.searchsorted(s, s[-1] - margin))
    if keep < 2:
        return
    nx, ny = -np.sin(track.heading[:keep]), np.cos(track.heading[:keep])
    x, y = track.x[:keep], track.y[:keep]
    left = np.stack([x + track.w_left[:keep] * nx, y + track.w_left[:keep] * ny], axis=1)
    right = np.stack([x - track.w_right[:keep] * nx, y - track.w_right[:keep] * ny], axis=1)
    spacing = float(s[1] - s[0])
    crossing = find_road_overlap(s[:keep], left, right, max(1, int(round(geometry.overlap_check_spacing_m / spacing))))
    if crossing is not None:
        raise SpecError(
            f"{source}: the racing line crosses itself: the road near s={crossing.s_a:.1f} m (line "
            f"{_line_of(lap.lines, lap, start + crossing.s_a)}) overlaps the road near s={crossing.s_b:.1f} m "
            f"(line {_line_of(lap.lines, lap, start + crossing.s_b)})")
