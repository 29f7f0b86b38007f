"""Shared control in a batch of race envs: frozen humans and an assistant drive, experts watch.

This is the assistant's collector (paper Algorithm 1, second phase) and the paired evaluator's
engine. Per vector step it calls the assistant once, each human checkpoint in use once (on the
envs it drives), each expert filter once, and steps every env with `clip(a_H + a_A, -1, 1)`. The
humans live here, outside the env (`SharedControl` is the single-env form, for rendering).

What each party sees:

- the assistant: the env's observation, whose partner slot holds the human's last action (with
  `partner_window` K > 1, followed by the K - 1 human actions before it: `PartnerWindow`), and
  (as a training target only, never an input) the index of the human's intent in the pair;
- a human: the same observation with the assistant's last action in the partner slot; its
  recurrent state continues with the *executed* (blended) action, so its world model tracks
  where the car really went;
- an expert filter (`ExpertFilter`): the observation with an empty partner slot (experts drove
  alone) and the blended action.

Episodes come from `next_episode()`, which returns an `EpisodeSpec` (who drives, which env seed
and replay) or None (that env then stays idle): random draws during training, a fixed list in
evaluation, so two conditions can be paired on the same specs.

The assistant's reward (`objectives.assistant`, equation 6) is made here, in the training
process: the reward for arriving at x_{t+1} uses the assistant's action a_A,t and its inferred
intent y_hat_t at x_t, the expert reward r_hat*(y_hat_t) read at x_{t+1} and the expert action
a*_t(y_hat_t) at x_t.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from d2a_core.agents.dreamer.agent import DreamerAgent, PolicyState
from d2a_core.agents.dreamer.expert import ExpertFilter
from d2a_core.agents.dreamer.latent import Latent
from d2a_core.agents.dreamer.world_model import REWARD_BY_CLASS_FIELD
from d2a_core.agents.protocol import AssistantAgent
from d2a_core.evaluation.metrics import episode_metrics
from d2a_core.objectives.assistant import AssistantRewardConfig, assistant_reward, pick_intent, totals_by_intent
from d2a_core.sim.episode_log import EpisodeRecorder
from d2a_core.sim.race_env import RaceEnv
from d2a_core.sim.recording import abort_open, close_with_outcome, scene_of, step_record
from d2a_core.training.partner_window import PARTNER_SLOT, PartnerWindow

ASSISTANT_TERMS = ("task", "intervention", "expert_reward", "expert_distance", "total")
"""The assistant reward's terms, unweighted (`AssistantRewardTerms`), summed per episode as
`assist/<term>` so that the return of any weighting can be recomputed (it is linear in them)."""


@dataclass(frozen=True)
class EpisodeSpec:
    """What defines an episode: the env seed (start and, unless given, the replay drawn), the
    human checkpoint (index into the collector's humans) and its intent (index in the pair).

    An intent swap (paper appendix): before step `swap_step` the human is replaced by human
    `swap_human` of intent `swap_label`, which starts from a blank recurrent state."""

    seed: int
    human: int
    label: int
    replay: int | None = None
    swap_step: int | None = None
    swap_human: int | None = None
    swap_label: int | None = None


def _rows(state: PolicyState, index: torch.Tensor) -> PolicyState:
    latent = state.latent
    probs = None if latent.probs is None else latent.probs[index]
    return PolicyState(Latent(latent.h[index], latent.index[index], probs), state.action[index])


def _put_rows(state: PolicyState, index: torch.Tensor, rows: PolicyState) -> None:
    state.latent.h[index] = rows.latent.h.to(state.latent.h.dtype)
    state.latent.index[index] = rows.latent.index
    if state.latent.probs is not None and rows.latent.probs is not None:
        state.latent.probs[index] = rows.latent.probs.to(state.latent.probs.dtype)
    state.action[index] = rows.action


class HumanDrivers:
    """Frozen human checkpoints (DreamerAgents) driving `num_envs` envs, one checkpoint per env;
    one batched policy call per checkpoint in use."""

    def __init__(self, agents: Sequence[DreamerAgent], num_envs: int, explore: bool, seed: int) -> None:
        self.agents = list(agents)
        self.num_envs = num_envs
        self.explore = explore
        self.generator = torch.Generator().manual_seed(seed)
        self.assigned = np.full(num_envs, -1, np.int64)
        self._states: dict[int, PolicyState] = {}

    def assign(self, env: int, human: int) -> None:
        self.assigned[env] = human

    def _state(self, k: int) -> PolicyState:
        if k not in self._states:
            self._states[k] = self.agents[k].initial_state(self.num_envs)
        return self._states[k]

    def act(self, obs: np.ndarray, first: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Actions (N, 2) of each active env's human on its observation; `first` starts episodes."""
        actions = np.zeros((self.num_envs, 2), np.float32)
        for k in np.unique(self.assigned[active]):
            envs = np.flatnonzero(active & (self.assigned == k))
            index = torch.as_tensor(envs)
            agent, state = self.agents[k], self._state(int(k))
            rows = _rows(state, index)
            out, rows = agent.policy({"obs": obs[envs], "is_first": first[envs]}, rows, explore=self.explore,
                                     generator=self.generator)
            _put_rows(state, index, rows)
            actions[envs] = out
        return actions

    def executed(self, blended: np.ndarray, active: np.ndarray) -> None:
        """Each active env's human state continues with the action the car executed."""
        for k in np.unique(self.assigned[active]):
            envs = np.flatnonzero(active & (self.assigned == k))
            index = torch.as_tensor(envs)
            state = self._state(int(k))
            rows = self.agents[k].with_action(_rows(state, index), blended[envs])
            state.action[index] = rows.action


class SharedCollector:
    """Steps `envs` under shared control; see the module docstring.

    `intents`: the pair, in label order. `experts`: one filter per intent of the pair (or None
    when the method's reward queries no expert). `assistant`: None drives unassisted (a_A = 0).
    `keep_steps`: keep per-step arrays of each episode (terms, actions, intent estimates).
    `partner_window`: how many of the human's last actions the assistant observes (its config's
    `assistant.partner_window`). `reward_by_intent`: the assistant's replay also gets the reward
    under each intent of the pair (`REWARD_BY_CLASS_FIELD`, for `DreamerConfig.reward_relabel_head`)."""

    def __init__(self, envs: Sequence[RaceEnv], humans: HumanDrivers, intents: Sequence[str],
                 next_episode: Callable[[], EpisodeSpec | None], assistant: AssistantAgent | None = None,
                 experts: Sequence[ExpertFilter] | None = None,
                 reward_config: AssistantRewardConfig | None = None, keep_steps: bool = False,
                 label_field: str | None = "intent", log_dir: Path | None = None,
                 log_metadata: dict[str, Any] | None = None,
                 record_features: Callable[[EpisodeSpec], bool] | None = None,
                 partner_window: int = 1, reward_by_intent: bool = False) -> None:
        self.envs = list(envs)
        self.n = len(self.envs)
        self._window = PartnerWindow(self.n, partner_window)
        self.humans = humans
        self.intents = tuple(intents)
        self.next_episode = next_episode
        self.assistant = assistant
        self.experts = list(experts) if experts else []
        self.reward_config = reward_config or AssistantRewardConfig()
        self.keep_steps = keep_steps
        self.label_field = label_field
        # episodes whose assistant latent features (`assistant.features(state)`) are kept per step
        self.record_features = record_features if assistant is not None and hasattr(assistant, "features") else None
        self.timing: dict[str, float] = {}  # wall seconds per phase since the caller last cleared it
        # MCAP episode logs (one file per episode in `log_dir`), for evaluation
        self.log_dir = None if log_dir is None else Path(log_dir)
        self.log_metadata = dict(log_metadata or {})
        self._recorders: list[EpisodeRecorder | None] = [None] * len(self.envs)
        self._scene = scene_of(self.envs[0].track) if log_dir is not None else None
        wants_experts = self.reward_config.alpha_r > 0 or self.reward_config.alpha_a > 0
        if assistant is not None and wants_experts and not self.experts:
            raise ValueError("the assistant's reward weights the experts (alpha_r or alpha_a > 0) but no "
                             "expert filters were given")
        if reward_by_intent and not (wants_experts and self.experts):
            raise ValueError("the reward under each intent needs the expert terms (alpha_r or alpha_a > 0) and filters")
        self.reward_by_intent = reward_by_intent
        obs_size = self.envs[0].observation_space.shape[0]
        self._reward_by_intent = np.zeros((self.n, len(self.intents)), np.float32)
        self._obs = np.zeros((self.n, obs_size), np.float32)  # the assistant's view
        self._human_obs = np.zeros((self.n, obs_size), np.float32)
        self._reward = np.zeros(self.n, np.float32)
        self._first = np.ones(self.n, bool)
        self._terminal = np.zeros(self.n, bool)
        self._done = np.zeros(self.n, bool)
        self._idle = np.zeros(self.n, bool)
        self._spec: list[EpisodeSpec | None] = [None] * self.n
        self._labels = np.zeros(self.n, np.int64)
        self._episode: list[dict[str, Any]] = [{} for _ in range(self.n)]
        self._assistant_state: Any = None
        self._a_star: np.ndarray | None = None  # (K, N, 2) the experts' actions at the current state
        for i in range(self.n):
            self._reset(i)
        if self.experts:
            for expert in self.experts:
                expert.reset(np.ones(self.n, bool))
            self._a_star = np.stack([e.step(self._expert_view(self._obs), None).action for e in self.experts])

    # --- episodes

    def _reset(self, i: int) -> None:
        spec = self.next_episode()
        self._spec[i] = spec
        self._first[i] = True
        self._terminal[i] = False
        self._done[i] = False
        self._reward[i] = 0.0
        self._reward_by_intent[i] = 0.0
        if spec is None:
            self._idle[i] = True
            return
        options: dict[str, Any] = {"intent": self.intents[spec.label]}
        if spec.replay is not None:
            options["replay"] = spec.replay
        obs, info = self.envs[i].reset(seed=spec.seed, options=options)
        self._window.reset(i)
        self._obs[i] = obs
        self._human_obs[i] = obs
        self._labels[i] = spec.label
        self.humans.assign(i, spec.human)
        self._episode[i] = {"infos": [info], "rewards": [], "terms": [], "y_hat": [], "p_true": [],
                            "labels": [], "human_action": [], "assistant_action": [],
                            "features": [] if self.record_features and self.record_features(spec) else None}
        if self.log_dir is not None:
            self._open_log(i, spec, info)

    @staticmethod
    def _expert_view(obs: np.ndarray) -> np.ndarray:
        view = obs.copy()
        view[:, -2:] = 0.0  # experts drove alone: their partner slot was always empty
        return view

    @property
    def idle(self) -> bool:
        """Whether every env has run out of episodes."""
        return bool(self._idle.all())

    # --- stepping

    def step(self, explore: bool = True, learn: bool = True) -> list[dict[str, Any]]:
        """One record per env: act, store (when `learn`), advance. Returns the episodes that
        ended on this call: their spec, metrics and the sums of the assistant's reward terms."""
        clock = time.perf_counter()
        active = ~self._idle
        record = {"obs": self._window.view(self._obs).copy(), "reward": self._reward.copy(), "is_first": self._first.copy(),
                  "is_terminal": self._terminal.copy()}
        y_hat = probs = None
        if self.assistant is not None:
            a_assist, self._assistant_state = self.assistant.policy(record, self._assistant_state, explore=explore)
            a_assist = np.asarray(a_assist, np.float32).reshape(self.n, 2)
            probs = self.assistant.intent_probs(self._assistant_state)
            if probs is not None:
                y_hat = np.asarray(probs).argmax(-1)
            features = self.assistant.features(self._assistant_state) if self.record_features else None
            if self.experts and y_hat is None:
                raise ValueError("the assistant gives no intent estimate, but its reward queries the experts")
            if learn:
                labels = {self.label_field: self._labels.copy()} if self.label_field else {}
                if self.reward_by_intent:
                    labels[REWARD_BY_CLASS_FIELD] = self._reward_by_intent.copy()
                self.assistant.observe({**record, "action": a_assist, **labels})
        else:
            a_assist = np.zeros((self.n, 2), np.float32)
            features = None
        clock = self._tick("acting/assistant", clock)
        stepping = active & ~self._done
        human_first = self._first.copy()
        for i in np.flatnonzero(stepping):
            spec = self._spec[i]
            if spec is not None and spec.swap_step is not None and len(self._episode[i]["infos"]) - 1 == spec.swap_step:
                self.humans.assign(i, spec.swap_human)
                self._labels[i] = spec.swap_label
                human_first[i] = True  # the new human knows nothing of the episode so far
        a_human = self.humans.act(self._human_obs, human_first, stepping)
        clock = self._tick("acting/humans", clock)
        blended = np.clip(a_human + a_assist, -1.0, 1.0)
        task = np.zeros(self.n)
        reset = np.zeros(self.n, bool)
        for i, env in enumerate(self.envs):
            if self._idle[i]:
                continue
            if self._done[i]:
                self._reset(i)
                reset[i] = not self._idle[i]
                continue
            ep = self._episode[i]
            if probs is not None:
                ep["y_hat"].append(int(y_hat[i]))
                ep["p_true"].append(float(probs[i, self._labels[i]]))
            ep["labels"].append(int(self._labels[i]))
            if features is not None and ep["features"] is not None:
                ep["features"].append(np.asarray(features[i], np.float32))
            env.set_partner_action(a_human[i])  # the assistant's next observation shows a_H
            obs, reward, terminated, truncated, info = env.step(blended[i])
            info = dict(info, human_action=a_human[i], assistant_action=a_assist[i])
            ep["infos"].append(info)
            ep["rewards"].append(float(reward))
            if self.keep_steps:
                ep["human_action"].append(a_human[i].tolist())
                ep["assistant_action"].append(a_assist[i].tolist())
            task[i] = info["reward_terms"]["task"]
            self._window.push(i, self._obs[i, -PARTNER_SLOT:])  # the slot's action moves into the window
            self._obs[i] = obs
            self._human_obs[i] = obs
            self._human_obs[i, -2:] = a_assist[i]  # ...and the human's shows a_A
            self._first[i] = False
            self._terminal[i] = terminated
            self._done[i] = terminated or truncated
        clock = self._tick("simulation", clock)
        self.humans.executed(blended, stepping)
        clock = self._tick("acting/humans", clock)

        r_star = a_star_now = None
        if self.experts:
            for expert in self.experts:
                expert.reset(reset)
            out = [e.step(self._expert_view(self._obs), blended) for e in self.experts]
            r_star = np.stack([o.reward for o in out])
            a_star_now = np.stack([o.action for o in out])
        choose = y_hat if y_hat is not None else np.zeros(self.n, np.int64)
        use_experts = self.experts and y_hat is not None
        terms = assistant_reward(
            task, a_assist, a_human,
            pick_intent(r_star, choose) if use_experts else None,
            pick_intent(self._a_star, choose) if use_experts else None,
            self.reward_config if use_experts else _without_experts(self.reward_config),
        )
        by_intent = None
        if self.reward_by_intent and use_experts:
            by_intent = totals_by_intent(task, a_assist, a_human, r_star, self._a_star, self.reward_config)
        if a_star_now is not None:
            self._a_star = a_star_now
        self._tick("expert_filtering", clock)
        finished = []
        for i in np.flatnonzero(stepping):
            self._reward[i] = terms.total[i]
            if by_intent is not None:
                self._reward_by_intent[i] = by_intent[:, i]
            ep = self._episode[i]
            ep["terms"].append([float(getattr(terms, name)[i]) for name in ASSISTANT_TERMS])
            if self._recorders[i] is not None:
                self._log_step(i, ep["infos"][-1], ep["rewards"][-1], None if probs is None else probs[i],
                               ep["terms"][-1])
            if self._done[i]:
                finished.append(self._finish(i))
        return finished

    def close(self) -> None:
        """Abandon the episode logs still being written (their partial files are removed)."""
        abort_open(self._recorders)

    # --- episode logs

    def _open_log(self, i: int, spec: EpisodeSpec, info: dict[str, Any]) -> None:
        assert self.log_dir is not None and self._scene is not None
        self.log_dir.mkdir(parents=True, exist_ok=True)
        path = self.log_dir / f"human{spec.human:03d}-seed{spec.seed}.mcap"
        meta = {**self.log_metadata, **asdict(spec), "intent": self.intents[spec.label], "replay": info["replay"]}
        recorder = EpisodeRecorder(path, self._scene, meta, self.envs[i].cfg.dt)
        recorder.open()
        self._recorders[i] = recorder
        self._log_step(i, info, 0.0, None, [0.0] * len(ASSISTANT_TERMS))

    def _log_step(self, i: int, info: dict[str, Any], reward: float, probs: np.ndarray | None,
                  terms: list[float]) -> None:
        """One step of episode log: the env's fields, plus an `assistant` channel with the
        inferred intent's probabilities (NaN without an estimate), the true intent and the
        assistant reward's terms."""
        cars, states = step_record(self.envs[i], info, reward)
        spec = self._spec[i]
        assert spec is not None
        states["assistant"] = {
            "intent_probs": {name: float("nan") if probs is None else float(probs[k])
                             for k, name in enumerate(self.intents)},
            "true_intent": self.intents[int(self._labels[i])],
            "terms": dict(zip(ASSISTANT_TERMS, terms)),
        }
        self._recorders[i].log_step(info["t"], cars, states)

    def _tick(self, phase: str, since: float) -> float:
        now = time.perf_counter()
        self.timing[phase] = self.timing.get(phase, 0.0) + now - since
        return now

    def _finish(self, i: int) -> dict[str, Any]:
        ep = self._episode[i]
        spec = self._spec[i]
        assert spec is not None
        row: dict[str, Any] = {**asdict(spec), "intent": self.intents[spec.label],
                               **episode_metrics(ep["infos"], ep["rewards"])}
        terms = np.array(ep["terms"], np.float64).reshape(-1, len(ASSISTANT_TERMS))
        for k, name in enumerate(ASSISTANT_TERMS):
            row[f"assist/{name}"] = float(np.nansum(terms[:, k])) if np.isfinite(terms[:, k]).any() else None
        if ep["y_hat"]:
            row["intent_accuracy"] = float(np.mean(np.array(ep["y_hat"]) == np.array(ep["labels"])))
            # one row of the per-step confusion matrix: how often each intent was inferred
            if spec.swap_step is None:
                row["intent_counts"] = np.bincount(ep["y_hat"], minlength=len(self.intents)).tolist()
        if self._recorders[i] is not None:
            close_with_outcome(self._recorders[i], row)
            row["log"] = str(self._recorders[i].path)
            self._recorders[i] = None
        if self.keep_steps:
            if ep["features"]:
                row["features"] = np.stack(ep["features"])
            row["steps_log"] = {"terms": terms.tolist(), "y_hat": ep["y_hat"], "p_true": ep["p_true"],
                                "labels": ep["labels"],
                                "human_action": ep["human_action"], "assistant_action": ep["assistant_action"]}
        return row


def _without_experts(cfg: AssistantRewardConfig) -> AssistantRewardConfig:
    """The config with the expert terms off, for a method (or a step) that queries no expert."""
    return cfg.model_copy(update={"alpha_r": 0.0, "alpha_a": 0.0})
