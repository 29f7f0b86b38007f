"""The typed schema of a run's configuration (the root of every preset).

Each subsystem owns its section model next to its code; this module only mounts them, so the
schema stays the single place that lists what a config file may contain.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from d2a_core.config.section import Section, record
from d2a_core.objectives.rewards import RewardConfig
from d2a_core.sim.driver import DriverConfig
from d2a_core.sim.episode_log.config import EpisodeLogConfig
from d2a_core.sim.env_config import EnvConfig
from d2a_core.sim.vehicle import VehicleConfig
from d2a_core.sim.world_config import WorldConfig
from d2a_core.tracks.config import TracksConfig
from d2a_core.training.config import AssistantConfig, HumansConfig
from d2a_core.agents.baselines.dreamer_ail_config import DreamerAILConfig
from d2a_core.agents.baselines.no_rssm_config import NoRSSMConfig
from d2a_core.agents.dreamer.config import DreamerConfig


class OpponentsConfig(Section):
    """How `make-track` generates opponent replays."""

    count: int = Field(8, ge=1, le=64)
    # Pace also caps the replay's throttle. On the straightaway, where the car is power-limited,
    # a replay above ~0.85 reaches the finish before a flat-out ego could pass it from its grid
    # slot 15 m behind (measured: 0.95 finishes 8 m ahead of it), so a pass driver could not
    # succeed against every opponent. At <= 0.8 a flat-out ego finishes >= 15 m ahead of each.
    pace_min: float = Field(0.6, gt=0, le=1.2, description="slowest replay, as a fraction of the tyre limit (and throttle)")
    pace_max: float = Field(0.8, gt=0, le=1.2, description="fastest replay, as a fraction of the tyre limit (and throttle)")
    line_offset_max_m: float = Field(2.0, ge=0, description="largest lateral offset of a replay's line")

    @model_validator(mode="after")
    def _ordered(self) -> "OpponentsConfig":
        if self.pace_min > self.pace_max:
            raise ValueError(f"pace_min ({self.pace_min}) must not exceed pace_max ({self.pace_max})")
        return self


class Config(Section):
    """Root configuration. Presets (smoke, quick, paper) fill it; defaults are the paper's values."""

    tracks: TracksConfig = TracksConfig()
    vehicle: VehicleConfig = VehicleConfig()
    env: EnvConfig = EnvConfig()
    reward: RewardConfig = RewardConfig()
    world: WorldConfig = WorldConfig()
    episode_log: EpisodeLogConfig = EpisodeLogConfig()
    opponents: OpponentsConfig = OpponentsConfig()
    driver: DriverConfig = DriverConfig()
    dreamer: DreamerConfig = DreamerConfig()
    humans: HumansConfig = HumansConfig()
    assistant: AssistantConfig = AssistantConfig()
    no_rssm: NoRSSMConfig = NoRSSMConfig()
    dreamer_ail: DreamerAILConfig = DreamerAILConfig()

    # a section added after runs were stored: left out of records at its defaults, so the grid's
    # cell keys (which hash the whole record) stay as they were
    omit_at_default = {"dreamer_ail": record(DreamerAILConfig())}
