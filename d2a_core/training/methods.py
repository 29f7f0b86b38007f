"""The assistant methods the paper compares, selected by name (torch-free).

Each method is one row of the paper's comparison (section 4 and appendix; DESIGN.md section 1):

| name | intent head | alpha_r | alpha_a | agent |
|---|---|---|---|---|
| `dream2assist` | yes | 1 | 0 | DreamerV3 with an intent head (the main method) |
| `dream2assist+a` | yes | 1 | 1 | the same, plus the distance to the expert's action |
| `dream2assist+a-r` | yes | 0 | 1 | the distance to the expert's action only |
| `dreamer` | no | 0 | 0 | DreamerV3 on task + intervention reward (FCP-style) |
| `no-rssm` | auxiliary classifier | 1 | 0 | 16-frame window, model-free actor-critic (PPO), `agents.baselines.no_rssm` |
| `dreamer-ail` | no | 0 | 0 | a residual trained by adversarial imitation of the experts (GAIL on PPO), `agents.baselines.dreamer_ail` |

A method names its agent's builder lazily (`entry_point = "module:function"`, as Gymnasium
does), so reading the registry (the CLI checking `--method`) imports no torch. A builder is called
as `build(section, obs_space, act_space, intents, seed, device)` with the method's own config
section (`agent_section`) and returns an `AssistantAgent` (`d2a_core.agents.protocol`). `configure` applies the method's
row to a resolved config (the reward weights, the intent head), so a method's run key, made
from the `config_sections` of the patched config, differs from every other method's.

Adding a method is one `register_method(Method(...))` in the module that holds its agent (or
here, for the paper's own rows).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from importlib import import_module
from typing import Any, Optional

from d2a_core.errors import UsageError

DREAMER_AGENT = "d2a_core.agents.dreamer.agent:build_assistant"

# What every assistant's run depends on besides its own learner: the simulator, r^task and the
# assistant's reward weights. The populations enter the run key as input artifacts, not config.
_COMMON_SECTIONS = ("env", "reward", "vehicle", "world", "assistant")

INTENT_HEAD_NAME = "intent"
"""Name of the intent head in the world model (its metrics are `wm/intent_*`) and of the replay
field that carries the label (the index of the human's intent in the pair)."""

METHOD_SET_KEYS = frozenset({"assistant.reward.alpha_r", "assistant.reward.alpha_a", "dreamer.extra_heads",
                             "dreamer.reward_relabel_head", "dreamer.action_cost"})
"""Config keys `Method.configure` sets from the method's row (so a record's value there is the
method's, not a user override)."""

ASSISTANT_DREAMER_KEYS = {"train_ratio": "train_ratio", "imag_starts": "imag_starts"}
"""`assistant.<key>` -> the `dreamer.<key>` it replaces in a Dreamer-family assistant's learner
(the `dreamer` section is shared with the populations, so the assistant's own values live here)."""


def assistant_dreamer_overrides(assistant: Any) -> dict[str, Any]:
    """The `dreamer.*` values an `assistant` section sets for a Dreamer-family learner (its keys
    of `ASSISTANT_DREAMER_KEYS` that are not None)."""
    return {target: getattr(assistant, key) for key, target in ASSISTANT_DREAMER_KEYS.items()
            if getattr(assistant, key) is not None}


@dataclass(frozen=True)
class Method:
    """One assistant method: its row of the paper's table and where its agent lives."""

    name: str
    intent_head: bool  # learns p(y_hat | s) from the human's intent label
    alpha_r: Optional[float]  # weight of r_hat*(y_hat); None: the method has its own reward
    alpha_a: Optional[float]  # weight of ||a_H + a_A - a*(y_hat)||; None: as alpha_r
    config_sections: tuple[str, ...]  # top-level config sections its run key depends on
    entry_point: str  # "module:function" building its agent, imported only by `builder`
    agent_section: str = "dreamer"  # the config section handed to the builder
    implemented: bool = True
    # learns from the experts' demonstrations: its section has `demo_episodes`, its agent
    # `set_demonstrations(obs, action)` (d2a_core.training.demonstrations)
    demonstrations: bool = False
    description: str = ""

    @property
    def labels(self) -> tuple[str, ...]:
        """Per-step label fields its learner trains on (to be given to the agent's `observe`)."""
        return (INTENT_HEAD_NAME,) if self.intent_head else ()

    @property
    def uses_experts(self) -> bool:
        """Whether its reward queries the experts (r_hat* or a*), so they must be filtered."""
        return bool(self.alpha_r) or bool(self.alpha_a)

    def relabels_reward(self, config: Any) -> bool:
        """Whether its learner takes each replayed step's reward under its current intent estimate
        (`dreamer.reward_relabel_head`), so the replay must carry the reward under each intent."""
        return self.entry_point == DREAMER_AGENT and config.dreamer.reward_relabel_head is not None

    def builder(self) -> Any:
        """Import and return the agent builder of `entry_point`."""
        _require_implemented(self)
        module, _, attribute = self.entry_point.partition(":")
        return getattr(import_module(module), attribute)

    def build_agent(self, config: Any, obs_space: Any, act_space: Any, intents: Sequence[str], seed: int,
                    device: str = "cpu") -> Any:
        """The method's agent for a root `config` already patched by `configure`."""
        section = getattr(config, self.agent_section)
        return self.builder()(section, obs_space, act_space, tuple(intents), seed, device)

    def configure(self, config: Any, intents: Sequence[str]) -> Any:
        """The root config with this method's row applied: `assistant.reward.alpha_r/alpha_a`
        set; for a Dreamer-family method, the assistant's own learner settings
        (`assistant.train_ratio`, `assistant.imag_starts`) in its `dreamer`
        section; and with an intent head, an `intent` head over `intents` (weight `assistant.intent_scale`) appended to
        `dreamer.extra_heads`, and `dreamer.reward_relabel_head` set when `assistant.reward_relabel`
        is on and the reward has expert terms."""
        _require_implemented(self)
        if len(intents) < 2 or len(set(intents)) != len(intents):
            raise UsageError(f"method {self.name!r}: a pair needs at least two distinct intents, got {list(intents)}")
        assistant = config.assistant
        dreamer_head = self.intent_head and self.entry_point == DREAMER_AGENT
        if config.dreamer.reward_relabel_head is not None:
            raise UsageError(f"dreamer.reward_relabel_head={config.dreamer.reward_relabel_head!r}: the method "
                             "sets it; use assistant.reward_relabel=true")
        if config.dreamer.action_cost:
            raise UsageError(f"dreamer.action_cost={config.dreamer.action_cost!r}: the method sets it; use "
                             "assistant.exact_intervention=true")
        reward = assistant.reward.model_copy(update={"alpha_r": self.alpha_r, "alpha_a": self.alpha_a})
        update: dict[str, Any] = {"assistant": assistant.model_copy(update={"reward": reward})}
        # the Dreamer learner's changes, applied to `dreamer` in one copy at the end
        learner = assistant_dreamer_overrides(assistant) if self.entry_point == DREAMER_AGENT else {}
        if dreamer_head and self.uses_experts and assistant.reward_relabel:
            learner["reward_relabel_head"] = INTENT_HEAD_NAME
        if self.entry_point == DREAMER_AGENT and assistant.exact_intervention and reward.w_interv:
            learner["action_cost"] = reward.w_interv
        if dreamer_head:
            heads = config.dreamer.extra_heads
            if any(head.name == INTENT_HEAD_NAME for head in heads):
                raise UsageError(f"method {self.name!r}: dreamer.extra_heads already has a head named 'intent'")
            from d2a_core.agents.dreamer.config import HeadConfig  # pydantic only, no torch

            options: dict[str, Any] = {"field": INTENT_HEAD_NAME, "intents": list(intents)}
            head = HeadConfig(name=INTENT_HEAD_NAME, kind="intent", weight=assistant.intent_scale, options=options)
            learner["extra_heads"] = [*heads, head]
        if learner:
            update["dreamer"] = config.dreamer.model_copy(update=learner)
        return config.model_copy(update=update)


METHODS: dict[str, Method] = {}
"""Every registered method by name, implemented or not (see `get_method`)."""


def register_method(method: Method) -> Method:
    """Add a method to the registry; a name may be registered once."""
    if method.name in METHODS and METHODS[method.name] != method:
        raise ValueError(f"method {method.name!r} is already registered")
    if ":" not in method.entry_point:
        raise ValueError(f"method {method.name!r}: entry_point must be 'module:Class', got {method.entry_point!r}")
    METHODS[method.name] = method
    return method


def method_names(implemented_only: bool = False) -> list[str]:
    """Registered method names, in registration order."""
    return [name for name, m in METHODS.items() if m.implemented or not implemented_only]


def get_method(name: str) -> Method:
    """The method called `name`. Raises UsageError (exit 2) for an unknown name, listing the
    registered ones, and for a method that is registered but not built yet."""
    if name not in METHODS:
        raise UsageError(f"unknown method {name!r}; registered: {', '.join(method_names())}")
    method = METHODS[name]
    _require_implemented(method)
    return method


def _require_implemented(method: Method) -> None:
    if not method.implemented:
        raise UsageError(
            f"method {method.name!r} is registered but not implemented yet (its agent will be "
            f"{method.entry_point}); implemented: {', '.join(method_names(implemented_only=True))}"
        )


_DREAMER_SECTIONS = (*_COMMON_SECTIONS, "dreamer")

for _method in (
    Method("dream2assist", True, 1.0, 0.0, _DREAMER_SECTIONS, DREAMER_AGENT,
           description="DreamerV3 with an intent head; reward: task, intervention, the inferred expert's reward"),
    Method("dream2assist+a", True, 1.0, 1.0, _DREAMER_SECTIONS, DREAMER_AGENT,
           description="dream2assist plus the distance to the inferred expert's action"),
    Method("dream2assist+a-r", True, 0.0, 1.0, _DREAMER_SECTIONS, DREAMER_AGENT,
           description="dream2assist with the distance to the inferred expert's action instead of its reward"),
    Method("dreamer", False, 0.0, 0.0, _DREAMER_SECTIONS, DREAMER_AGENT,
           description="DreamerV3 on task and intervention reward only (FCP-style partner training)"),
    Method("no-rssm", True, 1.0, 0.0, (*_COMMON_SECTIONS, "no_rssm"),
           "d2a_core.agents.baselines.no_rssm:build_assistant", agent_section="no_rssm",
           description="no world model: a 16-frame observation window, model-free actor-critic, "
                       "an auxiliary intent classifier"),
    Method("dreamer-ail", False, 0.0, 0.0, (*_COMMON_SECTIONS, "dreamer_ail"),
           "d2a_core.agents.baselines.dreamer_ail:build_assistant", agent_section="dreamer_ail", demonstrations=True,
           description="a residual trained by adversarial imitation of the experts' driving "
                       "(BeTAIL's AIL assistant beside a Dreamer human); reward: the discriminator's alone"),
):
    register_method(_method)
del _method
