"""d2a from Python: stored drivers and assistants as objects that act on observations.

    from d2a_core import api

    assistant = api.load("assistants/straightaway/pass-stay/dream2assist/seed0", store="artifacts")
    human = api.load("humans/straightaway/stay/expert", store="artifacts")
    env = assistant.make_env()                  # the env the assistant was trained in (gymnasium)
    episode = api.drive(env, human, assistant, seed=0)
    episode["intent_probs"]                     # (T, K): the assistant's belief at every step

or step by step, as `drive` does: `reset()` both at an episode's start; each step
`a_H = human.act(human_obs)`, `a_A = assistant.act(obs)`, `p = assistant.intent()`, then
`human.executed(blend(a_H, a_A))`. `obs` is the env's observation, whose last two entries (the
partner slot) hold the human's previous action; the human's own observation holds the
assistant's there (`human_view`). Everything acts with its actor's mode, as in evaluation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.errors import UsageError
from d2a_core.run_inputs import ENV_SECTIONS, load_track_bundle, track_of
from d2a_core.sim.shared_control import blend
from d2a_core.stored_agents import load_assistant, load_human


def _store(store: Store | str | Path | None) -> Store:
    if isinstance(store, Store):
        return store
    return Store(Path(store) if store is not None else Path("artifacts"))


class _Stored:
    """What drivers and assistants share: the artifact, its store and the env it was trained in."""

    def __init__(self, store: Store, art) -> None:
        self.store, self.artifact, self.id = store, art, art.id
        probe = self.make_env()  # only for its spaces
        self.observation_space, self.action_space = probe.observation_space, probe.action_space
        probe.close()

    def make_env(self, intent: str | None = None):
        """A `d2a/Race-v0` env with the track, opponents and settings this artifact was trained with
        (`intent` sets the human objective whose reward the env reports)."""
        from d2a_core.config.schema import Config

        cfg = Config.model_validate({k: self.artifact.config[k] for k in ENV_SECTIONS if k in self.artifact.config})
        return load_track_bundle(self.store, track_of(self.store, self.id), cfg.env.dt).env(cfg, intent)


class Driver(_Stored):
    """A stored human checkpoint (a synthetic driver of one intent). Its world model samples its
    latent state from a generator seeded with `seed`, as evaluation does."""

    def __init__(self, store: Store, art, device: str = "cpu", seed: int = 0) -> None:
        import torch

        super().__init__(store, art)
        self._generator = torch.Generator().manual_seed(seed)
        self.intent: str = art.labels["intent"]
        self.env_step: int = art.labels.get("env_step")
        self._agent = load_human(store, art.id, self.observation_space, self.action_space, device)
        self.reset()

    def make_env(self, intent: str | None = None):
        return super().make_env(intent or self.artifact.labels["intent"])

    def reset(self) -> None:
        self._state, self._first = None, True

    def act(self, observation: np.ndarray) -> np.ndarray:
        """The driver's action (2,) = [steer, accel] in [-1, 1] for its observation."""
        obs = np.asarray(observation, np.float32).reshape(1, -1)
        action, self._state = self._agent.policy({"obs": obs, "is_first": np.array([self._first])}, self._state,
                                                 explore=False, generator=self._generator)
        self._first = False
        return np.asarray(action, np.float32).reshape(2)

    def executed(self, action: np.ndarray) -> None:
        """The action the car really executed (under shared control, the blend), which the
        driver's model continues from; without a call it assumes its own."""
        self._state = self._agent.with_action(self._state, np.asarray(action, np.float32).reshape(1, 2))


class Assistant(_Stored):
    """A stored assistant checkpoint: acts beside a driver and, for methods with an intent head,
    says which intent of its pair it believes the driver has. A Dreamer-family assistant samples
    its latent state from a generator seeded with `seed`."""

    def __init__(self, store: Store, art, device: str = "cpu", seed: int = 0) -> None:
        import inspect

        import torch

        from d2a_core.training.partner_window import PartnerWindow

        super().__init__(store, art)
        self._agent, self.method, intents, self.partner_window = load_assistant(
            store, art.id, self.observation_space, self.action_space, device)
        self.intents: tuple[str, ...] = tuple(intents)
        self._window = PartnerWindow(1, self.partner_window)
        takes_generator = "generator" in inspect.signature(self._agent.policy).parameters
        self._generator = {"generator": torch.Generator().manual_seed(seed)} if takes_generator else {}
        self.reset()

    def reset(self) -> None:
        self._state, self._first, self._probs = None, True, None
        self._window.reset(0)

    def act(self, observation: np.ndarray) -> np.ndarray:
        """The assistant's action a_A (2,) for the env's observation (partner slot: the human's
        last action); the car executes clip(a_H + a_A, -1, 1)."""
        obs = np.asarray(observation, np.float32).reshape(1, -1)
        record = {"obs": self._window.view(obs).astype(np.float32), "is_first": np.array([self._first]),
                  "reward": np.zeros(1, np.float32), "is_terminal": np.zeros(1, bool)}
        action, self._state = self._agent.policy(record, self._state, explore=False, **self._generator)
        probs = self._agent.intent_probs(self._state)
        self._probs = None if probs is None else np.asarray(probs, np.float64).reshape(-1)
        self._window.push(0, obs[0, -2:])
        self._first = False
        return np.asarray(action, np.float32).reshape(2)

    def intent(self) -> dict[str, float] | None:
        """p(intent) after the last `act`, by intent name; None for a method without an estimate."""
        return None if self._probs is None else dict(zip(self.intents, map(float, self._probs)))


def load(ref: str, store: Store | str | Path | None = None, device: str = "cpu", seed: int = 0) -> Driver | Assistant:
    """A stored human checkpoint (`Driver`) or assistant (`Assistant`) by id, prefix or alias; a
    population or its alias gives its expert. `store`: a path or `Store` (default ./artifacts);
    `seed`: of the generator its latent states are sampled from."""
    st = _store(store)
    art = st.get(ref)
    if art.kind == "population":
        art = st.get(st.read_json(art.id, "population.json")["expert"])
    if art.kind == "human":
        return Driver(st, art, device, seed)
    if art.kind == "assistant":
        return Assistant(st, art, device, seed)
    raise UsageError(f"{ref} is a {art.kind} artifact; load takes a human checkpoint, a population or an assistant")


def human_view(observation: np.ndarray, assistant_action: np.ndarray | None) -> np.ndarray:
    """The driver's observation under shared control: the partner slot holds the assistant's
    last action (zeros when driving alone)."""
    view = np.array(observation, np.float32, copy=True)
    view[-2:] = 0.0 if assistant_action is None else assistant_action
    return view


def drive(env, human: Driver, assistant: Assistant | None = None, seed: int = 0) -> dict[str, Any]:
    """One episode of `human`, assisted by `assistant` or alone, on `env` from `seed`. Returns
    per-step arrays (`t`, `progress_m`, `gap_m` ahead of the opponent (negative: behind), `human_action`,
    `assistant_action`, `intent_probs` with the assistant's intents in `intents`) and the
    episode's outcome (`info` of its last step)."""
    race = env.unwrapped
    obs, info = env.reset(seed=seed)
    human.reset()
    if assistant is not None:
        assistant.reset()
    a_assist = np.zeros(2, np.float32)
    rows: dict[str, list] = {k: [] for k in ("t", "progress_m", "gap_m", "human_action", "assistant_action",
                                             "intent_probs")}
    done = False
    while not done:
        a_human = human.act(human_view(obs, a_assist if assistant is not None else None))
        if assistant is not None:
            a_assist = assistant.act(obs)
            belief = assistant.intent()
            rows["intent_probs"].append([belief[k] for k in assistant.intents] if belief else [])
        executed = blend(a_human, a_assist)
        human.executed(executed)
        race.set_partner_action(a_human)
        obs, _, terminated, truncated, info = env.step(executed)
        done = terminated or truncated
        rows["t"].append(float(info["t"]))
        rows["progress_m"].append(float(info["progress"]))
        rows["gap_m"].append(float(info["ds"]))
        rows["human_action"].append(a_human)
        rows["assistant_action"].append(a_assist.copy())
    out = {k: np.asarray(v, np.float64) for k, v in rows.items()}
    out["intents"] = assistant.intents if assistant is not None else ()
    out["info"] = info
    return out
