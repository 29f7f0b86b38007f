"""The Python API (`d2a_core.api`): stored drivers and assistants act on observations as they do
in evaluation, and the example script runs on smoke artifacts."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from d2a_core import api
from d2a_core.artifacts import Store
from d2a_core.errors import UsageError
from d2a_core.pipelines.evaluate import run_specs
from d2a_core.training.shared_rollout import EpisodeSpec

REPO = Path(__file__).resolve().parents[1]
ASSISTANT = "assistants/straightaway/pass-stay/dream2assist/seed0"


def test_a_driver_alone_drives_the_episode_the_evaluator_drives(pair_store_template):
    store = Store(pair_store_template)
    population = store.read_json("humans/straightaway/pass", "population.json")
    ref = population["checkpoints"][1]["id"]
    driver = api.load(ref, store=store)
    assert isinstance(driver, api.Driver) and driver.intent == "pass"
    spec = EpisodeSpec(seed=123, human=0, label=0)
    rows, _ = run_specs([spec], [api.load(ref, store=store)._agent], ("pass", "stay"), driver.make_env, 1,
                        Path(tempfile.mkdtemp()))
    episode = api.drive(driver.make_env(), api.load(ref, store=store), None, seed=123)
    assert episode["progress_m"][-1] == pytest.approx(rows[0]["progress_m"], abs=1e-9)
    assert len(episode["t"]) == rows[0]["steps"]
    assert np.all(episode["assistant_action"] == 0.0)


def test_an_assistant_gives_its_belief_and_repeats_itself(trained_assistants):
    store_dir, _ = trained_assistants
    human_ref = "humans/straightaway/stay/expert"
    runs = []
    for _ in range(2):
        assistant = api.load(ASSISTANT, store=store_dir)
        runs.append(api.drive(assistant.make_env(), api.load(human_ref, store=store_dir), assistant, seed=7))
    first, again = runs
    assert assistant.intents == ("pass", "stay") and assistant.method.name == "dream2assist"
    assert first["intent_probs"].shape == (len(first["t"]), 2)
    assert np.allclose(first["intent_probs"].sum(axis=1), 1.0, atol=1e-5)
    assert np.abs(first["assistant_action"]).max() > 0.0
    for key in ("progress_m", "intent_probs", "assistant_action", "human_action"):
        assert np.array_equal(first[key], again[key]), key
    # a population's alias gives its expert; a track is not something that acts
    expert = api.load("humans/straightaway/stay", store=store_dir)
    assert expert.id == Store(store_dir).resolve(human_ref)
    with pytest.raises(UsageError, match="track"):
        api.load("track/straightaway", store=store_dir)


def test_the_example_plots_an_assistants_belief(trained_assistants, tmp_path):
    store_dir, _ = trained_assistants
    out = tmp_path / "belief.png"
    proc = subprocess.run([sys.executable, str(REPO / "examples" / "intent_belief.py"), "--store", str(store_dir),
                           "--assistant", ASSISTANT, "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "pass driver" in proc.stdout and "stay driver" in proc.stdout
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
