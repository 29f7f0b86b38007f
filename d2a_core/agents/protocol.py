"""What a trainable assistant looks like to the collector and the evaluator (torch-free).

The assistant trainer (`d2a_core.training.assistant`) and the paired evaluation are typed to
this protocol, not to DreamerV3, so a model-free baseline plugs in without subclassing Dreamer.
Every array is numpy, batched over N environments; actions are in the env's units.

Record protocol (DreamerV3's, see `DreamerAgent`): every environment step is one record
`{"obs": (N, D), "reward": (N,), "is_first": (N,), "is_terminal": (N,)}`; `reward` is what
arriving at `obs` paid. The runner calls

    actions, state = agent.policy(record, state, explore)   # also on an episode's last record
    probs = agent.intent_probs(state)                       # (N, K) or None: the inferred intent
    agent.observe({**record, "action": actions, "intent": labels})   # labels only when training
    for _ in range(agent.updates_due(total_env_steps)):
        metrics = agent.train_step()

The intent label reaches `observe` only as a training target; `policy` never sees it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class AssistantAgent(Protocol):
    """An agent the assistant trainer can train, checkpoint and evaluate."""

    def initial_state(self, batch_size: int) -> Any:
        """Recurrent state before the first observation of `batch_size` environments."""

    def policy(self, obs_batch: Mapping[str, np.ndarray], state: Any = None,
               explore: bool = True) -> tuple[np.ndarray, Any]:
        """Actions (N, A) for a batch; `obs_batch["is_first"]` resets those environments' state."""

    def intent_probs(self, state: Any) -> np.ndarray | None:
        """p(y_hat | state) (N, K) over the pair's intents at the current state, or None for an
        agent without an intent estimate."""

    def observe(self, transition: Mapping[str, np.ndarray]) -> None:
        """Store one record of every environment, with the action taken and any label fields."""

    def updates_due(self, env_steps: int) -> int:
        """How many `train_step` calls are due after `env_steps` environment steps in total."""

    def train_step(self) -> dict[str, float]:
        """One update; returns scalar metrics (losses, the intent classifier's accuracy...)."""

    def state_dict(self, include_replay: bool = False) -> dict[str, Any]:
        """Everything needed to resume exactly (the replay or rollout buffer only when asked)."""

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore a `state_dict`."""
