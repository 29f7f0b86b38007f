"""The race env's settings (`EnvConfig`), apart from the env so that the config schema, and the
report that resolves presets through it, load without pybullet."""

from __future__ import annotations

from typing import Optional

from pydantic import Field

from d2a_core.config.section import Section

DEFAULT_LOOKAHEAD_M = (0.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 80.0, 100.0, 130.0)


class EnvConfig(Section):
    """The racing environment: timing, start, termination and observation layout."""

    dt: float = Field(0.1, gt=0, description="control step (s); the paper's CARLA step")
    time_limit_s: Optional[float] = Field(
        None, gt=0, description="truncate after this long; default: the finish distance at 8 m/s"
    )
    start_speed_m_s: float = Field(20.0, ge=0, description="rolling start speed of both cars")
    off_track_margin_m: float = Field(2.0, ge=0, description="terminate this far beyond a road edge")
    edge_lookahead_m: list[float] = Field(list(DEFAULT_LOOKAHEAD_M), min_length=1)
    car_length_m: float = Field(4.6, gt=0)
    car_width_m: float = Field(1.9, gt=0)
    car_height_m: float = Field(1.2, gt=0)
    render_view: str = Field("chase", pattern="^(chase|birdseye)$")
    render_width: int = Field(320, ge=16)
    render_height: int = Field(240, ge=16)

    # the distance between the cars' bodies in the observation: drivers trained with it were no
    # more reliable (docs/experiments/crash-blind-world-model.md, "The clearance in the observation")
    retired = {"observe_clearance": False, "clearance_cap_m": 10.0}
