"""Config sections of the training runs (kept free of torch so the CLI starts fast)."""

from __future__ import annotations

from typing import Optional

from pydantic import Field, model_validator

from d2a_core.config.section import Section
from d2a_core.objectives.assistant import AssistantRewardConfig


def _budget_holds_checkpoints(section):
    """Every checkpoint needs at least one step of every env: a budget below checkpoints x envs
    would train past itself to reach them."""
    if section.env_steps < section.checkpoints * section.num_envs:
        raise ValueError(f"env_steps ({section.env_steps}) must be at least checkpoints x num_envs "
                         f"({section.checkpoints} x {section.num_envs} = {section.checkpoints * section.num_envs})")
    return section


class HumansConfig(Section):
    """The population run: length, parallel envs, checkpoint schedule, evaluation."""

    _budget = model_validator(mode="after")(_budget_holds_checkpoints)

    env_steps: int = Field(2_000_000, gt=0, description="environment steps per intent (all envs together)")
    num_envs: int = Field(4, ge=1, le=64, description="envs stepped in parallel during collection")
    checkpoints: int = Field(10, ge=1, description="evenly spaced checkpoints (the expert is chosen among them)")
    eval_episodes: int = Field(10, ge=1, description="unassisted evaluation episodes per checkpoint")
    eval_envs: int = Field(4, ge=1, le=64)
    log_every: int = Field(5000, gt=0, description="environment steps between training-curve rows")
    torch_threads: int = Field(0, ge=0, description="torch CPU threads (0: all cores)")
    snapshot_every: int = Field(
        0, ge=0, description="env steps between weight snapshots kept for filling the imperfect span (0: none)"
    )
    fill_imperfect: int = Field(
        5, ge=0,
        description="after training, snapshots are evaluated and added until this many checkpoints are below 75 % of the expert",
    )
    model_lr: float | None = Field(
        None, gt=0,
        description="world-model learning rate of the drivers (unset: dreamer.model_lr); the assistant keeps dreamer.model_lr",
    )
    eval_logs: int = Field(
        0, ge=0,
        description="evaluation episodes of each checkpoint kept as MCAP episode logs (episodes/*.mcap), to see where it fails",
    )
    omit_at_default = {"eval_logs": 0}
    # experiments that did not become defaults: training starts spread along the race (hairpin), and
    # the drivers' own terminal weight (docs/experiments/crash-blind-world-model.md, "In the loop")
    retired = {"train_start_spread": 0.0, "terminal_weight": None}


class AssistantConfig(Section):
    """The assistant run (paper Algorithm 1, second phase): its reward and intent head. A method
    (`d2a_core.training.methods`) sets the reward's alpha_r and alpha_a and adds the intent head."""

    _budget = model_validator(mode="after")(_budget_holds_checkpoints)

    reward: AssistantRewardConfig = AssistantRewardConfig()
    intent_scale: float = Field(1.0, ge=0, description="weight of the intent head's NLL in the world-model loss")
    env_steps: int = Field(2_000_000, gt=0, description="environment steps of the assistant's training (all envs together)")
    num_envs: int = Field(4, ge=1, le=64, description="envs stepped in parallel during collection")
    checkpoints: int = Field(10, ge=1, description="evenly spaced checkpoints, each evaluated on the panel")
    human_explore: bool = Field(
        True, description="training humans sample their actor (true) or take its mode; evaluation always takes the mode"
    )
    panel_weakest: int = Field(5, ge=0, description="imperfect humans per intent in the evaluation panel (plus the expert)")
    panel_episodes: int = Field(10, ge=1, description="paired episodes per panel human at each checkpoint")
    eval_envs: int = Field(8, ge=1, le=64)
    log_every: int = Field(5000, gt=0, description="environment steps between training-curve rows")
    torch_threads: int = Field(0, ge=0, description="torch CPU threads (0: all cores)")
    partner_window: int = Field(
        1, ge=1, le=64,
        description="the human's last K actions in the assistant's observation (1: the partner slot alone, the paper's)",
    )

    # The assistant's own DreamerV3 settings where they differ from the drivers' (`dreamer.*`, which
    # the populations share): a Dreamer-family method's learner takes these (`Method.configure`).
    train_ratio: Optional[float] = Field(
        None, gt=0,
        description="replayed steps per env step of a Dreamer-family assistant (None: dreamer.train_ratio)",
    )
    imag_starts: Optional[int] = Field(
        None, gt=0,
        description="replayed posterior states that start imagination in a Dreamer-family assistant's "
                    "actor-critic update (None: dreamer.imag_starts)",
    )
    reward_relabel: bool = Field(
        False,
        description="a method with a Dreamer intent head and expert terms learns each replayed step's reward "
                    "under its current intent estimate, not the estimate the step was collected with "
                    "(sets dreamer.reward_relabel_head=intent; methods without both ignore it)",
    )

    exact_intervention: bool = Field(
        False,
        description="a Dreamer-family assistant charges its intervention (-w_interv * ||a_A||) exactly in "
                    "imagination instead of learning it through the reward head (sets dreamer.action_cost=w_interv)",
    )

    omit_at_default = {"partner_window": 1, "train_ratio": None, "imag_starts": None, "reward_relabel": False,
                       "exact_intervention": False}
    # experiments that did not become defaults: the intent head's own learning rate, and what the
    # head reads besides the model state (docs/experiments/intent-estimate.md)
    # and a bound on every method's action (docs/experiments/assistant-safety.md, "A bounded residual");
    # the learner's own actor gradient and precision (docs/benchmarks.md: REINFORCE, bfloat16)
    retired = {"intent_lr": None, "intent_reads": "latent", "authority": 1.0, "actor_grad": None, "precision": None}
