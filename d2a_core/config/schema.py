"""The typed schema of a run's configuration (the root of every preset).

Each subsystem owns its section model next to its code; this module only mounts them, so the
schema stays the single place that lists what a config file may contain.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class Section(BaseModel):
    """Base of every config section: unknown keys and loose types are errors, not guesses."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class RewardConfig(Section):
    """Task and intent reward constants (paper section 3 and appendix 'Human Objectives')."""

    collision: float = Field(-10.0, le=0, description="r^collision, paid once when a collision ends the episode")
    bounds: float = Field(-10.0, le=0, description="r^bounds, paid once when the car leaves the track too far")
    finish: float = Field(10.0, ge=0, description="r^finish, paid once when the finish line is reached")
    c_pass: float = Field(10.0, description="scale of the pass term on ds_t - ds_{t-1}")
    pass_window_m: float = Field(800.0, gt=0, description="s_high = -s_low of the pass indicator")
    c_stay: float = Field(-2.0, description="scale of the stay term on ds_t - ds_{t-1}")
    stay_window_m: float = Field(50.0, gt=0, description="s_high = -s_low of the stay indicator")
    c_side: float = Field(1.0, description="scale of the passing term of the left/right intents")
    c_margin: float = Field(0.3, description="lateral margin added to de_t by the left/right intents")


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
