"""Registry of extra world-model heads.

A head reads the model state (a `Latent`: h, and z as sample indices + probabilities; use
`LatentMLP`, or `latent.dense()` for concat(h, one-hot z)) and is trained with the world model
on a field of the replayed batch. To add one without touching the world model:

    @register_head("my_kind")
    class MyHead(WorldModelHead):
        def __init__(self, config, field="label"):
            super().__init__(config)
            self.field = field
            self.fields = (field,)
            self.net = latent_mlp(config, out_size=...)
        def loss(self, latent, batch):        # -> per-step loss (B, T)
            ...
        def predict(self, latent):             # -> what callers need at run time
            ...

then list it in the config: `DreamerConfig(extra_heads=[HeadConfig(name="intent",
kind="my_kind", weight=1.0, options={"field": "intent"})])`. The head's field must be present
in every transition given to `DreamerAgent.observe` (the replay stores any extra field). To log
scalars beside the loss (e.g. an accuracy, as `wm/<name>_<key>`), also override
`loss_and_metrics`, as `CategoricalHead` does.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from typing import TypeVar

import torch
from torch import Tensor, nn

from d2a_core.errors import ConfigError, TrainingError

from .config import DreamerConfig, HeadConfig
from .distributions import TwoHot
from .latent import Latent, LatentMLP

HEAD_KINDS: dict[str, type[WorldModelHead]] = {}
"""Registered head kinds by name."""


class WorldModelHead(nn.Module, ABC):
    """A prediction head on the model state, trained jointly with the world model."""

    #: batch fields the loss reads (checked when a batch lacks them)
    fields: tuple[str, ...] = ()

    def __init__(self, config: DreamerConfig) -> None:
        super().__init__()

    @abstractmethod
    def loss(self, latent: Latent, batch: Mapping[str, Tensor]) -> Tensor:
        """Per-step loss (B, T) for states of leading shape (B, T) and the batch's fields (B, T, ...)."""

    @abstractmethod
    def predict(self, latent: Latent) -> Tensor:
        """Run-time prediction for states of any leading shape."""

    def loss_and_metrics(self, latent: Latent, batch: Mapping[str, Tensor]) -> tuple[Tensor, dict[str, Tensor]]:
        """The per-step loss and scalar metrics (logged as `wm/<head name>_<key>`, e.g. an
        accuracy). The default reports none; override to report some without a second forward."""
        return self.loss(latent, batch), {}


def latent_mlp(config: DreamerConfig, out_size: int, zero_output: bool = False) -> LatentMLP:
    """A head MLP on the model state with the config's widths."""
    c = config
    return LatentMLP(c.deter, c.stoch_flat, c.units, c.layers, c.norm_eps, out_size, zero_output)


HeadType = TypeVar("HeadType", bound=type[WorldModelHead])


def register_head(kind: str) -> Callable[[HeadType], HeadType]:
    """Class decorator that makes a head buildable by `kind` from a `HeadConfig`."""

    def decorate(cls: HeadType) -> HeadType:
        known = HEAD_KINDS.get(kind)
        # The same class defined again (module reload, repeated test) may replace itself.
        if known is not None and (known.__module__, known.__qualname__) != (cls.__module__, cls.__qualname__):
            raise ValueError(f"head kind {kind!r} is already registered by {known.__qualname__}")
        HEAD_KINDS[kind] = cls
        return cls

    return decorate


def build_head(spec: HeadConfig, config: DreamerConfig) -> WorldModelHead:
    """Instantiate the head that `spec` names, passing its options as keyword arguments."""
    if spec.kind not in HEAD_KINDS:
        raise ConfigError(
            f"extra_heads: head {spec.name!r} has unknown kind {spec.kind!r}; registered: {sorted(HEAD_KINDS)}"
        )
    try:
        return HEAD_KINDS[spec.kind](config, **spec.options)
    except TypeError as error:
        raise ConfigError(f"extra_heads: head {spec.name!r} ({spec.kind}): bad options {spec.options}: {error}") from error


@register_head("categorical")
class CategoricalHead(WorldModelHead):
    """Classifier p(y | s) trained by negative log-likelihood on an integer label field.
    Labels < 0 mean 'unknown' and are left out of the loss (partial labelling)."""

    def __init__(self, config: DreamerConfig, field: str = "label", classes: int = 2) -> None:
        super().__init__(config)
        if classes < 2:
            raise TypeError("classes must be at least 2")
        self.field = field
        self.fields = (field,)
        self.classes = classes
        self.net = latent_mlp(config, classes)

    def loss(self, latent: Latent, batch: Mapping[str, Tensor]) -> Tensor:
        return self.loss_and_metrics(latent, batch)[0]

    def loss_and_metrics(self, latent: Latent, batch: Mapping[str, Tensor]) -> tuple[Tensor, dict[str, Tensor]]:
        """NLL per step, and the accuracy of the most probable class over the known labels."""
        label = batch[self.field].long()
        if bool((label >= self.classes).any()):
            raise TrainingError(f"head field {self.field!r} has a label >= its {self.classes} classes")
        known = label >= 0
        logits = self.net(latent)
        log_probs = torch.log_softmax(logits.float(), -1)
        nll = -log_probs.gather(-1, label.clamp(min=0).unsqueeze(-1)).squeeze(-1)
        with torch.no_grad():
            correct = (log_probs.argmax(-1) == label) & known
            accuracy = correct.float().sum() / known.float().sum().clamp(min=1.0)
        return torch.where(known, nll, torch.zeros_like(nll)), {"accuracy": accuracy}

    def predict(self, latent: Latent) -> Tensor:
        """Class probabilities (..., classes)."""
        return torch.softmax(self.net(latent).float(), -1)


@register_head("intent")
class IntentHead(CategoricalHead):
    """The assistant's intent head p(y_hat | s) over the intents of a pair (Dream2Assist's
    "intent predictor"), trained by negative log-likelihood on the index of the true intent of
    the episode's human in `intents` (the replay's `field`; < 0: unknown, left out).

    The paper predicts the symlog two-hot code of the integer label; a categorical over the
    pair's intents is the same prediction without an ordering between intents that do not have
    one, and its probabilities are the classifier's output that F1 and y_hat read directly.
    `predict` gives the probabilities (..., len(intents)); y_hat is their argmax. It reads the
    model state, as the paper's p(y_hat | s) does (what else it could read, and why it does not:
    docs/experiments/intent-estimate.md)."""

    def __init__(self, config: DreamerConfig, intents: Sequence[str], field: str = "intent") -> None:
        intents = tuple(intents)
        if len(intents) < 2 or len(set(intents)) != len(intents) or not all(isinstance(i, str) for i in intents):
            raise TypeError(f"intents must be at least two distinct names, got {list(intents)}")
        super().__init__(config, field=field, classes=len(intents))
        self.intents = intents


@register_head("twohot")
class TwoHotHead(WorldModelHead):
    """Scalar regression p(y | s) with the symlog two-hot code (like the reward head)."""

    def __init__(self, config: DreamerConfig, field: str = "target") -> None:
        super().__init__(config)
        self.field = field
        self.fields = (field,)
        self.net = latent_mlp(config, config.bins, zero_output=True)
        self.twohot = TwoHot(config.bins, config.bin_range)

    def _apply(self, fn, recurse=True):  # keep the bins on the module's device
        result = super()._apply(fn, recurse)
        self.twohot = self.twohot.to(self.net.out.weight.device)
        return result

    def loss(self, latent: Latent, batch: Mapping[str, Tensor]) -> Tensor:
        return self.twohot.loss(self.net(latent), batch[self.field].float())

    def predict(self, latent: Latent) -> Tensor:
        """Predicted value (...)."""
        return self.twohot.mean(self.net(latent))
