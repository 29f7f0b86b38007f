"""The shared-control collector: who sees what, the blended action, the assistant's reward terms,
the label as a target only, and paired episodes defined by their spec."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from d2a_core.agents.dreamer.agent import PolicyState
from d2a_core.agents.dreamer.expert import ExpertPrediction
from d2a_core.agents.dreamer.latent import Latent
from d2a_core.agents.protocol import AssistantAgent
from d2a_core.objectives.assistant import AssistantRewardConfig, combine
from d2a_core.sim.race_env import EnvConfig, RaceEnv
from d2a_core.tracks.sources import load_track_source
from d2a_core.training.shared_rollout import ASSISTANT_TERMS, EpisodeSpec, HumanDrivers, SharedCollector

PAIR = ("pass", "stay")


@pytest.fixture(scope="module")
def track():
    return load_track_source("straightaway").track


class ScriptedHuman:
    """A stand-in for a frozen DreamerAgent: a constant action; records what it was shown."""

    def __init__(self, action):
        self.action = np.asarray(action, np.float32)
        self.seen: list[np.ndarray] = []
        self.executed: list[np.ndarray] = []

    def initial_state(self, n):
        return PolicyState(Latent(torch.zeros(n, 1), torch.zeros(n, 1, dtype=torch.long), None), torch.zeros(n, 2))

    def policy(self, obs_batch, state, explore=True, generator=None):
        self.seen.append(np.array(obs_batch["obs"]))
        n = len(obs_batch["obs"])
        h = state.latent.h + 1.0  # counts the steps of each env's episode...
        h = torch.where(torch.as_tensor(obs_batch["is_first"]).reshape(n, 1), torch.ones_like(h), h)  # ...from 1
        acts = np.tile(self.action, (n, 1))
        return acts, PolicyState(Latent(h, state.latent.index, None), torch.as_tensor(acts))

    def with_action(self, state, env_actions):
        self.executed.append(np.array(env_actions))
        return PolicyState(state.latent, torch.as_tensor(np.asarray(env_actions, np.float32)))


class ScriptedAssistant:
    """A constant action and a fixed intent estimate; records its inputs."""

    def __init__(self, action, probs=None):
        self.action = np.asarray(action, np.float32)
        self.probs = probs
        self.inputs: list[dict] = []
        self.observed: list[dict] = []

    def initial_state(self, n):
        return None

    def policy(self, obs_batch, state=None, explore=True):
        self.inputs.append({k: np.array(v) for k, v in obs_batch.items()})
        return np.tile(self.action, (len(obs_batch["obs"]), 1)), state

    def intent_probs(self, state):
        if self.probs is None:
            return None
        return np.tile(np.asarray(self.probs, np.float32), (len(self.inputs[-1]["obs"]), 1))

    def observe(self, transition):
        self.observed.append({k: np.array(v) for k, v in transition.items()})

    def updates_due(self, env_steps):
        return 0

    def train_step(self):
        return {}

    def state_dict(self, include_replay=False):
        return {}

    def load_state_dict(self, state):
        pass


class ConstantExpert:
    """An expert filter stand-in: predicts `reward` and `action` always; records its inputs."""

    def __init__(self, reward, action):
        self.reward, self.action = reward, np.asarray(action, np.float32)
        self.steps: list[tuple[np.ndarray, np.ndarray | None]] = []

    def reset(self, mask):
        pass

    def step(self, obs, blended):
        self.steps.append((np.array(obs), None if blended is None else np.array(blended)))
        n = len(obs)
        return ExpertPrediction(np.full(n, self.reward, np.float32), np.tile(self.action, (n, 1)))


def specs(n, human=0, label=0):
    queue = iter([EpisodeSpec(seed=100 + k, human=human, label=label) for k in range(n)])
    return lambda: next(queue, None)


def run(collector, steps=None):
    rows = []
    k = 0
    while not collector.idle and (steps is None or k < steps):
        rows.extend(collector.step(explore=False, learn=True))
        k += 1
    return rows


def test_each_driver_sees_the_others_last_action_and_the_car_gets_the_clipped_sum(track):
    human = ScriptedHuman([0.9, 0.8])
    assistant = ScriptedAssistant([0.3, 0.4])
    env = RaceEnv(track)
    collector = SharedCollector([env], HumanDrivers([human], 1, explore=False, seed=0), PAIR, specs(1),
                                assistant=assistant, reward_config=AssistantRewardConfig(alpha_r=0.0))
    rows = run(collector, steps=5)
    assert not rows
    assert isinstance(assistant, AssistantAgent)
    np.testing.assert_array_equal(human.seen[0][0, -2:], [0.0, 0.0])  # nobody has acted yet
    for seen in human.seen[1:]:
        np.testing.assert_allclose(seen[0, -2:], [0.3, 0.4])  # the assistant's last action
    for inputs in assistant.inputs[1:]:
        np.testing.assert_allclose(inputs["obs"][0, -2:], [0.9, 0.8])  # the human's last action
    # the car executed clip(a_H + a_A) = (1.0, 1.0) and the human's state continued with it
    np.testing.assert_allclose(env._applied, [1.0, 1.0])
    np.testing.assert_allclose(human.executed[-1][0], [1.0, 1.0])


def test_the_intent_label_is_a_training_target_never_an_input(track):
    """The same episode with the human labelled pass or stay: identical assistant inputs; the
    label reaches only `observe`."""
    inputs = {}
    for label in (0, 1):
        assistant = ScriptedAssistant([0.0, 0.2])
        collector = SharedCollector([RaceEnv(track)], HumanDrivers([ScriptedHuman([0.0, 0.6])], 1, False, 0), PAIR,
                                    specs(1, label=label), assistant=assistant,
                                    reward_config=AssistantRewardConfig(alpha_r=0.0))
        run(collector, steps=30)
        assert all(set(i) == {"obs", "reward", "is_first", "is_terminal"} for i in assistant.inputs)
        assert all((o["intent"] == label).all() for o in assistant.observed)
        inputs[label] = np.stack([i["obs"] for i in assistant.inputs])
    np.testing.assert_array_equal(inputs[0], inputs[1])


def test_the_reward_is_equation_6_of_the_logged_terms_and_experts_are_read_at_the_inferred_intent(track):
    """y_hat = stay (index 1): r_hat* and a* come from the stay expert; the reward the assistant
    receives is `combine` of the logged terms; experts see an empty partner slot and the blended action."""
    cfg = AssistantRewardConfig(alpha_r=1.0, alpha_a=1.0, w_interv=0.5)
    experts = [ConstantExpert(-50.0, [1.0, 1.0]), ConstantExpert(7.0, [0.0, 0.0])]
    assistant = ScriptedAssistant([0.0, 0.3], probs=[0.2, 0.8])
    collector = SharedCollector([RaceEnv(track)], HumanDrivers([ScriptedHuman([0.1, 0.4])], 1, False, 0), PAIR,
                                specs(1), assistant=assistant, experts=experts, reward_config=cfg, keep_steps=True)
    rows = run(collector)
    assert len(rows) == 1
    terms = np.array(rows[0]["steps_log"]["terms"])
    task, intervention, r_star, distance, total = terms.T
    np.testing.assert_allclose(intervention, 0.3)
    np.testing.assert_allclose(r_star, 7.0)  # the stay expert's prediction
    np.testing.assert_allclose(distance, np.hypot(0.1, 0.7), rtol=1e-6)  # ||clip(a_H + a_A) - a*_stay||
    np.testing.assert_allclose(total, combine(task, intervention, r_star, distance, cfg))
    received = np.concatenate([o["reward"] for o in assistant.observed])[1:len(total) + 1]
    np.testing.assert_allclose(received, total, rtol=1e-6)
    for name, column in zip(ASSISTANT_TERMS, terms.T):
        assert rows[0][f"assist/{name}"] == pytest.approx(column.sum())
    assert rows[0]["intent_accuracy"] == 0.0 and rows[0]["intent_counts"] == [0, len(total)]
    for obs, blended in experts[1].steps[1:len(total) + 1]:  # (later calls: the env had ended)
        np.testing.assert_array_equal(obs[:, -2:], 0.0)
        np.testing.assert_allclose(blended, [[0.1, 0.7]])


def test_an_expert_weighted_reward_without_experts_or_an_intent_estimate_is_refused(track):
    human = HumanDrivers([ScriptedHuman([0.0, 0.5])], 1, False, 0)
    with pytest.raises(ValueError, match="no expert filters"):
        SharedCollector([RaceEnv(track)], human, PAIR, specs(1), assistant=ScriptedAssistant([0, 0]),
                        reward_config=AssistantRewardConfig(alpha_r=1.0))
    collector = SharedCollector([RaceEnv(track)], human, PAIR, specs(1), assistant=ScriptedAssistant([0, 0]),
                                experts=[ConstantExpert(0, [0, 0]), ConstantExpert(0, [0, 0])],
                                reward_config=AssistantRewardConfig(alpha_r=1.0))
    with pytest.raises(ValueError, match="no intent estimate"):
        collector.step()


def test_episodes_are_defined_by_their_spec_not_by_the_order_they_end(track):
    """Three specs over two envs, run twice with the envs in another order of availability:
    the same rows for the same specs; each human drives its own episodes."""
    humans = [ScriptedHuman([0.0, 1.0]), ScriptedHuman([0.5, 0.2])]
    spec_list = [EpisodeSpec(seed=s, human=h, label=h) for s, h in ((1, 0), (2, 1), (3, 0))]

    def rows_of(n_envs, order):
        queue = iter([spec_list[k] for k in order])
        collector = SharedCollector([RaceEnv(track) for _ in range(n_envs)], HumanDrivers(humans, n_envs, False, 0),
                                    PAIR, lambda: next(queue, None))
        return {(r["human"], r["seed"]): r for r in run(collector)}

    a, b = rows_of(2, [0, 1, 2]), rows_of(3, [2, 0, 1])
    assert set(a) == set(b) == {(0, 1), (1, 2), (0, 3)}
    for key in a:
        for metric in ("progress_m", "return", "steps", "finished", "collision"):
            assert a[key][metric] == b[key][metric], (key, metric)
    assert a[(1, 2)]["intent"] == "stay" and a[(0, 1)]["intent"] == "pass"
    assert a[(0, 1)]["mean_speed_m_s"] != a[(1, 2)]["mean_speed_m_s"]  # different humans drove


class CountingHuman(ScriptedHuman):
    """Also records the is_first flags it was given."""

    def __init__(self, action):
        super().__init__(action)
        self.firsts: list[np.ndarray] = []

    def policy(self, obs_batch, state, explore=True, generator=None):
        self.firsts.append(np.array(obs_batch["is_first"]))
        return super().policy(obs_batch, state, explore, generator)


def test_an_intent_swap_replaces_the_human_at_the_drawn_step(track):
    """Before step 7 human 0 (pass) drives; from step 7 human 1 (stay), from a blank state, and
    the true label the step logs carry flips at the same step."""
    first, second = CountingHuman([0.0, 0.8]), CountingHuman([0.0, -0.2])
    spec = EpisodeSpec(seed=5, human=0, label=0, swap_step=7, swap_human=1, swap_label=1)
    queue = iter([spec])
    assistant = ScriptedAssistant([0.0, 0.0], probs=[0.3, 0.7])
    collector = SharedCollector([RaceEnv(track)], HumanDrivers([first, second], 1, False, 0), PAIR,
                                lambda: next(queue, None), assistant=assistant,
                                reward_config=AssistantRewardConfig(alpha_r=0.0), keep_steps=True)
    rows = run(collector)
    assert len(first.seen) == 7 and len(second.seen) == len(rows[0]["steps_log"]["labels"]) - 7
    assert first.firsts[0][0] and not any(f[0] for f in first.firsts[1:])
    assert second.firsts[0][0] and not any(f[0] for f in second.firsts[1:])  # a blank state at the swap
    labels = rows[0]["steps_log"]["labels"]
    assert labels[:7] == [0] * 7 and set(labels[7:]) == {1}
    accuracy = np.mean(np.array(rows[0]["steps_log"]["y_hat"]) == np.array(labels))
    assert rows[0]["intent_accuracy"] == pytest.approx(accuracy)
    assert "intent_counts" not in rows[0]  # one label per episode no longer holds


class RampHuman(ScriptedHuman):
    """Accelerates by 0.01 more on every step of its episode, so each action names its step."""

    def policy(self, obs_batch, state, explore=True, generator=None):
        _, state = super().policy(obs_batch, state, explore, generator)
        acts = np.concatenate([np.zeros_like(state.latent.h.numpy()), state.latent.h.numpy() / 100], 1)
        return acts.astype(np.float32), PolicyState(state.latent, torch.as_tensor(acts))


def test_a_partner_window_shows_the_humans_earlier_actions_newest_first(track):
    """Window 4: after the env's observation (partner slot = the human's last action, 0.01 * t at
    step t + 1) come the 3 actions before it, zeros before the episode's start, again from zero in
    the next episode; window 1 is the env's observation itself."""
    views = {}
    for window in (1, 4):
        assistant = ScriptedAssistant([0.0, 0.0])
        env = RaceEnv(track, env_config=EnvConfig(time_limit_s=1.0))
        collector = SharedCollector([env], HumanDrivers([RampHuman([0, 0])], 1, False, 0), PAIR, specs(2),
                                    assistant=assistant, reward_config=AssistantRewardConfig(alpha_r=0.0),
                                    partner_window=window)
        run(collector)
        views[window] = np.stack([i["obs"][0] for i in assistant.inputs])
        firsts = np.flatnonzero(np.stack([i["is_first"][0] for i in assistant.inputs]))
    base, wide = views[1], views[4]
    assert wide.shape[1] == base.shape[1] + 6
    np.testing.assert_array_equal(wide[:, :base.shape[1]], base)
    assert len(firsts) == 2
    for start in firsts:
        for t in range(8):
            row = wide[start + t]
            assert row[base.shape[1] - 1] == pytest.approx(0.01 * t)  # the slot: a_H at step t - 1
            expected = [0.01 * (t - k) if t - k > 0 else 0.0 for k in (1, 2, 3)]
            np.testing.assert_allclose(row[base.shape[1]:].reshape(3, 2)[:, 1], expected, atol=1e-6)
            np.testing.assert_array_equal(row[base.shape[1]:].reshape(3, 2)[:, 0], 0.0)
