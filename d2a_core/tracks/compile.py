"""Compile a validated `TrackSpec` into a `Track` (samples, barriers, checks of the geometry)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d2a_core.errors import SpecError
from d2a_core.tracks.config import FrenetSearchConfig, TrackGeometryConfig
from d2a_core.tracks.frenet import CentrelineFrame
from d2a_core.tracks.interpolation import KnotProfile
from d2a_core.tracks.limits import MAX_GRADE
from d2a_core.tracks.overlap import Crossing, find_barrier_crossing, find_barrier_on_road, find_road_overlap
from d2a_core.tracks.segments import PlanCentreline, curvature_pieces, sample_centreline
from d2a_core.tracks.spec import TrackSpec
from d2a_core.tracks.spec_loading import check_spec_consistency, format_loc, width_profiles
from d2a_core.tracks.track import Barrier, GridSlot, StartGrid, Track


def _segment_field(spec: TrackSpec, index: int) -> str:
    segment = spec.segments[index]
    leaf = {"straight": "length", "arc": "radius", "transition": "end_curvature"}[segment.kind]
    return format_loc(("segments", index, segment.kind, leaf))


def _check_folds(
    spec: TrackSpec, plan: PlanCentreline, reach_left: np.ndarray, reach_right: np.ndarray, min_radius: float, source: str
) -> None:
    """An edge (or barrier) on the inside of a bend must keep a positive radius, else it folds over."""
    for side, reach, sign in (("left", reach_left, 1.0), ("right", reach_right, -1.0)):
        inward = np.maximum(sign * plan.curvature, 0.0)  # curvature towards this side
        # Radius of the offset curve = 1/k - reach must stay >= min_radius: k * (reach + min_radius) < 1.
        bad = inward * (reach + min_radius) >= 1.0
        if bad.any():
            i = int(np.argmax(bad))
            radius = 1.0 / inward[i]
            raise SpecError(
                f"{source}: {_segment_field(spec, int(plan.segment_index[i]))}: radius {radius:.2f} m at "
                f"s={plan.s[i]:.1f} is too tight for the {side} side reaching {reach[i]:.2f} m from the "
                f"centreline (width plus barrier offset); the {side} edge would fold over itself"
            )


def _segment_at(spec: TrackSpec, s: float) -> int:
    start = 0.0
    for index, segment in enumerate(spec.segments):
        start += segment.length
        if s < start:
            return index
    return len(spec.segments) - 1


def _describe_crossing(spec: TrackSpec, crossing: Crossing) -> str:
    def part(what: str, s: float) -> str:
        return f"{what} at s={s:.1f} m (segments[{_segment_at(spec, s)}])"

    return f"{part(crossing.what_a, crossing.s_a)} crosses {part(crossing.what_b, crossing.s_b)}"


def _barrier_samples(s: np.ndarray, s_start: float, s_end: float) -> np.ndarray:
    inside = s[(s > s_start) & (s < s_end)]
    return np.concatenate([[s_start], inside, [s_end]])


def compile_spec(
    spec: TrackSpec,
    source: str | Path = "<spec>",
    geometry: TrackGeometryConfig | None = None,
    frenet_config: FrenetSearchConfig | None = None,
) -> Track:
    """Build the `Track` a spec describes.

    Args:
        spec: a validated spec (from `load_spec` or `TrackSpec.model_validate`).
        source: the spec's file name, used in error messages and recorded in the track.
        geometry: overlap/fold check tunables.
        frenet_config: search tunables handed to the track.

    Raises:
        SpecError: positions beyond the track, an edge or barrier folding in a tight bend, or a road
            or barrier that crosses another part of the road.
    """
    geometry = geometry or TrackGeometryConfig()
    source = str(source)
    problems = check_spec_consistency(spec)
    if problems:
        raise SpecError("\n".join(f"{source}: {format_loc(loc)}: {message}" for loc, message in problems))

    plan = sample_centreline(curvature_pieces(spec.segments, spec.start_pose), spec.start_pose, spec.sample_spacing_m)
    left_profile, right_profile = width_profiles(spec.width)
    w_left, w_right = left_profile.value(plan.s), right_profile.value(plan.s)
    elevation = KnotProfile(spec.elevation)
    z, grade = elevation.value(plan.s), elevation.derivative(plan.s)
    steep = np.flatnonzero(np.abs(grade) > MAX_GRADE)
    if len(steep):
        k = int(steep[np.argmax(np.abs(grade[steep]))])
        raise SpecError(f"{source}: elevation: the road climbs {abs(grade[k]):.0%} at s={plan.s[k]:.1f} m, steeper "
                        f"than {MAX_GRADE:.0%} (no car climbs that); spread the height change over more metres")

    reach_left, reach_right = w_left.copy(), w_right.copy()
    for barrier in spec.barriers:
        covered = (plan.s >= barrier.s_start) & (plan.s <= barrier.s_end)
        reach = reach_left if barrier.side == "left" else reach_right
        profile = left_profile if barrier.side == "left" else right_profile
        reach[covered] = np.maximum(reach[covered], profile.value(plan.s[covered]) + barrier.offset)
    _check_folds(spec, plan, reach_left, reach_right, geometry.min_edge_radius_m, source)

    spacing = float(plan.s[-1]) / (len(plan.s) - 1)
    frame = CentrelineFrame(spacing, plan.x, plan.y, plan.heading)
    barriers = []
    for barrier in spec.barriers:
        bs = _barrier_samples(plan.s, barrier.s_start, min(barrier.s_end, float(plan.s[-1])))
        profile = left_profile if barrier.side == "left" else right_profile
        be = (profile.value(bs) + barrier.offset) * (1.0 if barrier.side == "left" else -1.0)
        bx, by = frame.point_array(bs, be)
        points = np.stack([bx, by, elevation.value(bs)], axis=1)
        barriers.append(Barrier(barrier.side, barrier.type, barrier.height, barrier.offset, bs, points, be))

    nx, ny = -np.sin(plan.heading), np.cos(plan.heading)
    left = np.stack([plan.x + w_left * nx, plan.y + w_left * ny], axis=1)
    right = np.stack([plan.x - w_right * nx, plan.y - w_right * ny], axis=1)
    step = max(1, int(round(geometry.overlap_check_spacing_m / spacing)))
    crossing = find_road_overlap(plan.s, left, right, step)
    if crossing is None:
        crossing = find_barrier_crossing(
            plan.s, left, right, [(b.side, b.s, b.points) for b in barriers], step
        )
    if crossing is None:
        crossing = find_barrier_on_road(frame, plan.s, w_left, w_right, [(b.s, b.points) for b in barriers], step)
    if crossing is not None:
        raise SpecError(f"{source}: segments: the track overlaps itself: {_describe_crossing(spec, crossing)}")

    grid = spec.start_grid
    return Track(
        spec.name,
        s=plan.s,
        x=plan.x,
        y=plan.y,
        z=z,
        heading=plan.heading,
        curvature=plan.curvature,
        w_left=w_left,
        w_right=w_right,
        grade=grade,
        barriers=barriers,
        finish_s=min(spec.finish_s, float(plan.s[-1])),
        start_grid=StartGrid(ego=GridSlot(grid.ego.s, grid.ego.e), opponent=GridSlot(grid.opponent.s, grid.opponent.e)),
        source={"kind": "spec", "file": Path(source).name, "spec": spec.model_dump(mode="json")},
        frenet_config=frenet_config,
    )
