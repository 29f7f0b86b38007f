"""DreamerAgent: acting, train-ratio schedule, checkpoint state and exact resume, non-finite
loss handling, extra world-model heads, discrete actions."""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from d2a_core.agents.dreamer import (
    DreamerAgent,
    DreamerConfig,
    HeadConfig,
    WorldModelHead,
    register_head,
)
from d2a_core.agents.dreamer.heads import latent_mlp
from d2a_core.errors import ConfigError, TrainingError, UsageError


def _first_step(n: int, obs_size: int = 3, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "obs": rng.normal(size=(n, obs_size)).astype(np.float32),
        "reward": np.zeros(n, np.float32),
        "is_first": np.ones(n, bool),
        "is_terminal": np.zeros(n, bool),
    }


def test_policy_acts_in_the_action_space_and_resets_on_is_first(make_agent):
    agent = make_agent()
    step = _first_step(5)
    actions, state = agent.policy(step)
    assert actions.shape == (5, 2) and actions.dtype == np.float32
    assert np.abs(actions).max() <= 1.0
    # Continue some steps, then reset env 0 only: its state equals a fresh start's.
    for _ in range(3):
        actions, state = agent.policy({**step, "is_first": np.zeros(5, bool)}, state)
    agent.act_generator.manual_seed(11)
    reset = {**step, "is_first": np.array([True, False, False, False, False])}
    _, after_reset = agent.policy(reset, state)
    agent.act_generator.manual_seed(11)
    _, fresh = agent.policy(reset, None)
    assert torch.allclose(after_reset.latent.h[0], fresh.latent.h[0], atol=1e-6)
    assert not torch.allclose(after_reset.latent.h[1], fresh.latent.h[1], atol=1e-3)
    # Without exploration the action is the actor's mean, strictly inside the bounds.
    mean_actions, _ = agent.policy(step, None, explore=False)
    assert np.abs(mean_actions).max() < 1.0


def test_box_action_bounds_are_mapped_to_the_unit_interval():
    agent = DreamerAgent(
        gym.spaces.Box(-1, 1, (3,), np.float32),
        gym.spaces.Box(np.array([0.0, -10.0], np.float32), np.array([2.0, 10.0], np.float32), dtype=np.float32),
        DreamerConfig(units=16, layers=1, deter=16, stoch=2, classes=3, bins=11, bin_range=3.0),
    )
    actions, _ = agent.policy(_first_step(64))
    assert (actions[:, 0] >= 0).all() and (actions[:, 0] <= 2).all()
    assert (np.abs(actions[:, 1]) <= 10).all() and np.abs(actions[:, 1]).max() > 1.0
    internal = agent._to_internal_action(np.array([[0.0, 10.0], [2.0, -10.0]]))
    assert torch.allclose(internal, torch.tensor([[-1.0, 1.0], [1.0, -1.0]]))


def test_updates_due_follows_the_train_ratio(make_agent, fill_random):
    # batch 4 x 8 = 32 replayed steps per update; ratio 16 -> one update every 2 env steps.
    agent = make_agent(train_ratio=16.0, prefill_steps=40)
    fill_random(agent, 10)
    assert agent.updates_due(39) == 0  # before prefill
    assert agent.updates_due(40) == 1  # first update at prefill
    assert agent.updates_due(41) == 1
    assert agent.updates_due(42) == 2
    assert agent.updates_due(140) == 51
    agent.train_step()
    assert agent.updates_done == 1
    assert agent.updates_due(140) == 50
    # Paper semantics: ratio 512 with batch 16 x 64 is 0.5 updates per env step.
    paper = DreamerConfig()
    assert paper.train_ratio / paper.replayed_steps_per_update == 0.5


def test_updates_wait_for_a_full_sequence(make_agent, fill_random):
    agent = make_agent()
    fill_random(agent, 5)  # fewer steps per stream than batch_length 8
    assert agent.updates_due(1000) == 0
    with pytest.raises(TrainingError, match="batch length"):
        agent.train_step()


def test_train_step_reports_finite_metrics_and_changes_weights(make_agent, fill_random):
    agent = make_agent()
    fill_random(agent, 30)
    before = [p.detach().clone() for p in agent.behavior.actor.parameters()]
    metrics = agent.train_step()
    for key in ("wm/loss", "wm/kl_dyn", "actor/loss", "critic/loss", "return_norm/scale", "actor/entropy"):
        assert np.isfinite(metrics[key]), key
    assert metrics["wm/kl_dyn"] >= 0
    assert any(not torch.equal(a, p) for a, p in zip(before, agent.behavior.actor.parameters()))


def _snapshot(agent: DreamerAgent) -> dict[str, torch.Tensor]:
    tensors = {}
    for name, module in (("wm", agent.world_model), ("beh", agent.behavior)):
        for key, value in module.state_dict().items():
            tensors[f"{name}.{key}"] = value.detach().clone()
    for name, opt in (("mo", agent.model_opt), ("ao", agent.actor_opt), ("co", agent.critic_opt)):
        for index, state in opt.state_dict()["state"].items():
            for key, value in state.items():
                tensors[f"{name}.{index}.{key}"] = torch.as_tensor(value).clone()
    return tensors


def test_same_seed_same_updates_on_two_threads(make_agent, fill_random):
    """Reproducibility: two agents built and trained with the same seed end bit-identical, at a
    size where the compiled kernels and PyTorch's ops run on both threads."""
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    sizes = dict(units=64, deter=64, stoch=32, classes=32, batch_size=16, batch_length=16)
    snapshots = []
    try:
        for _ in range(2):
            agent = make_agent(seed=3, **sizes)
            fill_random(agent, 40, envs=8)
            for _ in range(2):
                agent.train_step()
            snapshots.append(_snapshot(agent))
    finally:
        torch.set_num_threads(threads)
    first, second = snapshots
    assert first.keys() == second.keys()
    assert all(torch.equal(first[key], second[key]) for key in first)


def test_state_dict_round_trip_gives_identical_actions_and_updates(make_agent, fill_random):
    agent = make_agent(seed=0)
    fill_random(agent, 30)
    agent.train_step()
    agent.train_step()
    buffer = io.BytesIO()
    torch.save(agent.state_dict(include_replay=True), buffer)
    buffer.seek(0)

    clone = make_agent(seed=123)
    clone.load_state_dict(torch.load(buffer, weights_only=False))
    step = _first_step(4, seed=5)
    expected, state_a = agent.policy(step)
    got, state_b = clone.policy(step)
    assert np.array_equal(expected, got)
    expected, _ = agent.policy({**step, "is_first": np.zeros(4, bool)}, state_a)
    got, _ = clone.policy({**step, "is_first": np.zeros(4, bool)}, state_b)
    assert np.array_equal(expected, got)
    # Exact resume: the next update is the same update.
    expected_metrics, got_metrics = agent.train_step(), clone.train_step()
    timings = {k for k in expected_metrics if k.startswith("time/")}
    assert timings and {k: v for k, v in expected_metrics.items() if k not in timings} == {
        k: v for k, v in got_metrics.items() if k not in timings
    }
    assert clone.updates_done == agent.updates_done == 3


def test_checkpoint_with_other_network_shape_is_refused(make_agent):
    state = make_agent(units=32).state_dict()
    with pytest.raises(ConfigError, match="units"):
        make_agent(units=16).load_state_dict(state)


def test_nan_loss_raises_before_any_update(make_agent, fill_random):
    agent = make_agent()
    fill_random(agent, 30)
    agent.train_step()  # optimiser states exist
    before = _snapshot(agent)
    rng = np.random.default_rng(0)
    for _ in range(40):  # poison every stored reward
        agent.observe(
            {
                "obs": rng.normal(size=(2, 3)).astype(np.float32),
                "action": np.zeros((2, 2), np.float32),
                "reward": np.full(2, np.nan, np.float32),
                "is_first": np.zeros(2, bool),
                "is_terminal": np.zeros(2, bool),
            }
        )
    with pytest.raises(TrainingError, match="non-finite"):
        agent.train_step()
    after = _snapshot(agent)
    assert before.keys() == after.keys()
    for key in before:
        assert torch.equal(before[key], after[key]), key
    assert agent.updates_done == 1


def test_observe_requires_the_core_fields(make_agent):
    agent = make_agent()
    with pytest.raises(UsageError, match="action"):
        agent.observe(_first_step(2))


def test_intent_head_from_the_registry_learns_labels(make_agent, fill_random):
    """A categorical head trained on a label that depends on the observation: its NLL falls
    well below chance (log 2) and predictions are available while acting."""
    agent = make_agent(
        model_lr=3e-3,
        extra_heads=[HeadConfig(name="intent", kind="categorical", weight=1.0, options={"field": "intent", "classes": 2})],
    )
    fill_random(agent, 60, intent=lambda t: (t["obs"][:, 0] > 0).astype(np.int64))
    losses = [agent.train_step()["wm/intent_loss"] for _ in range(100)]
    assert losses[0] > 0.5
    assert np.mean(losses[-10:]) < 0.3
    _, state = agent.policy(_first_step(3))
    prediction = agent.predict(state)
    assert prediction["intent"].shape == (3, 2)
    assert torch.allclose(prediction["intent"].sum(-1), torch.ones(3))
    assert prediction["reward"].shape == (3,) and prediction["continue"].shape == (3,)


def test_custom_heads_register_without_touching_the_world_model(make_agent, fill_random):
    @register_head("test_constant_regression")
    class ConstantHead(WorldModelHead):
        def __init__(self, config, field: str = "label"):
            super().__init__(config)
            self.field = field
            self.fields = (field,)
            self.net = latent_mlp(config, 1)

        def loss(self, latent, batch):
            return (self.net(latent).squeeze(-1) - 3.0).square()

        def predict(self, latent):
            return self.net(latent).squeeze(-1)

    agent = make_agent(
        extra_heads=[HeadConfig(name="three", kind="test_constant_regression", weight=0.5, options={"field": "x"})],
    )
    assert "three" in agent.world_model.extra_heads
    fill_random(agent, 20, x=lambda t: np.zeros(2, np.float32))
    metrics = agent.train_step()
    assert metrics["wm/three_loss"] > 0
    with pytest.raises(ConfigError, match="unknown kind"):
        make_agent(extra_heads=[HeadConfig(name="x", kind="no_such_kind")])
    with pytest.raises(ConfigError, match="bad options"):
        make_agent(extra_heads=[HeadConfig(name="x", kind="categorical", options={"colour": 1})])


def test_missing_head_field_is_reported(make_agent, fill_random):
    agent = make_agent(extra_heads=[HeadConfig(name="intent", kind="categorical", options={"field": "intent"})])
    fill_random(agent, 20)
    with pytest.raises(TrainingError, match="intent"):
        agent.train_step()


def test_discrete_actions_train_with_reinforce():
    agent = DreamerAgent(
        gym.spaces.Box(-1, 1, (3,), np.float32),
        gym.spaces.Discrete(3, start=1),
        DreamerConfig(
            units=32, layers=1, deter=32, stoch=4, classes=4, bins=21, bin_range=5.0,
            batch_size=4, batch_length=8, imag_horizon=5, prefill_steps=0, replay_capacity=1000,
        ),
    )
    step = _first_step(6)
    actions, state = agent.policy(step)
    assert actions.shape == (6,) and set(actions.tolist()) <= {1, 2, 3}
    rng = np.random.default_rng(0)
    for t in range(20):
        agent.observe({**step, "action": rng.integers(1, 4, 6), "reward": rng.normal(size=6)})
        step = {**step, "is_first": np.zeros(6, bool)}
    before = [p.detach().clone() for p in agent.behavior.actor.parameters()]
    metrics = agent.train_step()
    assert np.isfinite(metrics["actor/loss"]) and metrics["actor/entropy"] > 0
    assert any(not torch.equal(a, p) for a, p in zip(before, agent.behavior.actor.parameters()))


def test_config_validation():
    with pytest.raises(ValueError):
        DreamerConfig(actor_min_std=2.0, actor_max_std=1.0)
    with pytest.raises(ValueError):
        DreamerConfig(bins=254)
    with pytest.raises(ValueError):
        DreamerConfig(unknown_key=1)
    with pytest.raises(ValueError):
        DreamerConfig(extra_heads=[HeadConfig(name="a", kind="categorical")] * 2)


def test_loaded_agent_saves_the_optimiser_state_it_loaded(make_agent, fill_random):
    """The optimisers are built on first use; an agent loaded and saved again without training
    keeps the loaded Adam moments, and its first update is the original's."""
    agent = make_agent(seed=0)
    fill_random(agent, 30)
    agent.train_step()
    state = agent.state_dict(include_replay=True)
    clone = make_agent(seed=7)
    clone.load_state_dict(state)
    again = clone.state_dict(include_replay=True)
    for name in ("model", "actor", "critic"):
        saved, resaved = state["optimizers"][name]["state"], again["optimizers"][name]["state"]
        assert saved.keys() == resaved.keys() and saved
        for index in saved:
            for key, value in saved[index].items():
                assert torch.equal(torch.as_tensor(value), torch.as_tensor(resaved[index][key])), (name, index, key)
    assert agent.train_step()["wm/loss"] == clone.train_step()["wm/loss"]


def test_an_agent_that_only_acts_does_not_build_its_optimisers(make_agent, fill_random, tmp_path):
    """Building torch's Adam imports torch._dynamo (seconds); `d2a eval` loads agents only to act.
    A trained agent's checkpoint is loaded in a new interpreter and acts there."""
    trained = make_agent(seed=0, units=16, deter=16)
    fill_random(trained, 30)
    trained.train_step()
    torch.save(trained.state_dict(), tmp_path / "agent.pt")
    script = textwrap.dedent("""
        import sys
        import gymnasium as gym, numpy as np, torch
        from d2a_core.agents.dreamer import DreamerAgent
        from tests.agents.conftest import tiny_config
        agent = DreamerAgent(gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
                             gym.spaces.Box(-1.0, 1.0, (2,), np.float32), tiny_config(units=16, deter=16), seed=1)
        agent.load_state_dict(torch.load(sys.argv[1], weights_only=False))
        agent.policy({"obs": np.zeros((2, 3), np.float32), "is_first": np.ones(2, bool)}, explore=False)
        print("acting imported torch._dynamo:", "torch._dynamo" in sys.modules)
        agent.model_opt  # first use builds them
        print("training imported torch._dynamo:", "torch._dynamo" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", script, str(tmp_path / "agent.pt")], capture_output=True, text=True,
                         timeout=120, cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[-2:] == ["acting imported torch._dynamo: False",
                                            "training imported torch._dynamo: True"]


def test_a_checkpoint_holds_the_config_record_and_older_full_dumps_still_load(make_agent):
    """The config inside a checkpoint is the record (settings added later at their neutral value
    left out), so adding or retiring a knob does not change checkpoint bytes or artifact ids;
    checkpoints that hold the whole dump, as older ones do, load the same."""
    agent = make_agent()
    state = agent.state_dict()
    assert "terminal_weight" not in state["config"] and "reward_relabel_head" not in state["config"]
    assert state["config"]["units"] == agent.config.units
    older = {**state, "config": agent.config.model_dump(mode="json")}
    make_agent().load_state_dict(older)
    with pytest.raises(ConfigError, match="units"):
        make_agent(units=agent.config.units * 2).load_state_dict(state)


def test_a_known_action_cost_is_taken_out_of_the_replayed_rewards(make_agent):
    """With `action_cost` w the replay stores reward + w * ||previous action|| (the env charged
    the action that led to the step; imagination charges it again exactly), per class too, and
    nothing on an episode's first step."""
    agent = make_agent(action_cost=0.5)
    by_class = "reward_by_class"
    actions = [np.array([[0.6, 0.8], [0.0, 0.0]], np.float32), np.array([[1.0, 0.0], [0.3, 0.4]], np.float32)]
    steps = [
        {**_first_step(2), "action": actions[0], by_class: np.zeros((2, 2), np.float32)},
        {**_first_step(2, seed=1), "reward": np.array([-1.0, 2.0], np.float32), "is_first": np.array([False, False]),
         "action": actions[1], by_class: np.array([[-1.0, 3.0], [2.0, 0.0]], np.float32)},
        {**_first_step(2, seed=2), "reward": np.array([4.0, 4.0], np.float32), "is_first": np.array([False, True]),
         "action": actions[0], by_class: np.array([[4.0, 4.0], [4.0, 4.0]], np.float32)},
    ]
    for step in steps:
        agent.observe(step)
    stored = agent.replay.data["reward"][:, :3]
    np.testing.assert_allclose(stored, [[0.0, -1.0 + 0.5 * 1.0, 4.0 + 0.5 * 1.0], [0.0, 2.0 + 0.0, 4.0]], atol=1e-6)
    np.testing.assert_allclose(agent.replay.data[by_class][:, 1], [[-0.5, 3.5], [2.0, 0.0]], atol=1e-6)
    plain = make_agent()
    for step in steps:
        plain.observe(step)
    np.testing.assert_allclose(plain.replay.data["reward"][:, :3], [[0.0, -1.0, 4.0], [0.0, 2.0, 4.0]])
