"""The pybullet world's settings (`WorldConfig`), apart from the world itself so that the config
schema, and the report that resolves presets through it, load without pybullet."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, Strict

from d2a_core.config.section import Section

# Strict(False): YAML gives lists for these tuples
Rgba = Annotated[tuple[float, float, float, float], Strict(False)]


def _default_car_colours() -> list[Rgba]:
    return [
        (0.85, 0.10, 0.10, 1.0),
        (0.10, 0.25, 0.90, 1.0),
        (0.95, 0.75, 0.05, 1.0),
        (0.10, 0.70, 0.20, 1.0),
    ]


class CameraConfig(Section):
    """Where the render cameras sit relative to the car they follow."""


    chase_distance_m: float = Field(9.0, gt=0, description="behind the car, along its heading")
    chase_height_m: float = Field(3.5, ge=0, description="above the car's road point")
    chase_look_ahead_m: float = Field(8.0, ge=0, description="the chase camera aims this far ahead")
    chase_target_height_m: float = Field(1.0, ge=0)
    chase_fov_deg: float = Field(60.0, gt=0, lt=180)
    birdseye_altitude_m: float = Field(60.0, gt=0, description="above the car's road point")
    birdseye_fov_deg: float = Field(60.0, gt=0, lt=180)
    birdseye_heading_up: bool = Field(True, description="True: car heading points up the image")
    near_m: float = Field(0.2, gt=0)
    far_m: float = Field(600.0, gt=0)
    light_direction: Annotated[tuple[float, float, float], Strict(False)] = (0.4, 0.3, 1.0)


class WorldConfig(Section):
    """Tunable constants of the pybullet world (geometry details, colours, cameras)."""


    barrier_thickness_m: float = Field(
        0.6, gt=0, description="walls extend this far away from the road behind their base line"
    )
    barrier_sink_m: float = Field(0.3, ge=0, description="walls reach this far below their base points")
    ground_clearance_m: float = Field(0.15, ge=0, description="gap between road point and car box bottom")
    contact_distance_m: float = Field(
        0.0, ge=0, description="report a contact when bodies are closer than this (0: touching)"
    )
    sweep_barrier_crossing: bool = Field(
        True, description="also report a barrier hit when a car's move since its last pose crosses a wall"
    )
    sweep_height_fraction: float = Field(
        0.25,
        ge=0,
        le=1,
        description="height of the crossing sweep ray on the car box, as a fraction of its height",
    )
    runoff_width_m: float = Field(25.0, ge=0, description="visual grass strip outside each road edge")
    runoff_drop_m: float = Field(0.05, ge=0, description="runoff sits this far below the road edge")
    edge_line_width_m: float = Field(0.3, ge=0, description="white line just inside each edge (0: none)")
    edge_line_lift_m: float = Field(0.02, ge=0)
    ground_drop_m: float = Field(3.0, ge=0, description="ground plane this far below the lowest road point")
    ground_margin_m: float = Field(300.0, ge=0, description="ground plane reaches this far past the track")
    road_colour: Rgba = (0.30, 0.30, 0.32, 1.0)
    edge_line_colour: Rgba = (0.95, 0.95, 0.95, 1.0)
    runoff_colour: Rgba = (0.30, 0.55, 0.25, 1.0)
    ground_colour: Rgba = (0.35, 0.50, 0.30, 1.0)
    barrier_colour: Rgba = (0.75, 0.75, 0.72, 1.0)
    car_colours: list[Rgba] = Field(default_factory=_default_car_colours, min_length=1)
    camera: CameraConfig = Field(default_factory=CameraConfig)
