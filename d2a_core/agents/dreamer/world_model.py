"""DreamerV3 world model for vector observations: symlog encoder, RSSM, symlog-MSE decoder,
two-hot reward head, Bernoulli continue head, KL balancing with free bits, extra heads."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from d2a_core.errors import ConfigError, TrainingError

from .config import DreamerConfig
from .distributions import TwoHot, categorical_kl, symlog, unimix_probs
from .heads import WorldModelHead, build_head, latent_mlp
from .latent import Latent, first_layers
from .nets import MLP
from .rssm import RSSM, Observed


def kl_balance(
    post_logits: Tensor,
    prior_logits: Tensor,
    unimix: float,
    free_nats: float,
    dyn_scale: float,
    rep_scale: float,
) -> tuple[Tensor, Tensor, Tensor]:
    """DreamerV3's KL loss per step: dyn_scale * max(free, KL(sg(post) || prior)) +
    rep_scale * max(free, KL(post || sg(prior))), each KL summed over all latents before the
    free-bits clip. Returns (loss, dyn KL, rep KL), each of the logits' leading shape."""
    post_log = torch.log(unimix_probs(post_logits, unimix))
    prior_log = torch.log(unimix_probs(prior_logits, unimix))
    dyn = categorical_kl(post_log.detach(), prior_log)
    rep = categorical_kl(post_log, prior_log.detach())
    loss = dyn_scale * dyn.clamp(min=free_nats) + rep_scale * rep.clamp(min=free_nats)
    return loss, dyn.detach(), rep.detach()


REWARD_BY_CLASS_FIELD = "reward_by_class"
"""Replay field (..., K) of the reward each class of `DreamerConfig.reward_relabel_head` would
have given on arriving at the step."""


def relabeled_reward(reward: Tensor, by_class: Tensor, choice: Tensor) -> Tensor:
    """Reward targets (B, T): step t's reward under the class chosen at step t - 1 (the state where
    the action that led to t was taken), `by_class[:, t, choice[:, t - 1]]`; the first step of each
    window, whose previous state the batch lacks, keeps its stored `reward`."""
    picked = by_class[:, 1:].gather(-1, choice[:, :-1].unsqueeze(-1).long()).squeeze(-1)
    return torch.cat((reward[:, :1], picked.to(reward.dtype)), 1)


@dataclass
class WorldModelOutput:
    """What one world-model loss evaluation returns to the trainer."""

    loss: Tensor  # scalar
    metrics: dict[str, Tensor]  # scalars, detached
    observed: Observed  # posterior states of the batch (for imagination starts)


class WorldModel(nn.Module):
    """Encoder + RSSM + decoder, reward, continue and registered extra heads."""

    def __init__(self, obs_size: int, action_size: int, config: DreamerConfig) -> None:
        super().__init__()
        c = config
        self.config = c
        self.encoder = MLP(obs_size, c.units, c.layers, c.norm_eps)
        self.rssm = RSSM(c, embed_size=c.units, action_size=action_size)
        self.decoder = latent_mlp(c, obs_size)
        self.reward_head = latent_mlp(c, c.bins, zero_output=True)
        self.continue_head = latent_mlp(c, 1)
        self.extra_heads = nn.ModuleDict({spec.name: build_head(spec, c) for spec in c.extra_heads})
        self.head_weights = {spec.name: spec.weight for spec in c.extra_heads}
        self.twohot = TwoHot(c.bins, c.bin_range)
        if c.reward_relabel_head is not None and c.reward_relabel_head not in self.extra_heads:
            raise ConfigError(f"reward_relabel_head {c.reward_relabel_head!r} is not one of the extra heads "
                              f"{sorted(self.extra_heads)}")

    def _apply(self, fn, recurse=True):  # keep the two-hot bins on the module's device
        result = super()._apply(fn, recurse)
        self.twohot = self.twohot.to(self.reward_head.out.weight.device)
        return result

    def embed(self, obs: Tensor) -> Tensor:
        """Observation embedding of raw vector observations (symlog applied here)."""
        return self.encoder(symlog(obs))

    def reward(self, latent: Latent) -> Tensor:
        """Predicted reward (raw scale) for arriving in state `latent`."""
        return self.twohot.mean(self.reward_head(latent))

    def continue_prob(self, latent: Latent) -> Tensor:
        """Predicted probability that the episode continues after state `latent`."""
        return torch.sigmoid(self.continue_head(latent).squeeze(-1).float())

    def predict_extra(self, latent: Latent) -> dict[str, Tensor]:
        """Run-time predictions of every extra head."""
        return {name: head.predict(latent) for name, head in self.extra_heads.items()}

    def loss(self, batch: Mapping[str, Tensor], generator: torch.Generator | None) -> WorldModelOutput:
        """World-model loss of a batch of sequences (B, T, ...): obs, action (taken at each
        observation), reward (received on arriving), is_first, is_terminal, and extra heads' fields."""
        c = self.config
        obs = batch["obs"]
        action = batch["action"]
        prev_actions = torch.cat((torch.zeros_like(action[:, :1]), action[:, :-1]), 1)
        embedding = self.embed(obs)
        observed = self.rssm.observe(embedding, prev_actions, batch["is_first"], generator)
        latent = observed.latent
        heads = [self.decoder, self.reward_head, self.continue_head]
        decoder_pre, reward_pre, continue_pre = first_layers(latent, heads)

        decoder_loss = (self.decoder.finish(decoder_pre).float() - symlog(obs)).square().sum(-1)
        reward_logits = self.reward_head.finish(reward_pre)
        reward_target, relabel_metrics = self._reward_target(latent, batch)
        reward_loss = self.twohot.loss(reward_logits, reward_target)
        continue_target = 1.0 - batch["is_terminal"].float()
        continue_logits = self.continue_head.finish(continue_pre).squeeze(-1).float()
        continue_loss = F.binary_cross_entropy_with_logits(continue_logits, continue_target, reduction="none")
        kl_loss, dyn, rep = kl_balance(
            observed.post_logits, observed.prior_logits, c.unimix, c.free_nats, c.kl_dyn_scale, c.kl_rep_scale
        )
        per_step = (
            c.decoder_scale * decoder_loss
            + c.reward_scale * reward_loss
            + c.continue_scale * continue_loss
            + kl_loss
        )
        metrics = {
            "wm/decoder_loss": decoder_loss.mean(),
            "wm/reward_loss": reward_loss.mean(),
            "wm/continue_loss": continue_loss.mean(),
            "wm/kl_dyn": dyn.mean(),
            "wm/kl_rep": rep.mean(),
            **self._terminal_fit(reward_logits, continue_logits, reward_target, batch),
            **relabel_metrics,
        }
        for name, head in self.extra_heads.items():
            head_loss, head_metrics = self._head_loss(name, head, latent, batch)
            per_step = per_step + self.head_weights[name] * head_loss
            metrics[f"wm/{name}_loss"] = head_loss.mean()
            metrics.update({f"wm/{name}_{key}": value for key, value in head_metrics.items()})
        loss = per_step.mean()
        metrics["wm/loss"] = loss
        return WorldModelOutput(
            loss=loss, metrics={k: v.detach() for k, v in metrics.items()}, observed=observed
        )

    def _reward_target(self, latent: Latent, batch: Mapping[str, Tensor]
                       ) -> tuple[Tensor, dict[str, Tensor]]:
        """The reward head's target: the stored reward, or (with `reward_relabel_head`) the reward
        under the class that head picks now from each step's previous posterior state, and the mean
        change that made (`wm/reward_relabel_change`)."""
        name = self.config.reward_relabel_head
        if name is None:
            return batch["reward"], {}
        if REWARD_BY_CLASS_FIELD not in batch:
            raise TrainingError(f"reward_relabel_head is set but the replay has no {REWARD_BY_CLASS_FIELD!r} field")
        with torch.no_grad():
            head = self.extra_heads[name]
            probs = head.predict(latent.detach())
            target = relabeled_reward(batch["reward"], batch[REWARD_BY_CLASS_FIELD], probs.argmax(-1))
            change = (target - batch["reward"]).abs().mean()
        return target, {"wm/reward_relabel_change": change}

    def _terminal_fit(self, reward_logits: Tensor, continue_logits: Tensor, reward_target: Tensor,
                      batch: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """How well the heads know the episode ends, the rare steps that carry a crash's penalty
        or the finish bonus (0 when the batch holds none): the mean predicted continue probability
        there (0 is perfect) and the reward error in symlog units."""
        with torch.no_grad():
            terminal = batch["is_terminal"].float()
            count = terminal.sum()
            denominator = count.clamp(min=1.0)
            cont = (torch.sigmoid(continue_logits) * terminal).sum() / denominator
            predicted = symlog(self.twohot.mean(reward_logits.float()))
            error = ((predicted - symlog(reward_target.float())).abs() * terminal).sum() / denominator
        return {"wm/terminal_steps": count, "wm/terminal_continue": cont, "wm/terminal_reward_error": error}

    @staticmethod
    def _head_loss(
        name: str, head: WorldModelHead, latent: Latent, batch: Mapping[str, Tensor]
    ) -> tuple[Tensor, dict[str, Tensor]]:
        missing = [field for field in head.fields if field not in batch]
        if missing:
            raise TrainingError(f"extra head {name!r} needs batch fields {missing}; observe() must provide them")
        loss, metrics = head.loss_and_metrics(latent, batch)
        return loss.float(), metrics
