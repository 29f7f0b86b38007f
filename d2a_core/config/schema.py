"""The typed schema of a run's configuration (the root of every preset).

Each subsystem owns its section model next to its code; this module only mounts them, so the
schema stays the single place that lists what a config file may contain.
"""

from __future__ import annotations

from pydantic import Field

from d2a_core.config.section import Section
from d2a_core.objectives.rewards import RewardConfig


class OpponentsConfig(Section):
    """How `make-track` generates opponent replays."""

    count: int = Field(8, ge=1, le=64)
    pace_min: float = Field(0.75, gt=0, le=1.2, description="slowest replay, as a fraction of the tyre limit")
    pace_max: float = Field(0.95, gt=0, le=1.2, description="fastest replay, as a fraction of the tyre limit")
    line_offset_max_m: float = Field(2.0, ge=0, description="largest lateral offset of a replay's line")


class Config(Section):
    """Root configuration. Presets (smoke, quick, paper) fill it; defaults are the paper's values."""

    reward: RewardConfig = RewardConfig()
    opponents: OpponentsConfig = OpponentsConfig()
