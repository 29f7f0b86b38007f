"""Tunable constants of the track package (CSV smoothing, Frenet search, geometry checks).

`TracksConfig` is the `tracks` section of the project's root config; every function that uses one
of these values takes the relevant sub-model as an optional argument and falls back to the defaults.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from d2a_core.config.section import Section


class CentrelineCsvConfig(Section):
    """How a racing-line CSV (`x_m, y_m, w_tr_right_m, w_tr_left_m[, z_m]`) becomes a track."""

    sample_spacing_m: float = Field(0.5, gt=0, le=5.0, description="spacing of the compiled track's samples")
    fine_spacing_m: float = Field(
        0.25, gt=0, le=2.0, description="resampling grid on which the raw points are smoothed"
    )
    smoothing_sigma_m: float = Field(
        3.0,
        ge=0,
        le=50.0,
        description="std of the Gaussian smoothing of x, y, z and widths along the lap (0: none); "
        "it removes point noise so curvature is not noise, and shrinks radii by ~sigma^2 / (2 R)",
    )
    min_points: int = Field(10, ge=4, description="fewer points than this is an error")
    closing_gap_factor: float = Field(
        3.0,
        gt=0,
        description="the file is a closed lap when its last point is within this many median point "
        "spacings of its first",
    )
    ego_start_s_m: float = Field(5.0, ge=0, description="start grid: ego's s on the cut section")
    ego_start_e_m: float = Field(0.0, description="start grid: ego's lateral offset (positive left)")
    opponent_gap_m: float = Field(15.0, gt=0, description="start grid: opponent starts this far ahead")
    opponent_start_e_m: float = Field(0.0, description="start grid: opponent's lateral offset")

    @model_validator(mode="after")
    def _fine_grid_finer_than_samples(self) -> CentrelineCsvConfig:
        if self.fine_spacing_m > self.sample_spacing_m:
            raise ValueError("fine_spacing_m must not exceed sample_spacing_m")
        return self


class FrenetSearchConfig(Section):
    """Local search of `Track.to_frenet` around an `s_hint`."""

    max_iterations: int = Field(
        64, ge=1, description="projections tried before giving up (each moves to a better interval)"
    )
    max_jump_samples: int = Field(
        64, ge=1, description="the most samples one step of the walk may skip (limits overshoot on curves)"
    )
    global_fallback_m: float = Field(
        30.0,
        gt=0,
        description="a hinted answer farther than this from the centreline is re-checked by a global search",
    )
    nearest_chunk: int = Field(
        512, ge=1, description="query points per block in the brute-force nearest-sample search"
    )


class TrackGeometryConfig(Section):
    """Checks applied when a spec is compiled."""

    overlap_check_spacing_m: float = Field(
        1.0, gt=0, description="edge polylines are subsampled to about this spacing for the overlap check"
    )
    min_edge_radius_m: float = Field(
        1.0,
        gt=0,
        description="an edge or barrier whose radius of curvature falls below this (or folds over) is an error",
    )


class TracksConfig(Section):
    """All tunables of `d2a_core.tracks`."""

    csv: CentrelineCsvConfig = Field(default_factory=CentrelineCsvConfig)
    frenet: FrenetSearchConfig = Field(default_factory=FrenetSearchConfig)
    geometry: TrackGeometryConfig = Field(default_factory=TrackGeometryConfig)
