"""Schema of a track spec (the YAML files in `tracks/`); see `tracks/README.md` for the format.

Conventions: metres and degrees; `s` is the horizontal (plan-view) distance along the centreline
from its first point; curvature and lateral offsets are positive to the left.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

Knots = list[tuple[float, float]]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StraightSegment(_Strict):
    length: float = Field(gt=0, description="metres")


class ArcSegment(_Strict):
    radius: float = Field(gt=0, description="metres")
    angle_deg: float = Field(gt=0, le=360, description="how far the road turns")
    direction: Literal["left", "right"]

    @property
    def curvature(self) -> float:
        """Signed curvature (1/m), positive for a left turn."""
        return (1.0 if self.direction == "left" else -1.0) / self.radius


class TransitionSegment(_Strict):
    """Clothoid: curvature changes linearly from the previous segment's end curvature to `end_curvature`."""

    length: float = Field(gt=0, description="metres")
    end_curvature: float = Field(
        ge=-1.0, le=1.0, description="signed 1/m at the end, positive left (1/radius); 0 for straight"
    )


class Segment(_Strict):
    """Exactly one of `straight`, `arc`, `transition`."""

    straight: StraightSegment | None = None
    arc: ArcSegment | None = None
    transition: TransitionSegment | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> Segment:
        given = [name for name in ("straight", "arc", "transition") if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(f"a segment needs exactly one of straight, arc, transition (got {given or 'none'})")
        return self

    @property
    def kind(self) -> str:
        return next(name for name in ("straight", "arc", "transition") if getattr(self, name) is not None)

    @property
    def length(self) -> float:
        if self.straight is not None:
            return self.straight.length
        if self.arc is not None:
            return self.arc.radius * math.radians(self.arc.angle_deg)
        assert self.transition is not None
        return self.transition.length


class StartPose(_Strict):
    x: float = 0.0
    y: float = 0.0
    heading_deg: float = Field(0.0, description="direction of travel at s = 0, counter-clockwise from +x")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_knots(knots: Knots, what: str, positive: bool) -> Knots:
    if len(knots) == 0:
        raise ValueError(f"{what} needs at least one (s, value) knot")
    for k in range(1, len(knots)):
        if knots[k][0] <= knots[k - 1][0]:
            raise ValueError(f"knot s values must be strictly increasing (knot {k}: {knots[k][0]})")
    for s, value in knots:
        if not (math.isfinite(s) and math.isfinite(value)):
            raise ValueError(f"{what} knots must be finite numbers")
        if positive and value <= 0:
            raise ValueError(f"{what} must be > 0 (got {value} at s={s})")
    return knots


class Width(_Strict):
    """Half widths of the road measured from the centreline: constants or (s, value) knots."""

    left: float | Knots = Field(description="metres, or a list of [s, metres]")
    right: float | Knots = Field(description="metres, or a list of [s, metres]")

    @field_validator("left", "right", mode="before")
    @classmethod
    def _number_or_knots(cls, value: Any) -> float | Knots:
        # Checked by hand before pydantic's union validation, which would report both alternatives.
        if _is_number(value):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"must be a finite number > 0 (got {value})")
            return float(value)
        if isinstance(value, list):
            knots = []
            for k, item in enumerate(value):
                if not (isinstance(item, (list, tuple)) and len(item) == 2 and all(_is_number(v) for v in item)):
                    raise ValueError(f"knot {k} must be a pair of numbers [s, metres] (got {item!r})")
                knots.append((float(item[0]), float(item[1])))
            return _check_knots(knots, "half width", positive=True)
        raise ValueError(f"must be a number or a list of [s, metres] knots (got {value!r})")


class Barrier(_Strict):
    side: Literal["left", "right"]
    s_start: float = Field(ge=0)
    s_end: float = Field(gt=0)
    offset: float = Field(1.0, ge=0, description="lateral distance from the road edge outward to the wall's face")
    height: float = Field(1.0, gt=0)
    type: Literal["concrete", "armco"] = Field("concrete", description="informational")

    @model_validator(mode="after")
    def _ordered(self) -> Barrier:
        if self.s_end <= self.s_start:
            raise ValueError(f"s_end ({self.s_end}) must be > s_start ({self.s_start})")
        return self


class GridSlot(_Strict):
    s: float = Field(ge=0, description="distance along the centreline of the car's centre")
    e: float = Field(0.0, description="lateral offset, positive left")


class StartGrid(_Strict):
    ego: GridSlot
    opponent: GridSlot

    @model_validator(mode="after")
    def _opponent_ahead(self) -> StartGrid:
        if self.opponent.s <= self.ego.s:
            raise ValueError(f"opponent.s ({self.opponent.s}) must be ahead of ego.s ({self.ego.s})")
        return self


class TrackSpec(_Strict):
    """A whole track spec (one YAML file)."""

    # the name becomes the alias track/<name>: it starts with a letter or digit (not '.', '-')
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
    description: str = ""
    sample_spacing_m: float = Field(0.5, gt=0, le=5.0)
    start_pose: StartPose = Field(default_factory=StartPose)
    segments: list[Segment] = Field(min_length=1)
    width: Width
    elevation: Knots = Field(default_factory=lambda: [(0.0, 0.0)], description="(s, z) knots, PCHIP")
    barriers: list[Barrier] = Field(default_factory=list)
    finish_s: float = Field(gt=0)
    start_grid: StartGrid

    @field_validator("elevation")
    @classmethod
    def _elevation_knots(cls, knots: Knots) -> Knots:
        return _check_knots(knots, "elevation", positive=False)

    @property
    def total_length(self) -> float:
        """Length of the centreline (sum of the segments)."""
        return sum(segment.length for segment in self.segments)
