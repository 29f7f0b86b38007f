"""No-RSSM baseline: protocol and action bounds, window resets, training windows equal acting
windows, GAE at episode ends, the intent classifier learns from the window and never reaches the
policy as a label, the actor-critic learns a toy task, exact resume, non-finite losses."""

from __future__ import annotations

import io

import gymnasium as gym
import numpy as np
import pytest
import torch

from d2a_core.agents.baselines.no_rssm import NoRSSMAgent, build_assistant, gae_advantages
from d2a_core.agents.baselines.no_rssm_config import NoRSSMConfig
from d2a_core.agents.protocol import AssistantAgent
from d2a_core.errors import ConfigError, TrainingError, UsageError

INTENTS = ("left", "right")


def make_agent(obs_size: int = 3, action_size: int = 2, seed: int = 0, intents=INTENTS, **overrides) -> NoRSSMAgent:
    values = dict(units=32, layers=1, rollout_length=8, epochs=2, minibatches=2)
    values.update(overrides)
    return NoRSSMAgent(
        gym.spaces.Box(-np.inf, np.inf, (obs_size,), np.float32),
        gym.spaces.Box(-1.0, 1.0, (action_size,), np.float32),
        NoRSSMConfig(**values),
        intents,
        seed=seed,
    )


def random_records(n: int, steps: int, obs_size: int = 3, seed: int = 0, episode: int = 5):
    """Records of `n` envs with ragged episode starts (about one in `episode` steps)."""
    rng = np.random.default_rng(seed)
    for t in range(steps):
        first = np.ones(n, bool) if t == 0 else rng.random(n) < 1.0 / episode
        yield {
            "obs": rng.normal(size=(n, obs_size)).astype(np.float32),
            "reward": np.where(first, 0.0, rng.normal(size=n)).astype(np.float32),
            "is_first": first,
            "is_terminal": np.zeros(n, bool),
            "intent": rng.integers(0, 2, n),
        }


def drive(agent: NoRSSMAgent, env, records: int, explore: bool = True, learn: bool = True) -> list[dict]:
    """The runner's loop of the record protocol: act on every record, observe it, train when due."""
    state, metrics = None, []
    for _ in range(records):
        record = env.record()
        actions, state = agent.policy(record, state, explore=explore)
        if learn:
            agent.observe({**record, "action": actions, "intent": env.labels()})
            for _ in range(agent.updates_due(0)):
                metrics.append(agent.train_step())
        env.step(actions)
    return metrics


class ToyEnv:
    """`n` envs of `horizon`-step episodes ended by a time limit (not terminal), in the record
    protocol: after the last record the env resets and the next record has is_first."""

    def __init__(self, n: int, seed: int, horizon: int) -> None:
        self.n, self.rng, self.horizon = n, np.random.default_rng(seed), horizon
        self.t = np.zeros(n, int)
        self.reward = np.zeros(n, np.float32)
        self.first = np.ones(n, bool)
        self.done = np.zeros(n, bool)
        self.new_episode(np.ones(n, bool))
        self.obs = self.observe()

    def record(self) -> dict[str, np.ndarray]:
        return {"obs": self.obs.copy(), "reward": self.reward.copy(), "is_first": self.first.copy(),
                "is_terminal": np.zeros(self.n, bool)}

    def step(self, actions: np.ndarray) -> None:
        self.reward = np.where(self.done, 0.0, self.pay(actions)).astype(np.float32)
        self.first = self.done.copy()
        self.t = np.where(self.done, 0, self.t + 1)
        self.new_episode(self.done)
        self.done = self.t >= self.horizon - 1
        self.obs = self.observe()

    def labels(self) -> np.ndarray:
        return np.full(self.n, -1)

    def new_episode(self, mask: np.ndarray) -> None:
        pass


class Reach(ToyEnv):
    """obs: a target in [-0.8, 0.8], new every step; arriving pays 1 - |action - last target|."""

    def observe(self) -> np.ndarray:
        self.target = self.rng.uniform(-0.8, 0.8, self.n).astype(np.float32)
        return self.target[:, None].copy()

    def pay(self, actions: np.ndarray) -> np.ndarray:
        return 1.0 - np.abs(actions[:, 0] - self.target)


class Labelled(ToyEnv):
    """Each episode has a label k in {0, 1}; feature 0 is +-1 (by k) plus unit noise, so one
    frame tells k with at most 84% accuracy (Phi(1)) and a 16-frame window with ~100%."""

    def new_episode(self, mask: np.ndarray) -> None:
        self.label = np.where(mask, self.rng.integers(0, 2, self.n), getattr(self, "label", 0))

    def observe(self) -> np.ndarray:
        obs = self.rng.normal(size=(self.n, 3)).astype(np.float32)
        obs[:, 0] += np.where(self.label == 1, 1.0, -1.0)
        return obs

    def pay(self, actions: np.ndarray) -> np.ndarray:
        return np.zeros(self.n)

    def labels(self) -> np.ndarray:
        return self.label.copy()


# --- protocol, acting


def test_satisfies_the_protocol_and_acts_in_the_action_box():
    box = gym.spaces.Box(np.array([0.0, -10.0], np.float32), np.array([2.0, 10.0], np.float32), dtype=np.float32)
    agent = build_assistant(NoRSSMConfig(units=16, layers=1, init_std=1.0), gym.spaces.Box(-1, 1, (3,), np.float32),
                            box, INTENTS, seed=0, device="cpu")
    assert isinstance(agent, NoRSSMAgent) and isinstance(agent, AssistantAgent)
    record = next(random_records(64, 1))
    actions, state = agent.policy(record)
    assert actions.shape == (64, 2) and actions.dtype == np.float32
    assert np.all(actions >= box.low) and np.all(actions <= box.high)
    assert actions[:, 1].std() > 1.0  # exploration spans the box's scale, not [-1, 1]
    mode, _ = agent.policy(record, explore=False)
    unit = 2.0 * (mode - box.low) / (box.high - box.low) - 1.0
    assert np.abs(unit).max() < 0.05  # an untrained actor's mean: the box's middle
    probs = agent.intent_probs(state)
    assert probs.shape == (64, 2) and np.allclose(probs.sum(-1), 1.0, atol=1e-6)
    assert agent.intent_probs(agent.initial_state(3)).shape == (3, 2)


def test_rejects_unsupported_spaces_and_intents():
    box = gym.spaces.Box(-1, 1, (3,), np.float32)
    with pytest.raises(ConfigError):
        NoRSSMAgent(box, gym.spaces.Discrete(3), NoRSSMConfig(), INTENTS)
    with pytest.raises(ConfigError):
        NoRSSMAgent(box, gym.spaces.Box(-np.inf, np.inf, (2,), np.float32), NoRSSMConfig(), INTENTS)
    with pytest.raises(UsageError):
        NoRSSMAgent(box, box, NoRSSMConfig(), ["pass"])
    with pytest.raises(ValueError):
        NoRSSMConfig(init_std=2.0, max_std=1.0)


def test_is_first_resets_the_window():
    agent = make_agent()  # window 16
    rng = np.random.default_rng(1)
    n = 3
    state = None
    for t in range(6):  # some history in every env
        record = {"obs": rng.normal(size=(n, 3)).astype(np.float32), "is_first": np.full(n, t == 0)}
        _, state = agent.policy(record, state, explore=False)
    sequence = [rng.normal(size=(n, 3)).astype(np.float32) for _ in range(4)]
    fresh_agent, fresh_state = make_agent(), None
    for t, obs in enumerate(sequence):
        reset = np.array([t == 0, False, False])  # env 0 starts an episode, envs 1-2 go on
        actions, state = agent.policy({"obs": obs, "is_first": reset}, state, explore=False)
        fresh_actions, fresh_state = fresh_agent.policy({"obs": obs, "is_first": np.full(n, t == 0)},
                                                        fresh_state, explore=False)
        np.testing.assert_array_equal(actions[0], fresh_actions[0])
        np.testing.assert_array_equal(agent.intent_probs(state)[0], fresh_agent.intent_probs(fresh_state)[0])
        assert not np.array_equal(actions[1], fresh_actions[1])  # the history still counts there
    assert state.valid[0].sum() == 4 and state.valid[1].sum() == 10


def test_training_windows_are_the_windows_the_policy_saw():
    agent = make_agent(window=4, rollout_length=6)
    state, seen = None, []
    for record in random_records(4, 6 * 3 + 1, seed=2):  # three rollouts, across two rolls
        _, state = agent.policy(record, state)
        seen.append((state.window.clone(), state.valid.clone()))
        agent.observe({**record, "action": np.zeros((4, 2), np.float32)})
        if agent.updates_due(0):
            window, valid = agent._rollout_windows()
            for r, (w, v) in enumerate(seen[-7:]):  # records 0..T of this rollout
                torch.testing.assert_close(valid[:, r], v)
                torch.testing.assert_close(window[:, r] * valid[:, r, :, None], w)
            agent.train_step()
    assert agent.updates_done == 3


def test_gae_at_terminal_and_time_limit_ends():
    values = torch.tensor([[1.0, 2.0, 3.0, 4.0, 5.0]] * 2)
    rewards = torch.tensor([[0.0, 1.0, 2.0, 0.0, 4.0]] * 2)
    first = torch.tensor([[True, False, False, True, False]] * 2)
    terminal = torch.tensor([[False, False, True, False, False], [False] * 5])  # env 1: cut by a time limit
    adv, sample = gae_advantages(rewards, values, first, terminal, discount=0.5, lam=1.0)
    returns = adv + values[:, :4]
    assert sample.tolist() == [[True, True, False, True]] * 2  # record 2 ends its episode: no sample
    # env 0: record 1's transition ends in a terminal state, so nothing is bootstrapped
    assert returns[0].tolist() == [1.0 + 0.5 * 2.0, 2.0, values[0, 2].item(), 4.0 + 0.5 * 5.0]
    assert adv[0, 2] == 0.0
    # env 1: record 2 is the last record of a cut episode: V(record 2) bootstraps
    assert returns[1, :2].tolist() == [1.0 + 0.5 * (2.0 + 0.5 * 3.0), 2.0 + 0.5 * 3.0]
    # lambda = 0: one-step TD errors
    adv0, _ = gae_advantages(rewards, values, first, terminal, discount=0.5, lam=0.0)
    assert adv0[1, 0].item() == 1.0 + 0.5 * 2.0 - 1.0


# --- learning


def test_intent_classifier_learns_from_the_window_and_the_label_never_reaches_the_policy():
    agent = make_agent(units=64, rollout_length=32, intent_lr=1e-3)  # window 16
    metrics = drive(agent, Labelled(8, seed=0, horizon=32), 33 * 40)
    accuracy = [m["intent/accuracy"] for m in metrics]  # on each rollout before training on it
    assert accuracy[0] < 0.8
    assert np.mean(accuracy[-10:]) > 0.93  # above one frame's 0.84: it reads the window
    assert all(np.isfinite(m["intent/loss"]) for m in metrics)

    # A label in the record (or a different one) changes no action and no inferred intent.
    record = Labelled(5, seed=9, horizon=32).record()
    outputs = []
    for labels in (None, np.zeros(5, int), np.ones(5, int)):
        agent.act_generator.manual_seed(3)
        actions, state = agent.policy(record if labels is None else {**record, "intent": labels})
        outputs.append((actions, agent.intent_probs(state)))
    for actions, probs in outputs[1:]:
        np.testing.assert_array_equal(actions, outputs[0][0])
        np.testing.assert_array_equal(probs, outputs[0][1])


def test_unlabelled_records_train_no_classifier():
    agent = make_agent()
    before = [p.clone() for p in agent.nets.classifier.parameters()]
    for record in random_records(2, 9):
        record.pop("intent")
        agent.observe({**record, "action": np.zeros((2, 2), np.float32)})
    metrics = agent.train_step()
    assert "intent/loss" not in metrics and "intent/accuracy" not in metrics
    assert all(torch.equal(a, b) for a, b in zip(before, agent.nets.classifier.parameters()))
    with pytest.raises(UsageError):
        agent.observe({**record, "action": np.zeros((2, 2), np.float32), "intent": np.array([0, 2])})


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_actor_critic_learns_to_reach_the_target(seed):
    agent = make_agent(obs_size=1, action_size=1, seed=seed, window=4, units=64, rollout_length=16, epochs=4,
                       actor_lr=1e-3, critic_lr=1e-3)
    env = Reach(8, seed=seed, horizon=8)
    metrics = drive(agent, env, 16 * 60 + 1)
    assert agent.updates_done == 60
    rewards = [m["rollout/reward"] for m in metrics]
    assert np.mean(rewards[-5:]) > np.mean(rewards[:5]) + 0.15
    # Without exploration the actor's mean is close to every target.
    env = Reach(8, seed=100 + seed, horizon=8)
    errors = []
    state = None
    for _ in range(24):
        record = env.record()
        actions, state = agent.policy(record, state, explore=False)
        errors.append(np.abs(actions[:, 0] - env.target).mean())
        env.step(actions)
    assert np.mean(errors) < 0.15  # a random policy's error is ~0.45


# --- schedule, checkpoints, failures


def test_update_schedule_follows_the_rollout():
    agent = make_agent(rollout_length=4)
    records = random_records(2, 20)
    for _ in range(4):
        agent.observe({**next(records), "action": np.zeros((2, 2), np.float32)})
        assert agent.updates_due(100) == 0
    with pytest.raises(TrainingError):
        agent.train_step()
    agent.observe({**next(records), "action": np.zeros((2, 2), np.float32)})
    assert agent.updates_due(0) == 1
    with pytest.raises(UsageError):  # a full rollout takes no record before its update
        agent.observe({**next(records), "action": np.zeros((2, 2), np.float32)})
    agent.train_step()
    assert agent.updates_due(0) == 0 and agent.rollout.count == 1  # record T carried over
    with pytest.raises(UsageError):
        agent.observe({"obs": np.zeros((2, 3), np.float32)})


def test_state_dict_round_trip_resumes_exactly():
    records = list(random_records(3, 40, seed=5))
    original = make_agent(seed=4)
    state = None
    for record in records[:20]:  # two updates, then part of a rollout
        actions, state = original.policy(record, state)
        original.observe({**record, "action": actions})
        for _ in range(original.updates_due(0)):
            original.train_step()
    buffer = io.BytesIO()
    torch.save(original.state_dict(include_replay=True), buffer)
    buffer.seek(0)
    resumed = make_agent(seed=99)
    resumed.load_state_dict(torch.load(buffer, weights_only=False))

    outputs = {id(original): [], id(resumed): []}
    for agent in (original, resumed):
        agent_state = state
        for record in records[20:]:
            actions, agent_state = agent.policy(record, agent_state)
            agent.observe({**record, "action": actions})
            outputs[id(agent)].append(actions)
            for _ in range(agent.updates_due(0)):
                metrics = {k: v for k, v in agent.train_step().items() if not k.startswith("time/")}
                outputs[id(agent)].append(metrics)
    assert len(outputs[id(original)]) == len(records) - 20 + 2
    for a, b in zip(outputs[id(original)], outputs[id(resumed)]):
        if isinstance(a, dict):
            assert a == b
        else:
            np.testing.assert_array_equal(a, b)

    # Without the rollout the next one starts empty; other settings must match.
    light = make_agent(seed=7)
    light.load_state_dict(original.state_dict())
    assert light.rollout.count == 0 and light.updates_done == original.updates_done
    with pytest.raises(ConfigError):
        make_agent(units=16).load_state_dict(original.state_dict())
    with pytest.raises(ConfigError):
        make_agent(intents=("pass", "stay")).load_state_dict(original.state_dict())


def test_non_finite_loss_raises_and_changes_nothing():
    agent = make_agent()
    records = random_records(2, 17, seed=3)
    for _ in range(9):
        agent.observe({**next(records), "action": np.zeros((2, 2), np.float32)})
    agent.train_step()  # the optimiser has state now
    for t in range(8):
        record = next(records)
        if t == 3:
            record["reward"] = np.array([np.nan, 0.0], np.float32)
        agent.observe({**record, "action": np.zeros((2, 2), np.float32)})
    before = io.BytesIO()
    torch.save(agent.state_dict(include_replay=True), before)
    with pytest.raises(TrainingError, match="non-finite"):
        agent.train_step()
    after = agent.state_dict(include_replay=True)
    saved = torch.load(io.BytesIO(before.getvalue()), weights_only=False)
    for name, value in saved["nets"].items():
        assert torch.equal(value, after["nets"][name]), name
    torch.testing.assert_close(saved["optimizer"]["state"], after["optimizer"]["state"])
    assert saved["return_moments"]["count"] == after["return_moments"]["count"]
    np.testing.assert_array_equal(saved["obs_moments"]["mean"], after["obs_moments"]["mean"])
    assert torch.equal(saved["train_rng"], after["train_rng"])
    assert agent.updates_done == 1 and agent.updates_due(0) == 1  # the rollout is kept
