"""Tunable settings of the MCAP episode recorder: file layout and how the 3-D scene looks."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, Strict

from d2a_core.config.section import Section

UnitInterval = Annotated[float, Field(ge=0.0, le=1.0)]
# Strict(False): YAML gives lists, and a colour is naturally written as one
Colour = Annotated[tuple[UnitInterval, UnitInterval, UnitInterval, UnitInterval], Strict(False)]
"""An RGBA colour, each channel in [0, 1]."""


class EpisodeLogConfig(Section):
    """How episode logs are written and drawn.

    None of these settings change what `read_episode` returns; they only change file size and
    what Foxglove's 3-D panel shows.
    """


    compression: Literal["zstd", "lz4", "none"] = Field(
        "zstd", description="Chunk compression of the MCAP file."
    )
    chunk_size_bytes: int = Field(
        1 << 20, gt=0, description="Target uncompressed size of one MCAP chunk."
    )
    fsync: bool = Field(
        False,
        description="fsync the file before moving it into place: survives power loss, but costs "
        "about 0.1-0.2 s per file on a busy disk. The move itself is atomic either way.",
    )
    car_length_m: float = Field(4.5, gt=0, description="Drawn car length when a pose gives none.")
    car_width_m: float = Field(1.9, gt=0, description="Drawn car width when a pose gives none.")
    car_height_m: float = Field(1.2, gt=0, description="Drawn car height when a pose gives none.")
    car_colours: list[Colour] = Field(
        default_factory=lambda: [
            (0.12, 0.47, 0.71, 1.0),
            (0.89, 0.10, 0.11, 1.0),
            (0.20, 0.63, 0.17, 1.0),
            (1.00, 0.50, 0.00, 1.0),
        ],
        min_length=1,
        description="Colours given to cars without their own, in sorted car-name order (cycled).",
    )
    road_colour: Colour = (0.35, 0.35, 0.37, 1.0)
    edge_colour: Colour = (1.0, 1.0, 1.0, 1.0)
    centreline_colour: Colour = (1.0, 0.85, 0.1, 0.8)
    finish_colour: Colour = (1.0, 0.2, 0.2, 1.0)
    barrier_colour: Colour = (0.75, 0.15, 0.15, 0.9)
    edge_line_width_m: float = Field(0.15, gt=0, description="Thickness of drawn track lines.")
    overlay_lift_m: float = Field(
        0.02, ge=0, description="Lines are drawn this far above the road so they are not hidden."
    )
