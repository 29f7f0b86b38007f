"""Hyperparameters of the Dreamer-AIL baseline (torch-free, so the config schema can mount it cheaply).

The residual's learner is the no-rssm PPO learner (its window, networks and PPO settings, the
same defaults); the discriminator and the demonstrations are this baseline's own. The paper gives
no values for it; these are GAIL's usual ones (Ho & Ermon 2016) at `quick` size.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from d2a_core.agents.baselines.no_rssm_config import NoRSSMConfig


class DreamerAILConfig(NoRSSMConfig):
    """The `dreamer_ail` section: the residual's PPO learner, the discriminator, the demonstrations."""

    policy_reads_intent: bool = Field(
        False, description="always false: the baseline has no intent estimate (the learner's no-rssm key)"
    )

    # --- the residual
    residual_bound: float = Field(
        0.5, gt=0, le=1,
        description="largest |a_A| on each control: the residual acts in [-bound, bound], so the human's "
                    "own input keeps at least 1 - bound of the car",
    )

    # --- the discriminator D(s, a): an MLP on the car's observation and the executed action
    disc_units: int = Field(128, gt=0, description="width of the discriminator's hidden layers")
    disc_layers: int = Field(2, ge=1, description="hidden layers of the discriminator")
    disc_lr: float = Field(3e-4, gt=0, description="learning rate of the discriminator")
    disc_steps: int = Field(8, ge=1, description="discriminator minibatch steps per PPO update")
    disc_batch: int = Field(256, ge=2, description="pairs per side (experts, assisted car) in a discriminator minibatch")
    reward_clip: float = Field(10.0, gt=0, description="the reward log D - log(1 - D) is clipped to +-this")

    # --- the demonstrations: each expert of the pair driving alone
    demo_episodes: int = Field(20, ge=1, description="episodes of each intent's expert driving alone")

    @model_validator(mode="after")
    def _no_intent(self) -> "DreamerAILConfig":
        if self.policy_reads_intent:
            raise ValueError("dreamer_ail.policy_reads_intent: Dreamer-AIL has no intent estimate to read")
        return self
