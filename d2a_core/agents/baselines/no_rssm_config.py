"""Hyperparameters of the No-RSSM baseline (torch-free, so the config schema can mount it cheaply).

Defaults suit a `quick` run: ~40k env steps over 8 envs on a 2-core CPU, i.e. about 80 PPO
updates of 8 x 64 records, each 10 passes of 8 minibatches (~0.5 s per update on one core with
66 observation features). The paper gives no values for this baseline; these are the usual PPO
ones (Schulman et al. 2017; Andrychowicz et al. 2021) with a short rollout for that budget.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from d2a_core.config.section import Section


class NoRSSMConfig(Section):
    """The `no_rssm` section: window, networks, PPO learner and the intent classifier."""

    # --- what the networks read
    window: int = Field(16, ge=1, description="observation frames the actor, critic and classifier read (paper: 16)")
    policy_reads_intent: bool = Field(
        True, description="actor and critic also read the classifier's probabilities y_hat (detached)"
    )

    # --- networks (Linear -> LayerNorm -> SiLU MLPs, one per actor, critic and classifier)
    units: int = Field(128, gt=0, description="width of every hidden layer")
    layers: int = Field(2, ge=1, description="hidden layers of every MLP")
    init_std: float = Field(0.5, gt=0, description="initial std of the actor's Gaussian (before tanh)")
    min_std: float = Field(0.05, gt=0, description="lower bound of the actor's std")
    max_std: float = Field(1.0, gt=0, description="upper bound of the actor's std")

    # --- PPO learner
    rollout_length: int = Field(64, ge=1, description="records per env between updates")
    epochs: int = Field(10, ge=1, description="passes over a rollout per update")
    minibatches: int = Field(8, ge=1, description="minibatches per pass")
    discount: float = Field(0.99, gt=0, le=1)
    gae_lambda: float = Field(0.95, ge=0, le=1)
    clip: float = Field(0.2, gt=0, description="PPO ratio clip")
    entropy: float = Field(1e-3, ge=0, description="entropy bonus per unit of normalised advantage")
    actor_lr: float = Field(3e-4, gt=0)
    critic_lr: float = Field(3e-4, gt=0)
    # The classifier has its own parameters, so its loss weight would only rescale a gradient
    # that Adam normalises away; its learning rate is the knob that matters.
    intent_lr: float = Field(3e-4, gt=0, description="learning rate of the intent classifier")
    adam_eps: float = Field(1e-5, gt=0)
    grad_clip: float = Field(0.5, gt=0, description="max gradient norm, per network")

    @model_validator(mode="after")
    def _check_ranges(self) -> NoRSSMConfig:
        if not self.min_std <= self.init_std <= self.max_std:
            raise ValueError("need min_std <= init_std <= max_std")
        return self
