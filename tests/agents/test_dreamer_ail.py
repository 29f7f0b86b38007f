"""Dreamer-AIL baseline: the discriminator separates the experts' driving from other driving, the
imitation reward moves the car toward the experts, the residual stays in its bounds, it has no
intent estimate, and a checkpoint restores it exactly (with or without the demonstrations)."""

from __future__ import annotations

import io

import gymnasium as gym
import numpy as np
import pytest
import torch

from d2a_core.agents.baselines.dreamer_ail import DreamerAILAgent, build_assistant
from d2a_core.agents.baselines.dreamer_ail_config import DreamerAILConfig
from d2a_core.agents.protocol import AssistantAgent
from d2a_core.errors import UsageError

INTENTS = ("pass", "stay")


def make_agent(bound: float = 1.0, seed: int = 0, **overrides) -> DreamerAILAgent:
    values = dict(window=1, units=32, layers=1, rollout_length=16, epochs=4, minibatches=2, init_std=0.8,
                  disc_units=32, disc_layers=1, disc_steps=8, disc_batch=64, disc_lr=1e-3)
    values.update(overrides)
    return build_assistant(DreamerAILConfig(residual_bound=bound, **values),
                           gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
                           gym.spaces.Box(-1.0, 1.0, (2,), np.float32), INTENTS, seed=seed)


def expert_action(target: np.ndarray) -> np.ndarray:
    """The toy expert steers onto the target and holds the throttle at 0.5."""
    return np.stack([target, np.full_like(target, 0.5)], -1).astype(np.float32)


def demonstrations(m: int = 512, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    target = np.random.default_rng(seed).uniform(-0.8, 0.8, m).astype(np.float32)
    return target[:, None], expert_action(target)


class Toy:
    """`n` envs: the observation is [target, partner slot (2)]; the target is new every step and
    the partner slot shows the human's action at the last step (the human here does nothing, so
    the car executes the assistant's action). Episodes of 8 steps, cut by a time limit."""

    def __init__(self, n: int = 8, seed: int = 0, horizon: int = 8) -> None:
        self.n, self.rng, self.horizon = n, np.random.default_rng(seed), horizon
        self.t = np.zeros(n, int)
        self.first = np.ones(n, bool)
        self.target = self.rng.uniform(-0.8, 0.8, n).astype(np.float32)
        self.executed: list[np.ndarray] = []
        self.expert: list[np.ndarray] = []

    def record(self) -> dict[str, np.ndarray]:
        obs = np.zeros((self.n, 3), np.float32)
        obs[:, 0] = self.target  # partner slot: the human's zero action
        return {"obs": obs, "reward": np.zeros(self.n, np.float32), "is_first": self.first.copy(),
                "is_terminal": np.zeros(self.n, bool)}

    def step(self, actions: np.ndarray) -> None:
        done = self.t >= self.horizon - 1
        self.executed.append(np.clip(actions, -1, 1))
        self.expert.append(expert_action(self.target))
        self.first = done.copy()
        self.t = np.where(done, 0, self.t + 1)
        self.target = self.rng.uniform(-0.8, 0.8, self.n).astype(np.float32)


def drive(agent: DreamerAILAgent, env: Toy, records: int, learn: bool = True) -> list[dict]:
    state, metrics = None, []
    for _ in range(records):
        record = env.record()
        actions, state = agent.policy(record, state, explore=True)
        if learn:
            agent.observe({**record, "action": actions})
            for _ in range(agent.updates_due(0)):
                metrics.append(agent.train_step())
        env.step(actions)
    return metrics


def test_it_is_an_assistant_without_an_intent_estimate_and_needs_demonstrations():
    agent = make_agent()
    assert isinstance(agent, AssistantAgent)
    actions, state = agent.policy(Toy().record(), None)
    assert actions.shape == (8, 2) and agent.intent_probs(state) is None
    with pytest.raises(UsageError, match="demonstrations"):
        drive(agent, Toy(), 17)
    with pytest.raises(UsageError, match="demonstrations"):
        agent.set_demonstrations(np.zeros((4, 1)), np.zeros((4, 3)))
    with pytest.raises(UsageError, match="do not fit"):
        agent.set_demonstrations(np.zeros((4, 2)), np.zeros((4, 2)))  # 2 + the partner slot > 3
    with pytest.raises(ValueError, match="no intent estimate"):
        DreamerAILConfig(policy_reads_intent=True)


def test_the_discriminator_separates_the_experts_from_other_driving():
    """Trained against an untrained residual's driving (a random policy, as the car drives at the
    start), it scores fresh expert pairs above 0 and fresh random driving below."""
    agent = make_agent(actor_lr=1e-9)  # the driving stays random; only the discriminator learns
    agent.set_demonstrations(*demonstrations())
    metrics = drive(agent, Toy(), 16 * 40 + 1, learn=True)
    assert len(metrics) == 40 and metrics[-1]["ail/disc_loss"] < 0.7 * metrics[0]["ail/disc_loss"]
    obs, action = demonstrations(256, seed=7)
    other = np.tanh(0.8 * np.random.default_rng(3).normal(size=(256, 2))).astype(np.float32)
    with torch.no_grad():
        expert = agent.discriminator_logits(torch.as_tensor(obs), torch.as_tensor(action)).numpy()
        random = agent.discriminator_logits(torch.as_tensor(obs), torch.as_tensor(other)).numpy()
    assert (expert > 0).mean() > 0.8 and (random < 0).mean() > 0.8


def test_imitation_moves_the_car_toward_the_experts():
    """Paid only by the discriminator (the env's rewards are all zero here), the residual learns
    to steer as the experts do: its steering's distance to theirs falls by more than half. (Its
    throttle first overshoots the experts' 0.5 and comes back over some 400 updates: GAIL's usual
    chase between policy and discriminator, too slow for a unit test.)"""
    agent = make_agent(seed=2)
    agent.set_demonstrations(*demonstrations())

    def steering_gap() -> float:
        record = Toy(n=256, seed=11).record()
        action = agent.policy(record, None, explore=False)[0]
        return float(np.abs(action - expert_action(record["obs"][:, 0]))[:, 0].mean())

    before = steering_gap()
    drive(agent, Toy(seed=2), 16 * 50 + 1)
    assert steering_gap() < 0.4 * before, (before, steering_gap())


def test_the_residual_stays_within_its_bound():
    agent = make_agent(bound=0.3)
    agent.set_demonstrations(*demonstrations())
    env = Toy()
    drive(agent, env, 16 * 3 + 1)
    executed = np.concatenate(env.executed)
    assert np.abs(executed).max() <= 0.3 + 1e-6 and np.abs(executed).max() > 0.25


def test_a_checkpoint_restores_the_agent_for_acting_and_for_training_on():
    agent = make_agent()
    agent.set_demonstrations(*demonstrations())
    drive(agent, Toy(), 16 * 2 + 1)
    buffer = io.BytesIO()  # through bytes, as a checkpoint file: a live state dict shares tensors
    torch.save(agent.state_dict(include_replay=True), buffer)
    buffer.seek(0)
    state = torch.load(buffer, weights_only=False)

    acting = make_agent(seed=5)  # an evaluator: no demonstrations
    acting.load_state_dict(state)
    record = Toy(seed=9).record()
    assert np.array_equal(acting.policy(record, None, explore=False)[0], agent.policy(record, None, explore=False)[0])

    resumed = make_agent(seed=5)
    resumed.set_demonstrations(*demonstrations())
    resumed.load_state_dict(state)
    a, b = drive(agent, Toy(seed=4), 16 * 2), drive(resumed, Toy(seed=4), 16 * 2)
    assert len(a) == len(b) == 2
    assert [m["ail/disc_loss"] for m in a] == [m["ail/disc_loss"] for m in b]
    assert [m["ail/reward"] for m in a] == [m["ail/reward"] for m in b]
