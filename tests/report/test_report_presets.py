"""Which preset an artifact was made with, as the report names it (d2a_core.report.presets)."""

from __future__ import annotations

import subprocess
import sys

from d2a_core.report.presets import describe


QUICK_ASSISTANT = {"env_steps": 60000, "partner_window": 16, "human_explore": False, "reward_relabel": True,
                   "train_ratio": 128.0, "exact_intervention": True}


def test_a_value_the_preset_file_leaves_at_its_default_is_named():
    # quick.yaml does not set intent_scale: it is a schema default the run changed with --set
    record = {"assistant": {**QUICK_ASSISTANT, "intent_scale": 2.0}}
    assert describe(record) == "quick, except assistant.intent_scale=2.0"


def test_method_keys_and_keys_the_record_lacks_are_not_differences():
    record = {"assistant": {**QUICK_ASSISTANT, "reward": {"alpha_r": 1.0, "alpha_a": 1.0}}}
    assert describe(record) == "quick"
    assert describe({"assistant": {**QUICK_ASSISTANT, "some_future_key": 3}}) == "quick"


def test_a_key_left_out_at_its_neutral_value_is_compared_at_that_value():
    """A record omits later additions at their neutral value (partner_window 1, stored rewards, the
    learnt intervention charge), so an assistant made before `quick` set them reads as quick except
    those, not as quick."""
    record = {"assistant": {"env_steps": 60000, "checkpoints": 6, "human_explore": False, "train_ratio": 128.0}}
    assert describe(record) == ("quick, except assistant.exact_intervention=false, assistant.partner_window=1, "
                                "assistant.reward_relabel=false")


def test_an_assistants_learner_value_set_in_its_assistant_section_is_named_once():
    """`assistant.train_ratio` sets the assistant's `dreamer.train_ratio` (`Method.configure`): the
    report names the assistant key, not both; unset, the learner's own value is named; a
    population's `dreamer` section is the shared one."""
    record = {"assistant": {**QUICK_ASSISTANT, "train_ratio": 96.0}, "dreamer": {"train_ratio": 96.0}}
    assert describe(record) == "quick, except assistant.train_ratio=96.0"
    unset = {key: value for key, value in QUICK_ASSISTANT.items() if key != "train_ratio"}
    assert describe({"assistant": unset, "dreamer": {"train_ratio": 64.0}}) == "quick, except dreamer.train_ratio=64.0"
    assert describe({"humans": {"env_steps": 100000}, "dreamer": {"train_ratio": 128.0}}) == \
        "quick, except dreamer.train_ratio=128.0"


def test_many_differences_read_as_custom():
    record = {"dreamer": {"train_ratio": 3.0, "batch_size": 3, "batch_length": 3, "units": 3, "layers": 3,
                          "actor_lr": 3.0, "critic_lr": 3.0, "model_lr": 3.0, "imag_horizon": 3}}
    assert describe(record).startswith("custom (closest preset ")


def test_resolving_presets_loads_neither_the_simulator_nor_torch():
    # the report reads artifacts only (docs/architecture.md); the schema's sim settings live apart
    code = ("import sys\nfrom d2a_core.report.presets import describe\n"
            "describe({'assistant': {'env_steps': 1}})\n"
            "print(sorted(m for m in ('pybullet', 'torch', 'd2a_core.sim.world', 'd2a_core.sim.race_env') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
