"""The assistant's intent head p(y_hat | s): built from the method registry's config patch,
trained by NLL on the replayed label, and read while acting."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from d2a_core.agents.dreamer import DreamerAgent, DreamerConfig, HeadConfig
from d2a_core.config import load
from d2a_core.errors import ConfigError, TrainingError
from d2a_core.training.methods import get_method

OBS, ENVS, EPISODE = 5, 4, 20


def _smoke_agent(**overrides) -> DreamerAgent:
    """The smoke preset's agent with dream2assist's intent head over (pass, stay); `overrides`:
    DreamerConfig fields."""
    config = load("smoke").config
    config = get_method("dream2assist").configure(config, ("pass", "stay"))
    dreamer = config.dreamer.model_copy(update={"prefill_steps": 0, **overrides})
    return DreamerAgent(gym.spaces.Box(-np.inf, np.inf, (OBS,), np.float32),
                        gym.spaces.Box(-1.0, 1.0, (2,), np.float32), DreamerConfig(**dreamer.model_dump()), seed=0)


class _LabelledEpisodes:
    """ENVS streams of EPISODE-step episodes; each episode's intent y is drawn at its start and
    shows in every observation as the sign of its first component (the rest is noise)."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.t = 0
        self.intent = self.rng.integers(0, 2, ENVS)

    def step(self) -> dict[str, np.ndarray]:
        first = self.t % EPISODE == 0
        if first:
            self.intent = self.rng.integers(0, 2, ENVS)
        obs = self.rng.normal(size=(ENVS, OBS)).astype(np.float32)
        obs[:, 0] = (2 * self.intent - 1) * (0.3 + np.abs(obs[:, 0]))
        self.t += 1
        return {"obs": obs, "reward": self.rng.normal(size=ENVS).astype(np.float32),
                "is_first": np.full(ENVS, first), "is_terminal": np.zeros(ENVS, bool)}


def test_intent_head_learns_the_label_well_above_chance():
    torch.manual_seed(0)
    # A learning rate 10x the smoke preset's, so that a few hundred updates suffice.
    agent = _smoke_agent(model_lr=1e-3)
    assert list(agent.world_model.extra_heads) == ["intent"]
    assert agent.world_model.extra_heads["intent"].intents == ("pass", "stay")
    episodes = _LabelledEpisodes(seed=1)
    rng = np.random.default_rng(2)
    for _ in range(10 * EPISODE):
        step = episodes.step()
        # The label reaches the agent only as a replay field, never in the observation.
        agent.observe({**step, "action": rng.uniform(-1, 1, (ENVS, 2)).astype(np.float32),
                       "intent": episodes.intent.copy()})
    metrics = [agent.train_step() for _ in range(300)]
    losses = np.array([m["wm/intent_loss"] for m in metrics])
    accuracy = np.array([m["wm/intent_accuracy"] for m in metrics])
    assert losses[:10].mean() > 0.6  # about log 2 at the start
    assert losses[-30:].mean() < 0.35 and losses[-30:].mean() < 0.5 * losses[:10].mean()
    assert accuracy[-30:].mean() > 0.85  # chance is 0.5

    # While acting: y_hat from the filtered state along fresh episodes.
    fresh, state, hits = _LabelledEpisodes(seed=7), None, []
    for _ in range(EPISODE):
        step = fresh.step()
        _, state = agent.policy(step, state, explore=False)
        probs = agent.predict(state)["intent"]
        assert probs.shape == (ENVS, 2) and torch.allclose(probs.sum(-1), torch.ones(ENVS))
        hits.append(probs.argmax(-1).numpy() == fresh.intent)
    assert np.mean(hits) > 0.8


def test_intent_head_options_and_labels_are_checked(make_agent, fill_random):
    with pytest.raises(ConfigError, match="bad options"):
        make_agent(extra_heads=[HeadConfig(name="intent", kind="intent", options={"intents": ["pass"]})])
    with pytest.raises(ConfigError, match="bad options"):
        make_agent(extra_heads=[HeadConfig(name="intent", kind="intent", options={"intents": ["pass", "pass"]})])
    agent = make_agent(extra_heads=[HeadConfig(name="intent", kind="intent", options={"intents": ["left", "right"]})])
    fill_random(agent, 20, intent=lambda t: np.full(2, 2))  # index 2 is not an intent of the pair
    with pytest.raises(TrainingError, match="label >= its 2 classes"):
        agent.train_step()
    # Unknown labels (< 0) are left out of the loss and the accuracy.
    agent = make_agent(extra_heads=[HeadConfig(name="intent", kind="intent", options={"intents": ["left", "right"]})])
    fill_random(agent, 20, intent=lambda t: np.full(2, -1))
    metrics = agent.train_step()
    assert metrics["wm/intent_loss"] == 0.0 and metrics["wm/intent_accuracy"] == 0.0


def _stale_reward_agent(relabel: bool) -> tuple[DreamerAgent, "_LabelledEpisodes"]:
    """An agent trained on episodes whose reward under intent estimate k is +1 for k = 0 and -1
    for k = 1 (`reward_by_class`), but whose stored reward was made with a coin flip for the
    estimate (a stale, untrained one): the stored reward says nothing about the episode's intent."""
    torch.manual_seed(0)
    overrides = {"reward_relabel_head": "intent"} if relabel else {}
    agent = _smoke_agent(model_lr=1e-3, **overrides)
    episodes, rng = _LabelledEpisodes(seed=5), np.random.default_rng(6)
    by_class = np.tile(np.array([1.0, -1.0], np.float32), (ENVS, 1))
    for _ in range(10 * EPISODE):
        step = episodes.step()
        stale = by_class[np.arange(ENVS), rng.integers(0, 2, ENVS)]
        agent.observe({**step, "reward": stale, "action": rng.uniform(-1, 1, (ENVS, 2)).astype(np.float32),
                       "intent": episodes.intent.copy(), "reward_by_class": by_class})
    metrics = [agent.train_step() for _ in range(300)]
    return agent, metrics


def _predicted_reward_by_intent(agent: DreamerAgent) -> np.ndarray:
    """Mean reward-head prediction along fresh episodes, for intent 0 and intent 1."""
    fresh, state, sums, counts = _LabelledEpisodes(seed=8), None, np.zeros(2), np.zeros(2)
    for t in range(2 * EPISODE):
        step = fresh.step()
        _, state = agent.policy(step, state, explore=False)
        if t % EPISODE >= 3:  # the model state has seen a few observations of the episode
            reward = agent.predict(state)["reward"].numpy()
            np.add.at(sums, fresh.intent, reward)
            np.add.at(counts, fresh.intent, 1)
    return sums / counts


def test_reward_relabelling_learns_the_reward_under_the_current_intent_estimate():
    """`reward_relabel_head="intent"`: the reward head's target is the stored reward under the
    intent the head picks now, so it learns +1 for intent-0 episodes and -1 for intent-1 ones,
    where the stale stored reward (a coin flip between them) teaches it about 0 for both."""
    relabelled, metrics = _stale_reward_agent(relabel=True)
    assert metrics[-1]["wm/reward_relabel_change"] > 0.5  # about half the stored rewards were wrong
    low, high = _predicted_reward_by_intent(relabelled)[[1, 0]]
    assert high > 0.5 and low < -0.5
    plain, metrics = _stale_reward_agent(relabel=False)
    assert "wm/reward_relabel_change" not in metrics[-1]
    assert np.all(np.abs(_predicted_reward_by_intent(plain)) < 0.4)


def test_reward_relabelling_targets_and_checks():
    from d2a_core.agents.dreamer.world_model import relabeled_reward

    reward = torch.tensor([[9.0, 9.0, 9.0]])
    by_class = torch.tensor([[[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]]])
    # step t takes its reward under the class chosen at t - 1; the window's first step keeps its own
    np.testing.assert_array_equal(relabeled_reward(reward, by_class, torch.tensor([[1, 0, 1]])).numpy(),
                                  [[9.0, 3.0, 4.0]])
    with pytest.raises(ConfigError, match="reward_relabel_head 'goal' is not one of the extra heads"):
        _smoke_agent(reward_relabel_head="goal")
    agent = _smoke_agent(reward_relabel_head="intent")
    rng = np.random.default_rng(0)
    episodes = _LabelledEpisodes(seed=1)
    for _ in range(3 * EPISODE):
        agent.observe({**episodes.step(), "action": rng.uniform(-1, 1, (ENVS, 2)).astype(np.float32),
                       "intent": episodes.intent.copy()})
    with pytest.raises(TrainingError, match="no 'reward_by_class' field"):
        agent.train_step()
