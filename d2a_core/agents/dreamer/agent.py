"""DreamerAgent: acting for a batch of environments, replay, train-ratio schedule, updates and
exact checkpoint state. The agent sees numpy arrays and gymnasium spaces, never a simulator.

Interaction protocol (DreamerV3's): every environment step is one record
`{"obs", "reward", "is_first", "is_terminal", [extra fields]}`; `reward` is what arriving at
`obs` paid (0 on the first step of an episode). The runner calls

    actions, state = agent.policy(step, state)           # acts on every record, last ones too
    agent.observe({**step, "action": actions})           # the action taken at `obs`
    for _ in range(agent.updates_due(total_env_steps)):
        metrics = agent.train_step()

and after an episode ends (terminated or truncated) the next record of that environment is
its reset observation with `is_first = True`; the action chosen on the final record is ignored.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import Tensor, nn

from d2a_core.config.section import record, stored_dump
from d2a_core.errors import ConfigError, TrainingError, UsageError

from .behavior import Behavior
from .config import DreamerConfig
from .latent import Latent
from .replay import SequenceReplay
from .world_model import REWARD_BY_CLASS_FIELD, WorldModel

_CORE_FIELDS = ("obs", "reward", "is_first", "is_terminal")
_SHAPE_FIELDS = ("units", "layers", "deter", "stoch", "classes", "bins", "extra_heads", "learned_initial_state")


@dataclass
class PolicyState:
    """Recurrent state of a batch of environments: model state after the last observation
    and the (internal, [-1, 1] or one-hot) action taken there."""

    latent: Latent
    action: Tensor


class DreamerAgent:
    """DreamerV3 agent for a flat Box observation space and a Box or Discrete action space."""

    def __init__(
        self,
        obs_space: gym.spaces.Space,
        act_space: gym.spaces.Space,
        config: DreamerConfig | None = None,
        seed: int = 0,
    ) -> None:
        self.config = config or DreamerConfig()
        self.device = torch.device(self.config.device)
        if not isinstance(obs_space, gym.spaces.Box):
            raise ConfigError(f"DreamerAgent needs a Box observation space, got {obs_space}")
        self.obs_size = int(np.prod(obs_space.shape))
        self.discrete = isinstance(act_space, gym.spaces.Discrete)
        if self.discrete:
            self.action_size = int(act_space.n)
            self._action_start = int(act_space.start)
        elif isinstance(act_space, gym.spaces.Box):
            low, high = np.broadcast_arrays(act_space.low, act_space.high)
            if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
                raise ConfigError("DreamerAgent needs a bounded Box action space")
            self.action_size = int(np.prod(act_space.shape))
            self._action_low = low.reshape(-1).astype(np.float32)
            self._action_span = (high - low).reshape(-1).astype(np.float32)
            self._action_shape = act_space.shape
        else:
            raise ConfigError(f"DreamerAgent needs a Box or Discrete action space, got {act_space}")

        # Initialise weights from `seed` without disturbing the caller's global RNG.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.world_model = WorldModel(self.obs_size, self.action_size, self.config).to(self.device)
            self.behavior = Behavior(self.action_size, self.discrete, self.config).to(self.device)
        c = self.config
        # Built on first use (`_optimizers`): constructing torch's Adam imports torch._dynamo, seconds
        # that an agent loaded only to act (eval, intent-swap) would pay for nothing.
        self._built_optimizers: dict[str, torch.optim.Optimizer] | None = None
        self._pending_optimizer_state: Mapping[str, Any] | None = None
        self.train_generator = torch.Generator(self.device).manual_seed(seed * 3 + 1)
        self.act_generator = torch.Generator(self.device).manual_seed(seed * 3 + 2)
        self.replay = SequenceReplay(c.replay_capacity, seed * 3 + 3)
        self.updates_done = 0
        # ||a|| of each stream's last observed action: the charge (`action_cost`) that the next
        # reward contains (episodes start afresh after a resume, so it is not checkpointed)
        self._last_action_norm: np.ndarray | None = None

    # --- optimisers

    def _optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The three Adam optimisers, built when first needed, with any state loaded before then."""
        if self._built_optimizers is None:
            c = self.config
            optimizers = {
                "model": torch.optim.Adam(_model_param_groups(self.world_model, c), lr=c.model_lr, eps=c.model_eps,
                                          fused=True),
                "actor": torch.optim.Adam(self.behavior.actor.parameters(), lr=c.actor_lr, eps=c.actor_eps,
                                          fused=True),
                "critic": torch.optim.Adam(self.behavior.critic.parameters(), lr=c.critic_lr, eps=c.critic_eps,
                                           fused=True),
            }
            if self._pending_optimizer_state is not None:
                for name, optimizer in optimizers.items():
                    optimizer.load_state_dict(self._pending_optimizer_state[name])
                self._pending_optimizer_state = None
            self._built_optimizers = optimizers
        return self._built_optimizers

    @property
    def model_opt(self) -> torch.optim.Optimizer:
        return self._optimizers()["model"]

    @property
    def actor_opt(self) -> torch.optim.Optimizer:
        return self._optimizers()["actor"]

    @property
    def critic_opt(self) -> torch.optim.Optimizer:
        return self._optimizers()["critic"]

    # --- acting

    def initial_state(self, batch_size: int) -> PolicyState:
        """State before the first observation of `batch_size` environments."""
        with torch.no_grad():
            latent = self.world_model.rssm.initial(batch_size)
            action = torch.zeros(batch_size, self.action_size, device=self.device)
        return PolicyState(Latent(*(x.contiguous() for x in latent)), action)

    @torch.no_grad()
    def policy(
        self,
        obs_batch: Mapping[str, np.ndarray],
        state: PolicyState | None = None,
        explore: bool = True,
        generator: torch.Generator | None = None,
    ) -> tuple[np.ndarray, PolicyState]:
        """Actions for a batch of environments. `obs_batch["obs"]` is (N, *obs_shape);
        `obs_batch["is_first"]` (N,) resets those environments' state (all are reset when
        `state` is None). Samples the actor when `explore`, else takes its mode. Latent and
        action samples draw from `generator` (default: the agent's own acting generator)."""
        generator = self.act_generator if generator is None else generator
        obs = self._tensor(obs_batch["obs"], torch.float32).reshape(-1, self.obs_size)
        n = obs.shape[0]
        if state is None:
            state = self.initial_state(n)
        elif "is_first" in obs_batch:
            first = self._tensor(obs_batch["is_first"], torch.bool).reshape(n)
            if bool(first.any()):
                fresh = self.initial_state(n)
                state = PolicyState(
                    Latent.where(first, fresh.latent, state.latent),
                    torch.where(first.unsqueeze(-1), fresh.action, state.action),
                )
        rssm = self.world_model.rssm
        h = rssm.step(state.latent, state.action)
        embedding = self.world_model.embed(obs)
        logits = rssm.posterior_logits(h, embedding)
        feat = rssm.sample(h, logits, rssm.uniform((n,), generator, self.device))
        actor = self.behavior.actor
        if explore:
            noise = actor.noise((n,), generator, self.device)
            action, _ = actor.sample(feat, noise)
        else:
            action = actor.mode(feat)
        new_state = PolicyState(feat, action.float())
        return self._to_env_action(new_state.action), new_state

    @torch.no_grad()
    def intent_probs(self, state: PolicyState) -> np.ndarray | None:
        """The intent head's p(y_hat | s) (N, K) at `state`, or None without an intent head
        (the head named "intent", as the method registry adds it)."""
        heads = self.world_model.extra_heads
        if "intent" not in heads:
            return None
        return heads["intent"].predict(state.latent).float().cpu().numpy()

    def features(self, state: PolicyState) -> np.ndarray:
        """The model state's deterministic part h (N, deter): what the report's t-SNE of
        latent states embeds."""
        return state.latent.h.float().cpu().numpy()

    def with_action(self, state: PolicyState, env_actions: np.ndarray) -> PolicyState:
        """The same state with another action taken (e.g. a blended human+assistant action), so
        that the next `policy` call conditions on what was really executed."""
        return PolicyState(state.latent, self._to_internal_action(env_actions))

    @torch.no_grad()
    def predict(self, state: PolicyState) -> dict[str, Tensor]:
        """World-model predictions at the current state: reward, continue probability and every
        extra head (e.g. an intent classifier's probabilities)."""
        latent = state.latent
        out = {"reward": self.world_model.reward(latent), "continue": self.world_model.continue_prob(latent)}
        out.update(self.world_model.predict_extra(latent))
        return out

    # --- data

    def observe(self, transition: Mapping[str, np.ndarray]) -> None:
        """Add one step of every environment to replay: obs, action (taken at obs, env format),
        reward, is_first, is_terminal, plus any extra fields (e.g. labels for extra heads)."""
        missing = [key for key in (*_CORE_FIELDS, "action") if key not in transition]
        if missing:
            raise UsageError(f"observe: transition lacks fields {missing}")
        n = np.asarray(transition["obs"]).shape[0]
        step: dict[str, np.ndarray] = {
            "obs": np.asarray(transition["obs"], np.float32).reshape(n, self.obs_size),
            "action": self._internal_action_array(transition["action"]),
            "reward": np.asarray(transition["reward"], np.float32).reshape(n),
            "is_first": np.asarray(transition["is_first"], bool).reshape(n),
            "is_terminal": np.asarray(transition["is_terminal"], bool).reshape(n),
        }
        for key, value in transition.items():
            if key not in step:
                step[key] = np.asarray(value)
        if self.config.action_cost:
            self._take_out_action_charge(step)
        self.replay.add(step)

    def _take_out_action_charge(self, step: dict[str, np.ndarray]) -> None:
        """Add back to the step's reward (and its per-class rewards) the charge -w * ||a|| of the
        stream's previous action, which imagination adds exactly (`DreamerConfig.action_cost`).
        The first step of an episode pays no charge (no action led to it)."""
        n = step["reward"].shape[0]
        last = self._last_action_norm if self._last_action_norm is not None else np.zeros(n)
        charge = self.config.action_cost * np.where(step["is_first"], 0.0, last)
        step["reward"] = (step["reward"] + charge).astype(np.float32)
        if REWARD_BY_CLASS_FIELD in step:
            by_class = np.asarray(step[REWARD_BY_CLASS_FIELD])
            step[REWARD_BY_CLASS_FIELD] = (by_class + charge.reshape(n, *([1] * (by_class.ndim - 1)))).astype(by_class.dtype)
        self._last_action_norm = np.linalg.norm(step["action"].astype(np.float64), axis=-1)

    def updates_due(self, env_steps: int) -> int:
        """Updates to run now so that, after `prefill_steps`, replayed steps per environment
        step equal `train_ratio` (updates = train_ratio / (batch_size * batch_length) per env step).
        `env_steps` counts steps of all environments together."""
        c = self.config
        if env_steps < c.prefill_steps or not self.replay.can_sample(c.batch_length):
            return 0
        target = math.floor((env_steps - c.prefill_steps) * c.train_ratio / c.replayed_steps_per_update) + 1
        return max(0, target - self.updates_done)

    # --- training

    def train_step(self) -> dict[str, float]:
        """One world-model update on a replayed batch and one actor-critic update from its states.

        Raises TrainingError before any optimiser step whose loss or gradient is not finite,
        so the parameters stay as they were."""
        c = self.config
        started = time.perf_counter()
        batch, wm_out, model_norm = self.world_model_update()
        world_model_done = time.perf_counter()

        start = wm_out.observed.latent.detach().reshape(-1)
        start_continue = 1.0 - batch["is_terminal"].float().reshape(-1)
        beh = self.behavior.losses(self.world_model, start, start_continue, self.train_generator)
        self._check_finite({"actor/loss": beh.actor_loss, "critic/loss": beh.critic_loss}, beh.metrics)
        actor_params = list(self.behavior.actor.parameters())
        critic_params = list(self.behavior.critic.parameters())
        self.actor_opt.zero_grad(set_to_none=True)
        self.critic_opt.zero_grad(set_to_none=True)
        # One forward pass serves both losses, so each is differentiated only with respect to
        # its own parameters: the critic's loss must not move the imagined states (the actor),
        # and the actor's returns must not train the critic (see Behavior._imagine).
        torch.autograd.backward(beh.actor_loss, inputs=actor_params, retain_graph=True)
        torch.autograd.backward(beh.critic_loss, inputs=critic_params)
        actor_norm = self._clip(actor_params, c.actor_grad_clip, "actor")
        critic_norm = self._clip(critic_params, c.critic_grad_clip, "critic")
        self.actor_opt.step()
        self.critic_opt.step()
        self.behavior.return_norm.commit(beh.norm_low, beh.norm_high)
        self.updates_done += 1
        if self.updates_done % c.slow_critic_every == 0:
            self.behavior.update_slow_critic()

        metrics = {**wm_out.metrics, **beh.metrics}
        metrics.update({"wm/grad_norm": model_norm, "actor/grad_norm": actor_norm, "critic/grad_norm": critic_norm})
        names = list(metrics)
        values = torch.stack([metrics[name].float().reshape(()) for name in names]).tolist()
        result = dict(zip(names, values))
        # Wall-clock phases (on CUDA only exact after a synchronisation, which the caller owns).
        result["time/world_model_s"] = world_model_done - started
        result["time/behavior_s"] = time.perf_counter() - world_model_done
        return result

    def world_model_update(self) -> tuple[dict[str, Tensor], Any, Tensor]:
        """One world-model update on a freshly replayed batch: (batch, loss output, grad norm).
        `train_step` runs one; offline tools (docs/analysis/wm_offline.py) train the world model
        alone with it."""
        c = self.config
        batch = {
            key: torch.as_tensor(value, device=self.device)
            for key, value in self.replay.sample(c.batch_size, c.batch_length).items()
        }
        wm_out = self.world_model.loss(batch, self.train_generator)
        self._check_finite({"wm/loss": wm_out.loss}, wm_out.metrics)
        self.model_opt.zero_grad(set_to_none=True)
        wm_out.loss.backward()
        model_norm = self._clip(self.world_model.parameters(), c.model_grad_clip, "world model")
        self.model_opt.step()
        return batch, wm_out, model_norm

    @staticmethod
    def _check_finite(losses: Mapping[str, Tensor], metrics: Mapping[str, Tensor]) -> None:
        bad = [name for name, value in losses.items() if not bool(torch.isfinite(value))]
        if bad:
            detail = ", ".join(f"{k}={float(v):.4g}" for k, v in metrics.items())
            raise TrainingError(f"non-finite loss {bad}; no update applied ({detail})")

    @staticmethod
    def _clip(params, max_norm: float, name: str) -> Tensor:
        norm = nn.utils.clip_grad_norm_(params, max_norm)
        if not bool(torch.isfinite(norm)):
            raise TrainingError(f"non-finite {name} gradient norm; no {name} update applied")
        return norm

    # --- checkpoint state

    def state_dict(self, include_replay: bool = False) -> dict[str, Any]:
        """Everything needed to resume exactly: networks (world model, actor, critic, slow
        critic), optimisers, return-normaliser statistics, RNG states and the update count.
        The replay's contents are included only when asked (they can be large); its RNG always."""
        state: dict[str, Any] = {
            "format": 1,
            # the config *record*: settings added later at their neutral value are left out and
            # retired ones kept as recorded, so adding or retiring a knob leaves checkpoints (and
            # the ids of the artifacts holding them) byte-identical
            "config": record(self.config),
            "world_model": self.world_model.state_dict(),
            "behavior": self.behavior.state_dict(),
            "optimizers": self._optimizer_state_dicts(),
            "rng": {"train": self.train_generator.get_state(), "act": self.act_generator.get_state()},
            "updates_done": self.updates_done,
        }
        if include_replay:
            state["replay"] = self.replay.state_dict()
        else:
            state["replay_rng"] = self.replay.rng.bit_generator.state
        return state

    def _optimizer_state_dicts(self) -> dict[str, Any]:
        if self._built_optimizers is None and self._pending_optimizer_state is not None:
            return {name: self._pending_optimizer_state[name] for name in ("model", "actor", "critic")}
        return {name: optimizer.state_dict() for name, optimizer in self._optimizers().items()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore a `state_dict` (the network shapes of both configs must agree)."""
        saved = stored_dump(type(self.config), state["config"], "checkpoint")
        current = self.config.model_dump(mode="json")
        differing = [key for key in _SHAPE_FIELDS if saved.get(key) != current.get(key)]
        if differing:
            raise ConfigError(
                "checkpoint was made with different network settings: "
                + ", ".join(f"{k}: {saved.get(k)!r} != {current.get(k)!r}" for k in differing)
            )
        self.world_model.load_state_dict(state["world_model"])
        self.behavior.load_state_dict(state["behavior"])
        if self._built_optimizers is None:
            self._pending_optimizer_state = state["optimizers"]  # loaded when the optimisers are built
        else:
            for name, optimizer in self._built_optimizers.items():
                optimizer.load_state_dict(state["optimizers"][name])
        self.train_generator.set_state(state["rng"]["train"])
        self.act_generator.set_state(state["rng"]["act"])
        self.updates_done = int(state["updates_done"])
        if "replay" in state:
            self.replay.load_state_dict(state["replay"])
        else:
            self.replay.rng.bit_generator.state = state["replay_rng"]

    # --- conversions

    def _tensor(self, value: Any, dtype: torch.dtype) -> Tensor:
        return torch.as_tensor(np.asarray(value), dtype=dtype, device=self.device)

    def _internal_action_array(self, env_actions: Any) -> np.ndarray:
        """Environment actions as the model sees them: in [-1, 1] (Box) or one-hot (Discrete)."""
        actions = np.asarray(env_actions)
        if self.discrete:
            index = actions.reshape(-1).astype(np.int64) - self._action_start
            return np.eye(self.action_size, dtype=np.float32)[index]
        flat = actions.reshape(-1, self.action_size).astype(np.float32)
        return np.clip(2.0 * (flat - self._action_low) / self._action_span - 1.0, -1.0, 1.0).astype(np.float32)

    def _to_internal_action(self, env_actions: Any) -> Tensor:
        return self._tensor(self._internal_action_array(env_actions), torch.float32)

    def _to_env_action(self, internal: Tensor) -> np.ndarray:
        values = internal.float().cpu().numpy()
        if self.discrete:
            return values.argmax(-1) + self._action_start
        env = self._action_low + (values + 1.0) * 0.5 * self._action_span
        return env.reshape(values.shape[0], *self._action_shape).astype(np.float32)


def build_assistant(config: DreamerConfig, obs_space: gym.spaces.Space, act_space: gym.spaces.Space,
                    intents: tuple[str, ...], seed: int, device: str = "cpu") -> DreamerAgent:
    """A DreamerV3 assistant (the method registry's builder). Its intent head, if the method has
    one, is already in `config.extra_heads` (see `Method.configure`), so `intents` is not needed."""
    del intents
    return DreamerAgent(obs_space, act_space, config.model_copy(update={"device": device}), seed=seed)


def _model_param_groups(world_model: WorldModel, config: DreamerConfig) -> Any:
    """The world model's parameters for its optimiser: one group at `model_lr`, plus one group
    per extra head with its own `lr` (those heads' weights leave the first group)."""
    own_lr = {spec.name: spec.lr for spec in config.extra_heads if spec.lr is not None}
    if not own_lr:
        return world_model.parameters()  # one group, as every run before per-head rates
    heads = {name: list(world_model.extra_heads[name].parameters()) for name in own_lr}
    taken = {id(p) for params in heads.values() for p in params}
    return [{"params": [p for p in world_model.parameters() if id(p) not in taken]},
            *({"params": heads[name], "lr": lr} for name, lr in own_lr.items())]
