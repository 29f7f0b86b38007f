"""ExpertFilter: a frozen expert's world model filtered along the assistant's episodes, so that
r_hat* and a* depend on the episode's history; a reset forgets it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from d2a_core.agents.dreamer.expert import ExpertFilter

ENVS = 2


@pytest.fixture
def expert(make_agent):
    agent = make_agent(seed=0)
    # DreamerV3 starts the reward head's and the actor's output layers at zero, so an untrained
    # expert would predict reward 0 and mean action 0 everywhere: give them weights, as training would.
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        torch.nn.init.normal_(agent.world_model.reward_head.out.weight, std=1.0)
        torch.nn.init.normal_(agent.behavior.actor.net.out.weight, std=1.0)
    return agent


def _obs(rng) -> np.ndarray:
    return rng.normal(size=(ENVS, 3)).astype(np.float32)


def _act(rng) -> np.ndarray:
    return rng.uniform(-1, 1, (ENVS, 2)).astype(np.float32)


def _run(filter_: ExpertFilter, history_seed: int, steps: int = 6):
    """Start an episode in every env and step it along `steps` observations of one history."""
    rng = np.random.default_rng(history_seed)
    filter_.reset(np.ones(ENVS, bool))
    out = filter_.step(_obs(rng), None)
    for _ in range(steps - 1):
        out = filter_.step(_obs(rng), _act(rng))
    return out


def test_predictions_depend_on_the_history(expert):
    now_obs, now_action = _obs(np.random.default_rng(100)), _act(np.random.default_rng(101))
    results = []
    for history in (1, 2):
        filter_ = ExpertFilter(expert, ENVS, sample=False, seed=0)
        _run(filter_, history)
        results.append(filter_.step(now_obs, now_action))
    (reward_a, action_a), (reward_b, action_b) = results
    assert reward_a.shape == (ENVS,) and action_a.shape == (ENVS, 2)
    assert np.all(np.abs(reward_a - reward_b) > 1e-4)
    assert np.all(np.abs(action_a - action_b).max(-1) > 1e-4)
    # The same history gives the same predictions (nothing else enters) ...
    again = ExpertFilter(expert, ENVS, sample=False, seed=0)
    _run(again, 1)
    assert np.array_equal(again.step(now_obs, now_action).action, action_a)
    # ... and the blended action executed last enters the state the reward is read at.
    other = ExpertFilter(expert, ENVS, sample=False, seed=0)
    _run(other, 1)
    assert np.all(np.abs(other.step(now_obs, -now_action).reward - reward_a) > 1e-4)


def test_reset_forgets_the_history_of_the_masked_envs_only(expert):
    rng = np.random.default_rng(5)
    now_obs, now_action = _obs(rng), _act(rng)
    filter_ = ExpertFilter(expert, ENVS, sample=False, seed=0)
    _run(filter_, 1)
    filter_.reset(np.array([True, False]))
    filter_.generator.manual_seed(9)  # the same latent-sampling noise as the fresh filter's
    after_reset = filter_.step(now_obs, now_action)
    fresh = ExpertFilter(expert, ENVS, sample=False, seed=9)
    first = fresh.step(now_obs, None)
    assert np.array_equal(after_reset.action[0], first.action[0])
    assert after_reset.reward[0] == 0.0 and np.all(first.reward == 0.0)  # nothing led here
    assert np.abs(after_reset.action[1] - first.action[1]).max() > 1e-4  # env 1 kept its history
    assert after_reset.reward[1] != 0.0


def test_filtering_equals_stepping_the_experts_own_policy_by_hand(expert):
    act_rng_before = expert.act_generator.get_state()
    filter_ = ExpertFilter(expert, ENVS, sample=True, seed=3)
    generator = torch.Generator().manual_seed(3)
    rng = np.random.default_rng(7)
    state, blended = None, None
    for t in range(8):
        obs = _obs(rng)
        is_first = np.array([t == 0, t in (0, 4)])  # env 1 starts a second episode at t = 4
        if t == 4:
            filter_.reset(np.array([False, True]))
        out = filter_.step(obs, blended)
        if state is not None:
            state = expert.with_action(state, blended)
        action, state = expert.policy({"obs": obs, "is_first": is_first}, state, explore=True, generator=generator)
        with torch.no_grad():
            reward = expert.world_model.reward(state.latent).numpy()
        assert np.array_equal(out.action, action)
        assert np.array_equal(out.reward, np.where(is_first, 0.0, reward).astype(np.float32))
        blended = _act(rng)
    # The expert is untouched: its own acting generator was not drawn from, no gradients exist.
    assert torch.equal(expert.act_generator.get_state(), act_rng_before)
    assert all(p.grad is None for p in expert.world_model.parameters())


def test_a_continuing_env_needs_the_blended_action(expert):
    filter_ = ExpertFilter(expert, ENVS)
    rng = np.random.default_rng(0)
    filter_.step(_obs(rng), None)
    with pytest.raises(ValueError, match="blended_action"):
        filter_.step(_obs(rng), None)
