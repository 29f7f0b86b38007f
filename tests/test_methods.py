"""The method registry: the paper's rows, lookups and their errors, lazy agents, config patches."""

from __future__ import annotations

import subprocess
import sys

import pytest

from d2a_core.config.schema import Config
from d2a_core.errors import UsageError
from d2a_core.training.methods import METHODS, Method, get_method, method_names, register_method

PAIR = ("pass", "stay")


def test_the_papers_rows():
    rows = {name: (m.intent_head, m.alpha_r, m.alpha_a, m.implemented) for name, m in METHODS.items()}
    assert rows == {
        "dream2assist": (True, 1.0, 0.0, True),
        "dream2assist+a": (True, 1.0, 1.0, True),
        "dream2assist+a-r": (True, 0.0, 1.0, True),
        "dreamer": (False, 0.0, 0.0, True),
        "no-rssm": (True, 1.0, 0.0, True),
        "dreamer-ail": (False, 0.0, 0.0, True),
    }
    assert get_method("dream2assist").labels == ("intent",) and get_method("dreamer").labels == ()
    assert get_method("dream2assist+a-r").uses_experts and not get_method("dreamer").uses_experts
    assert method_names(implemented_only=True) == ["dream2assist", "dream2assist+a", "dream2assist+a-r", "dreamer",
                                                   "no-rssm", "dreamer-ail"]
    assert [name for name in METHODS if METHODS[name].demonstrations] == ["dreamer-ail"]


def test_unknown_and_unimplemented_names_are_usage_errors():
    with pytest.raises(UsageError, match="unknown method 'dream2asist'.*dream2assist, dream2assist\\+a.*dreamer-ail"):
        get_method("dream2asist")
    unbuilt = register_method(Method("unbuilt", False, 0.0, 0.0, ("assistant",), "somewhere.unbuilt:build",
                                     implemented=False))
    try:
        with pytest.raises(UsageError, match="'unbuilt' is registered but not implemented.*somewhere.unbuilt:build"):
            get_method("unbuilt")
        with pytest.raises(UsageError, match="unbuilt"):
            unbuilt.builder()
    finally:
        del METHODS["unbuilt"]


def test_agents_load_lazily_and_reading_the_registry_imports_no_torch():
    from d2a_core.agents.dreamer.agent import build_assistant

    assert all(get_method(name).builder() is build_assistant for name in method_names(implemented_only=True)
               if get_method(name).agent_section == "dreamer")
    code = ("import sys, d2a_core.training.methods as m; m.get_method('dreamer'); "
            "assert not [k for k in sys.modules if k.split('.')[0] == 'torch'], 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_run_key_sections_exist_in_the_config():
    fields = set(Config.model_fields)
    for name in method_names(implemented_only=True):
        assert set(get_method(name).config_sections) <= fields, name
        assert {"assistant", "reward", "env"} <= set(get_method(name).config_sections)


def test_variants_differ_exactly_in_their_row():
    base = Config()
    configured = {name: get_method(name).configure(base, PAIR) for name in method_names(implemented_only=True)}
    for name, config in configured.items():
        method = get_method(name)
        assert (config.assistant.reward.alpha_r, config.assistant.reward.alpha_a) == (method.alpha_r, method.alpha_a)
        heads = config.dreamer.extra_heads
        if method.agent_section != "dreamer":  # its own learner (no-rssm: the classifier is always built)
            assert heads == []
        elif method.intent_head:
            assert [(h.name, h.kind, h.weight, h.options) for h in heads] == [
                ("intent", "intent", base.assistant.intent_scale, {"field": "intent", "intents": ["pass", "stay"]})
            ]
        else:
            assert heads == []
        # Nothing else moves: with the row undone the config is the base config.
        undone = config.model_copy(update={
            "assistant": base.assistant,
            "dreamer": config.dreamer.model_copy(update={"extra_heads": []}),
        })
        assert undone.model_dump() == base.model_dump()
    # Every pair of methods records different run-key sections.
    records = {
        name: repr(sorted(config.model_dump(include=set(get_method(name).config_sections)).items()))
        for name, config in configured.items()
    }
    assert len(set(records.values())) == len(records)
    assert base.assistant.reward.alpha_a == 0.0 and base.dreamer.extra_heads == []  # the base is untouched


def test_configure_uses_the_intent_scale_and_refuses_bad_pairs():
    base = Config()
    scaled = base.model_copy(update={"assistant": base.assistant.model_copy(update={"intent_scale": 0.25})})
    assert get_method("dream2assist").configure(scaled, ("left", "right")).dreamer.extra_heads[0].weight == 0.25
    with pytest.raises(UsageError, match="two distinct intents"):
        get_method("dream2assist").configure(base, ("pass",))
    twice = get_method("dream2assist").configure(base, PAIR)
    with pytest.raises(UsageError, match="already has a head named 'intent'"):
        get_method("dream2assist").configure(twice, PAIR)


def test_the_intent_head_reads_the_model_state_only():
    options = get_method("dream2assist").configure(Config(), PAIR).dreamer.extra_heads[0].options
    assert options == {"field": "intent", "intents": list(PAIR)}


def test_retired_assistant_and_population_settings_load_at_their_former_defaults_only():
    """Stored records may carry `assistant.intent_lr: null`, `assistant.intent_reads: latent` and
    `humans.train_start_spread: 0.0` (settings retired after their experiments); any other value
    names the key."""
    config = Config.model_validate({"assistant": {"intent_lr": None, "intent_reads": "latent", "authority": 1.0},
                                    "humans": {"train_start_spread": 0.0}})
    assert config == Config()
    for section, key, value in (("assistant", "intent_lr", 1e-3), ("assistant", "intent_reads", "partner_window"),
                                ("assistant", "authority", 0.5), ("humans", "train_start_spread", 0.7)):
        with pytest.raises(ValueError, match=f"'{key}' is a retired setting"):
            Config.model_validate({section: {key: value}})


def _assistant(base, **update):
    return base.model_copy(update={"assistant": base.assistant.model_copy(update=update)})


def test_reward_relabelling_is_for_a_dreamer_intent_head_with_expert_terms_only():
    base = Config()
    relabel = _assistant(base, reward_relabel=True)
    for name in ("dream2assist", "dream2assist+a", "dream2assist+a-r"):
        method = get_method(name)
        assert method.configure(relabel, PAIR).dreamer.reward_relabel_head == "intent"
        assert method.relabels_reward(method.configure(relabel, PAIR))
        assert not method.relabels_reward(method.configure(base, PAIR))
    # no intent estimate (dreamer) or no world model (no-rssm): nothing to relabel, the key is ignored
    for name in ("dreamer", "no-rssm"):
        assert get_method(name).configure(relabel, PAIR).dreamer.reward_relabel_head is None
    # the method sets the learner's key; set by hand it is refused, naming the assistant's key
    direct = base.model_copy(update={"dreamer": base.dreamer.model_copy(update={"reward_relabel_head": "intent"})})
    for name in ("dream2assist", "dreamer"):
        with pytest.raises(UsageError, match="assistant.reward_relabel"):
            get_method(name).configure(direct, PAIR)


def test_the_assistants_own_learner_settings_reach_dreamer_methods_only():
    """`assistant.train_ratio` / `assistant.imag_starts` replace the drivers' `dreamer.*` values in
    a Dreamer-family assistant's learner; unset, the shared values stay; no-rssm has no such learner."""
    base = Config()
    own = _assistant(base, train_ratio=base.dreamer.train_ratio * 2, imag_starts=96)
    for name in ("dream2assist", "dream2assist+a", "dream2assist+a-r", "dreamer"):
        dreamer = get_method(name).configure(own, PAIR).dreamer
        assert (dreamer.train_ratio, dreamer.imag_starts) == (base.dreamer.train_ratio * 2, 96)
        unset = get_method(name).configure(base, PAIR).dreamer
        assert (unset.train_ratio, unset.imag_starts) == (base.dreamer.train_ratio, base.dreamer.imag_starts)
    assert get_method("no-rssm").configure(own, PAIR).dreamer == base.dreamer
    # with the intent head appended as well
    assert [h.name for h in get_method("dream2assist").configure(own, PAIR).dreamer.extra_heads] == ["intent"]
    # unset they stay out of the record, so earlier runs keep their keys
    from d2a_core.config.section import record

    assert not {"train_ratio", "imag_starts", "reward_relabel"} & set(record(base.assistant))


def test_the_retired_learner_settings_load_only_at_their_neutral_value():
    """A stored assistant record from before `assistant.actor_grad` / `assistant.precision` were
    retired left them out (None); one that set them names the key."""
    from d2a_core.training.config import AssistantConfig

    assert AssistantConfig.model_validate({"actor_grad": None, "precision": None}) == AssistantConfig()
    for key, value in (("actor_grad", "reinforce"), ("precision", "bfloat16")):
        with pytest.raises(ValueError, match=f"'{key}' is a retired setting"):
            AssistantConfig.model_validate({key: value})


def test_registering_twice_or_without_entry_point_is_refused():
    with pytest.raises(ValueError, match="already registered"):
        register_method(Method("dreamer", True, 1.0, 1.0, ("env",), "x:Y"))
    with pytest.raises(ValueError, match="module:Class"):
        register_method(Method("test-bad-entry", False, 0.0, 0.0, ("env",), "no_colon"))
    assert "test-bad-entry" not in METHODS


def test_exact_intervention_sets_the_learners_action_cost_for_dreamer_methods_only():
    base = Config()
    exact = _assistant(base, exact_intervention=True)
    weight = base.assistant.reward.w_interv
    for name in ("dream2assist", "dream2assist+a", "dream2assist+a-r", "dreamer"):
        assert get_method(name).configure(exact, PAIR).dreamer.action_cost == weight
        assert get_method(name).configure(base, PAIR).dreamer.action_cost == 0.0
    heavier = exact.model_copy(update={"assistant": exact.assistant.model_copy(
        update={"reward": exact.assistant.reward.model_copy(update={"w_interv": 2.5})})})
    assert get_method("dream2assist").configure(heavier, PAIR).dreamer.action_cost == 2.5
    assert get_method("no-rssm").configure(exact, PAIR).dreamer == base.dreamer
    # the method sets the learner's key; set by hand it is refused, naming the assistant's key
    direct = base.model_copy(update={"dreamer": base.dreamer.model_copy(update={"action_cost": 1.0})})
    with pytest.raises(UsageError, match="assistant.exact_intervention"):
        get_method("dream2assist").configure(direct, PAIR)
    # unset, neither key is in a record: every stored run keeps its key
    from d2a_core.config.section import record

    assert "exact_intervention" not in record(base.assistant) and "action_cost" not in record(base.dreamer)
    assert record(exact.assistant)["exact_intervention"] is True
