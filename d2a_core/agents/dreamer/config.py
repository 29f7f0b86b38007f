"""Hyperparameters of the DreamerV3 agent. Defaults are the paper's values (Dream2Assist table 2,
DreamerV3 2023 for everything the table leaves out)."""

from __future__ import annotations

from typing import Any, Optional

from pydantic import Field, model_validator

from d2a_core.config.section import Section


class HeadConfig(Section):
    """One extra world-model head, built by name from the head registry (see `heads.py`)."""

    name: str = Field(min_length=1, description="key of the head in the world model and its metrics")
    kind: str = Field(min_length=1, description="registered head kind, e.g. 'categorical'")
    weight: float = Field(1.0, ge=0, description="scale of this head's loss in the world-model loss")
    options: dict[str, Any] = Field(default_factory=dict, description="kind-specific settings")
    # Adam steps each weight by about the learning rate whatever the loss's scale, so `weight`
    # changes how much the head shapes the shared representation, not how fast the head itself
    # learns; `lr` does the latter.
    lr: Optional[float] = Field(None, gt=0, description="learning rate of this head's own weights (None: model_lr)")

    omit_at_default = {"lr": None}


class DreamerConfig(Section):
    """Every tunable constant of the agent (networks, losses, optimisers, replay, schedule)."""

    # --- networks
    units: int = Field(512, gt=0, description="width of every MLP layer (encoder, decoder, heads, actor, critic)")
    layers: int = Field(2, ge=1, description="hidden layers of every MLP")
    deter: int = Field(512, gt=0, description="size of the RSSM's deterministic (GRU) state")
    stoch: int = Field(32, gt=0, description="number of categorical latents")
    classes: int = Field(32, ge=2, description="classes per categorical latent")
    unimix: float = Field(0.01, ge=0, lt=1, description="uniform mixture of latent (and discrete-action) categoricals")
    bins: int = Field(255, ge=3, description="two-hot bins of reward and critic, symmetric in symlog space")
    bin_range: float = Field(20.0, gt=0, description="bins span [-bin_range, bin_range] in symlog space")
    norm_eps: float = Field(1e-3, gt=0, description="LayerNorm epsilon")
    actor_min_std: float = Field(0.1, gt=0, description="lower bound of the continuous actor's std")
    actor_max_std: float = Field(1.0, gt=0, description="upper bound of the continuous actor's std")
    learned_initial_state: bool = Field(True, description="learn the RSSM's initial deterministic state")

    # --- world-model loss
    free_nats: float = Field(1.0, ge=0, description="free bits per step, applied after summing KL over latents")
    kl_dyn_scale: float = Field(0.5, ge=0, description="weight of KL(sg(post) || prior)")
    kl_rep_scale: float = Field(0.1, ge=0, description="weight of KL(post || sg(prior))")
    decoder_scale: float = Field(1.0, ge=0)
    reward_scale: float = Field(1.0, ge=0)
    continue_scale: float = Field(1.0, ge=0)
    extra_heads: list[HeadConfig] = Field(default_factory=list, description="extra world-model heads")
    # A reward that depends on a classifier's estimate at collection time (the assistant's
    # r_hat*(y_hat)) goes stale in replay: most of it was collected while the estimate was poor.
    # Naming a categorical extra head here makes the replay carry the reward under every class
    # (`REWARD_BY_CLASS_FIELD`) and the reward head learn the one that head picks now.
    reward_relabel_head: str | None = Field(
        None, description="extra head whose current argmax picks each replayed step's reward among "
                          "the stored rewards per class (None: the stored reward)"
    )
    # A charge on each action that the reward contains and whose form is known (the assistant's
    # intervention term, -w * ||a||_2): learnt through the reward head, which reads the next model
    # state, the charge of one action is lost in the rewards around it and imagination pays no
    # gradient for it. With a weight here the replay stores rewards with the charge taken out,
    # the reward head learns the rest, and imagination charges each imagined action exactly.
    action_cost: float = Field(
        0.0, ge=0, description="weight w of a charge -w * ||a||_2 on each action (internal units) that the "
                               "env's reward contains: taken out of the replayed rewards and added exactly "
                               "in imagination (0: none; the assistant sets it, see assistant.exact_intervention)"
    )

    # --- behaviour
    imag_horizon: int = Field(15, ge=1)
    imag_starts: int | None = Field(
        None, gt=0, description="replayed posterior states that start imagination (None: all batch*length)"
    )
    discount: float = Field(0.997, gt=0, le=1)
    return_lambda: float = Field(0.95, ge=0, le=1)
    actor_entropy: float = Field(3e-4, ge=0)
    slow_critic_fraction: float = Field(0.02, gt=0, le=1, description="EMA step of the slow critic")
    slow_critic_every: int = Field(1, ge=1, description="updates between slow-critic EMA steps")
    slow_critic_reg: float = Field(1.0, ge=0, description="weight of the regulariser toward the slow critic")
    return_norm_decay: float = Field(0.99, ge=0, lt=1)
    return_norm_low: float = Field(5.0, ge=0, lt=100, description="lower percentile of the return range")
    return_norm_high: float = Field(95.0, gt=0, le=100, description="upper percentile of the return range")
    return_norm_limit: float = Field(1.0, gt=0, description="returns are divided by max(limit, hi - lo)")
    # --- optimisers (Adam)
    model_lr: float = Field(1e-4, gt=0)
    actor_lr: float = Field(3e-5, gt=0)
    critic_lr: float = Field(3e-5, gt=0)
    model_eps: float = Field(1e-8, gt=0)
    actor_eps: float = Field(1e-5, gt=0)
    critic_eps: float = Field(1e-5, gt=0)
    model_grad_clip: float = Field(1000.0, gt=0)
    actor_grad_clip: float = Field(100.0, gt=0)
    critic_grad_clip: float = Field(100.0, gt=0)

    # --- replay and schedule
    batch_size: int = Field(16, gt=0)
    batch_length: int = Field(64, ge=2)
    train_ratio: float = Field(512.0, gt=0, description="replayed steps per environment step")
    replay_capacity: int = Field(1_000_000, gt=0, description="environment steps kept (over all env streams)")
    prefill_steps: int = Field(1024, ge=0, description="environment steps collected before the first update")

    # --- execution
    device: str = Field("cpu", description="torch device, e.g. 'cpu' or 'cuda'")

    omit_at_default = {"reward_relabel_head": None, "action_cost": 0.0}
    # experiments that did not become defaults (docs/experiments/): replay weighted to the newest
    # or to terminal windows, extra world-model updates, a return scale from running trajectories,
    # the reward and continue losses weighted at episode ends (the assistant's; assistant-safety.md)
    retired = {"replay_recent_fraction": 0.0, "replay_recent_steps": 5000, "replay_terminal_fraction": 0.0,
               "model_updates": 1, "return_norm_scope": "all", "terminal_weight": 1.0}
    # settings with one possible value left, always recorded: kept in records for the ids made with
    # them (continuous actions learn by backprop through the dynamics; training runs in float32;
    # REINFORCE for continuous actions and bfloat16 autocast: docs/benchmarks.md)
    recorded_constants = {"discrete_actor_grad": "reinforce", "continuous_actor_grad": "backprop",
                          "precision": "float32"}

    @model_validator(mode="after")
    def _check_ranges(self) -> DreamerConfig:
        if self.actor_min_std > self.actor_max_std:
            raise ValueError("actor_min_std must not exceed actor_max_std")
        if self.return_norm_low >= self.return_norm_high:
            raise ValueError("return_norm_low must be below return_norm_high")
        names = [head.name for head in self.extra_heads]
        if len(names) != len(set(names)):
            raise ValueError(f"extra_heads names must be unique, got {names}")
        if self.bins % 2 == 0:
            raise ValueError("bins must be odd so that zero is a bin centre")
        return self

    @property
    def stoch_flat(self) -> int:
        """Size of a flattened one-hot latent sample."""
        return self.stoch * self.classes

    @property
    def feat_size(self) -> int:
        """Size of the model state (deterministic + flattened stochastic) that heads read."""
        return self.deter + self.stoch_flat

    @property
    def replayed_steps_per_update(self) -> int:
        """Environment steps one update replays (batch_size * batch_length)."""
        return self.batch_size * self.batch_length
