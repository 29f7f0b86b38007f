"""The assistant's reward (paper equation 6) against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from d2a_core.objectives.assistant import (
    AssistantRewardConfig,
    assistant_reward,
    combine,
    pick_intent,
    totals_by_intent,
)


def test_defaults_are_the_papers_main_method():
    cfg = AssistantRewardConfig()
    # r^interv = -||a_A||_2 has unit weight in the paper; Dream2Assist is alpha_r = 1, alpha_a = 0.
    assert (cfg.w_interv, cfg.alpha_r, cfg.alpha_a) == (1.0, 1.0, 0.0)
    assert cfg.expert_action_penalty and cfg.clip_blend


def test_every_term_by_hand():
    cfg = AssistantRewardConfig(alpha_r=1.0, alpha_a=1.0)
    terms = assistant_reward(
        task=np.array([0.0, -100.0]),
        assistant_action=np.array([[0.3, 0.4], [0.0, 0.0]]),
        human_action=np.array([[0.5, 0.5], [1.0, 1.0]]),
        expert_reward=np.array([2.0, -50.0]),
        expert_action=np.array([[0.5, 0.5], [1.0, 1.0]]),
        cfg=cfg,
    )
    assert terms.intervention == pytest.approx([0.5, 0.0])         # ||(0.3, 0.4)|| = 0.5
    assert terms.expert_distance == pytest.approx([0.5, 0.0])      # ||(0.8, 0.9) - (0.5, 0.5)||
    assert terms.expert_reward == pytest.approx([2.0, -50.0])
    # 0 - 0.5 + 2 - 0.5 = 1;  -100 - 0 - 50 - 0 = -150
    assert terms.total == pytest.approx([1.0, -150.0])


def test_intervention_weight_and_the_action_term_sign():
    a_assist, a_human = np.array([[0.0, 0.6]]), np.array([[0.0, 0.0]])
    a_star = np.array([[0.0, -0.2]])  # distance 0.8
    base = dict(task=np.array([1.0]), assistant_action=a_assist, human_action=a_human,
                expert_reward=np.array([3.0]), expert_action=a_star)
    # 1 - 0.1 * 0.6 + 0.5 * 3 - 2 * 0.8 = 0.84
    cfg = AssistantRewardConfig(w_interv=0.1, alpha_r=0.5, alpha_a=2.0)
    assert assistant_reward(**base, cfg=cfg).total == pytest.approx([0.84])
    # the paper's printed sign pays for the distance: 1 - 0.06 + 1.5 + 1.6 = 4.04
    literal = AssistantRewardConfig(w_interv=0.1, alpha_r=0.5, alpha_a=2.0, expert_action_penalty=False)
    assert assistant_reward(**base, cfg=literal).total == pytest.approx([4.04])


def test_distance_is_taken_from_the_executed_clipped_action():
    base = dict(task=np.zeros(1), assistant_action=np.array([[0.6, 0.0]]), human_action=np.array([[0.9, 0.0]]),
                expert_reward=np.zeros(1), expert_action=np.array([[0.0, 0.0]]))
    clipped = assistant_reward(**base, cfg=AssistantRewardConfig(alpha_a=1.0))
    assert clipped.expert_distance == pytest.approx([1.0])  # clip(1.5) = 1
    raw = assistant_reward(**base, cfg=AssistantRewardConfig(alpha_a=1.0, clip_blend=False))
    assert raw.expert_distance == pytest.approx([1.5])
    assert clipped.intervention == pytest.approx([0.6]) and clipped.total == pytest.approx([-1.6])


def test_a_method_without_experts_needs_none_and_a_missing_weighted_term_is_an_error():
    dreamer = AssistantRewardConfig(alpha_r=0.0, alpha_a=0.0)
    terms = assistant_reward(np.array([100.0, 0.0]), np.array([[0.3, 0.4], [0.0, 1.0]]), np.zeros((2, 2)),
                             None, None, dreamer)
    assert terms.total == pytest.approx([99.5, -1.0])
    assert np.isnan(terms.expert_reward).all() and np.isnan(terms.expert_distance).all()
    with pytest.raises(ValueError, match="r_hat"):
        assistant_reward(np.zeros(1), np.zeros((1, 2)), np.zeros((1, 2)), None, np.zeros((1, 2)),
                         AssistantRewardConfig(alpha_r=1.0))
    with pytest.raises(ValueError, match="a\\*"):
        assistant_reward(np.zeros(1), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1), None,
                         AssistantRewardConfig(alpha_a=1.0))


def test_logged_terms_recompute_any_variant():
    rng = np.random.default_rng(0)
    n = 6
    terms = assistant_reward(rng.normal(size=n), rng.uniform(-1, 1, (n, 2)), rng.uniform(-1, 1, (n, 2)),
                             rng.normal(size=n), rng.uniform(-1, 1, (n, 2)), AssistantRewardConfig())
    variant = AssistantRewardConfig(alpha_r=0.0, alpha_a=1.0, w_interv=0.3)
    expected = terms.task - 0.3 * terms.intervention - terms.expert_distance
    assert combine(terms.task, terms.intervention, terms.expert_reward, terms.expert_distance, variant) == \
        pytest.approx(expected)
    assert set(terms.as_dict()) == {"task", "intervention", "expert_reward", "expert_distance", "total"}


def test_pick_intent_takes_each_envs_inferred_expert():
    rewards = np.array([[1.0, 2.0, 3.0], [10.0, 20.0, 30.0]])  # (intents, envs)
    assert pick_intent(rewards, np.array([1, 0, 1])) == pytest.approx([10.0, 2.0, 30.0])
    actions = np.arange(12.0).reshape(2, 3, 2)
    assert pick_intent(actions, np.array([0, 1, 0])).tolist() == [[0.0, 1.0], [8.0, 9.0], [4.0, 5.0]]
    with pytest.raises(ValueError, match="outside"):
        pick_intent(rewards, np.array([2, 0, 0]))
    with pytest.raises(ValueError, match="environments"):
        pick_intent(rewards, np.array([0, 0]))


def test_totals_by_intent_are_the_reward_under_each_inferred_intent_by_hand():
    cfg = AssistantRewardConfig(alpha_r=1.0, alpha_a=1.0)
    totals = totals_by_intent(
        task=np.array([0.0, 10.0]),
        assistant_action=np.array([[0.3, 0.4], [0.0, 0.0]]),
        human_action=np.array([[0.5, 0.5], [1.0, 1.0]]),
        expert_rewards=np.array([[2.0, 5.0], [-3.0, 1.0]]),               # (intents, envs)
        expert_actions=np.array([[[0.5, 0.5], [1.0, 1.0]], [[0.8, 0.9], [1.0, 0.0]]]),
        cfg=cfg,
    )
    # env 0: blended (0.8, 0.9), ||a_A|| 0.5; intent 0: 0 - 0.5 + 2 - 0.5 = 1; intent 1: 0 - 0.5 - 3 - 0 = -3.5
    # env 1: blended (1, 1), no intervention; intent 0: 10 + 5 - 0 = 15; intent 1: 10 + 1 - 1 = 10
    assert totals == pytest.approx(np.array([[1.0, 15.0], [-3.5, 10.0]]))
    # row k is exactly what assistant_reward gives with intent k's expert
    for k in range(2):
        alone = assistant_reward(np.array([0.0, 10.0]), np.array([[0.3, 0.4], [0.0, 0.0]]),
                                 np.array([[0.5, 0.5], [1.0, 1.0]]), np.array([[2.0, 5.0], [-3.0, 1.0]])[k],
                                 np.array([[[0.5, 0.5], [1.0, 1.0]], [[0.8, 0.9], [1.0, 0.0]]])[k], cfg)
        assert totals[k] == pytest.approx(alone.total)


def test_the_retired_crash_forfeit_loads_only_at_its_former_default():
    """Stored records may carry `crash_forfeit: false` (a retired experiment); true names the key."""
    assert AssistantRewardConfig.model_validate({"crash_forfeit": False}) == AssistantRewardConfig()
    with pytest.raises(ValueError, match="'crash_forfeit' is a retired setting"):
        AssistantRewardConfig.model_validate({"crash_forfeit": True})
