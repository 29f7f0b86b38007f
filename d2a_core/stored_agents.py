"""Stored drivers and assistants as ready-to-act agents: a `human` checkpoint or an `assistant`
artifact, checked and loaded for the env it will act in.

Torch-free at import: torch and the learners are imported when an agent is loaded, so the layers
above (training, pipelines, the Python API) can import this module without starting a learner.
Checkpoint files are read only through the restricted unpickler (`training.torch_files`):
nothing in a store can run code.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from d2a_core.artifacts import Artifact, Store
from d2a_core.errors import UsageError
from d2a_core.run_inputs import parse_pair

if TYPE_CHECKING:
    from d2a_core.agents.dreamer.agent import DreamerAgent
    from d2a_core.sim.env_config import EnvConfig
    from d2a_core.training.methods import Method

_NOT_OURS = "the store holds a file that d2a did not write; remove the artifact or the store"


def trained_env_config(art: Artifact) -> "EnvConfig":
    """The env settings a human checkpoint was trained in (its manifest's `env` section)."""
    from d2a_core.sim.env_config import EnvConfig

    return EnvConfig.model_validate((art.config or {}).get("env", {}))


def load_human(store: Store, ref: str, obs_space, act_space, device: str = "cpu") -> "DreamerAgent":
    """A stored human checkpoint as a ready-to-act agent (on `device`)."""
    from d2a_core.agents.dreamer.agent import DreamerAgent
    from d2a_core.agents.dreamer.config import DreamerConfig
    from d2a_core.sim.race_env import observation_names
    from d2a_core.training.torch_files import load_torch

    art = store.get(ref)
    if art.kind != "human":
        raise UsageError(f"{ref} is a {art.kind} artifact, not a human checkpoint")
    trained = trained_env_config(art)
    names = observation_names(trained.edge_lookahead_m)
    if len(names) != int(np.prod(obs_space.shape)):
        raise UsageError(
            f"human {art.id[:12]} was trained on observations of {len(names)} values "
            f"(env.edge_lookahead_m={trained.edge_lookahead_m}), this env gives {int(np.prod(obs_space.shape))}: "
            "use the env settings its population was trained with (--set env.edge_lookahead_m=...)")
    state = load_torch(store.path(art.id, "agent.pt"), f"human checkpoint {art.id[:12]} file 'agent.pt'", device,
                       _NOT_OURS)
    config = DreamerConfig.model_validate({**state["config"], "device": device})
    agent = DreamerAgent(obs_space, act_space, config, seed=0)
    agent.load_state_dict(state)
    return agent


def load_assistant(store: Store, ref: str, obs_space, act_space,
                   device: str = "cpu") -> tuple[Any, "Method", tuple[str, ...], int]:
    """A stored assistant checkpoint as a ready-to-act agent, with its method, pair and partner
    window: (agent, method, intents, partner_window). `obs_space` is the env's; the learner's
    config and the window come from the artifact's recorded config."""
    from d2a_core.config.schema import Config  # the section classes, to validate the recorded one
    from d2a_core.training.methods import get_method
    from d2a_core.training.partner_window import assistant_observation_space
    from d2a_core.training.torch_files import load_torch

    art = store.get(ref)
    if art.kind != "assistant":
        raise UsageError(f"{ref} is a {art.kind} artifact, not an assistant")
    method = get_method(art.labels["method"])
    intents = parse_pair(art.labels["pair"])
    section_type = type(getattr(Config(), method.agent_section))
    section = section_type.model_validate(art.config[method.agent_section])
    window = int(art.config.get("assistant", {}).get("partner_window", 1))
    agent = method.builder()(section, assistant_observation_space(obs_space, window), act_space, intents, 0, device)
    state = load_torch(store.path(art.id, "agent.pt"), f"assistant {art.id[:12]} file 'agent.pt'", device, _NOT_OURS)
    agent.load_state_dict(state)
    return agent, method, intents, window
