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
        def predict(self, latent, embedding=None, observation=None):  # -> what callers need at run time
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
from .nets import MLP

HEAD_KINDS: dict[str, type[WorldModelHead]] = {}
"""Registered head kinds by name."""


EMBEDDING_FIELD = "embedding"
"""Batch key under which the world model hands its observation embeddings (B, T, units) to the
heads whose `reads_embedding` is set (a reserved name: no replay field may use it)."""


class WorldModelHead(nn.Module, ABC):
    """A prediction head on the model state, trained jointly with the world model."""

    #: batch fields the loss reads (checked when a batch lacks them)
    fields: tuple[str, ...] = ()
    #: whether the head also reads the encoder's embedding of the current observation: then its
    #: loss finds it in the batch under EMBEDDING_FIELD and `predict` gets it as `embedding`
    reads_embedding: bool = False
    #: whether the head reads the raw current observation: then its loss finds it in the batch
    #: under "obs" and `predict` gets it as `observation`
    reads_observation: bool = False

    def __init__(self, config: DreamerConfig) -> None:
        super().__init__()

    @abstractmethod
    def loss(self, latent: Latent, batch: Mapping[str, Tensor]) -> Tensor:
        """Per-step loss (B, T) for states of leading shape (B, T) and the batch's fields (B, T, ...)."""

    @abstractmethod
    def predict(self, latent: Latent, embedding: Tensor | None = None, observation: Tensor | None = None) -> Tensor:
        """Run-time prediction for states of any leading shape (and, for a head that reads them,
        the embedding of the observation the state was inferred from, or that observation)."""

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


CATEGORICAL_READS = ("latent", "latent+embedding", "observation_tail")
"""What a categorical head may read: the model state, the state plus the encoder's embedding of
the current observation, or the raw observation's last columns alone."""


@register_head("categorical")
class CategoricalHead(WorldModelHead):
    """Classifier p(y | s) trained by negative log-likelihood on an integer label field.
    Labels < 0 mean 'unknown' and are left out of the loss (partial labelling)."""

    def __init__(self, config: DreamerConfig, field: str = "label", classes: int = 2, reads: str = "latent",
                 tail: int = 0) -> None:
        super().__init__(config)
        if classes < 2:
            raise TypeError("classes must be at least 2")
        if reads not in CATEGORICAL_READS:
            raise TypeError(f"reads must be one of {list(CATEGORICAL_READS)}, got {reads!r}")
        if (reads == "observation_tail") != (tail > 0):
            raise TypeError(f"tail (> 0 columns) goes with reads='observation_tail' and only with it, got "
                            f"reads={reads!r}, tail={tail!r}")
        self.field = field
        self.fields = (field,)
        self.classes = classes
        self.tail = tail
        self.reads_embedding = reads == "latent+embedding"
        self.reads_observation = reads == "observation_tail"
        if self.reads_observation:
            # A classifier on the observation's last `tail` columns alone (e.g. the window of the
            # partner's actions): what the car's state shows, which the assistant's own actions
            # shape, cannot sway it.
            self.net = MLP(tail, config.units, config.layers, config.norm_eps, out_size=classes)
        else:
            self.net = latent_mlp(config, classes)
        # The embedding enters the MLP's first layer beside (h, z): a direct path from what the
        # encoder sees now (e.g. a window of the partner's actions) that the stochastic state
        # need not carry.
        self.embedding_in = nn.Linear(config.units, config.units, bias=False) if self.reads_embedding else None

    def _logits(self, latent: Latent, embedding: Tensor | None, observation: Tensor | None) -> Tensor:
        if self.reads_observation:
            if observation is None:
                raise TrainingError(f"head on field {self.field!r} reads the observation; none was given")
            if observation.shape[-1] < self.tail:
                raise TrainingError(f"head on field {self.field!r} reads the last {self.tail} observation "
                                    f"columns; the observation has {observation.shape[-1]}")
            return self.net(observation[..., -self.tail:].to(self.net.first.linear.weight.dtype))
        if self.embedding_in is None:
            return self.net(latent)
        if embedding is None:
            raise TrainingError(f"head on field {self.field!r} reads the observation embedding; none was given")
        pre = self.net.first(latent.h, latent.index, latent.probs)
        return self.net.finish(pre + self.embedding_in(embedding.to(pre.dtype)))

    def loss(self, latent: Latent, batch: Mapping[str, Tensor]) -> Tensor:
        return self.loss_and_metrics(latent, batch)[0]

    def loss_and_metrics(self, latent: Latent, batch: Mapping[str, Tensor]) -> tuple[Tensor, dict[str, Tensor]]:
        """NLL per step, and the accuracy of the most probable class over the known labels."""
        label = batch[self.field].long()
        if bool((label >= self.classes).any()):
            raise TrainingError(f"head field {self.field!r} has a label >= its {self.classes} classes")
        known = label >= 0
        logits = self._logits(latent, batch.get(EMBEDDING_FIELD), batch.get("obs"))
        log_probs = torch.log_softmax(logits.float(), -1)
        nll = -log_probs.gather(-1, label.clamp(min=0).unsqueeze(-1)).squeeze(-1)
        with torch.no_grad():
            correct = (log_probs.argmax(-1) == label) & known
            accuracy = correct.float().sum() / known.float().sum().clamp(min=1.0)
        return torch.where(known, nll, torch.zeros_like(nll)), {"accuracy": accuracy}

    def predict(self, latent: Latent, embedding: Tensor | None = None, observation: Tensor | None = None) -> Tensor:
        """Class probabilities (..., classes)."""
        return torch.softmax(self._logits(latent, embedding, observation).float(), -1)


@register_head("intent")
class IntentHead(CategoricalHead):
    """The assistant's intent head p(y_hat | s) over the intents of a pair (Dream2Assist's
    "intent predictor"), trained by negative log-likelihood on the index of the true intent of
    the episode's human in `intents` (the replay's `field`; < 0: unknown, left out).

    The paper predicts the symlog two-hot code of the integer label; a categorical over the
    pair's intents is the same prediction without an ordering between intents that do not have
    one, and its probabilities are the classifier's output that F1 and y_hat read directly.
    `predict` gives the probabilities (..., len(intents)); y_hat is their argmax. `reads`:
    "latent" (the paper's p(y_hat | s)), "latent+embedding" (also the encoder's embedding of
    the current observation) or "observation_tail" (only the observation's last `tail` columns,
    not the model state), see `CategoricalHead`."""

    def __init__(self, config: DreamerConfig, intents: Sequence[str], field: str = "intent",
                 reads: str = "latent", tail: int = 0) -> None:
        intents = tuple(intents)
        if len(intents) < 2 or len(set(intents)) != len(intents) or not all(isinstance(i, str) for i in intents):
            raise TypeError(f"intents must be at least two distinct names, got {list(intents)}")
        super().__init__(config, field=field, classes=len(intents), reads=reads, tail=tail)
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

    def predict(self, latent: Latent, embedding: Tensor | None = None, observation: Tensor | None = None) -> Tensor:
        """Predicted value (...)."""
        return self.twohot.mean(self.net(latent))
