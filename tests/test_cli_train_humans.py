"""`d2a train-humans` through the CLI: checkpoints as artifacts, aliases, idempotence, resume."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from d2a_core import config as config_mod
from d2a_core.artifacts import Store
from d2a_core.config.schema import Config
from d2a_core.evaluation.criteria import EXPERT_RULE, choose_expert, meets_intent
from d2a_core.training import humans as humans_mod
from d2a_core.training import run_state as run_state_mod
from d2a_core.training.code_version import TRAINING_CODE_VERSION
from d2a_core.training.humans import train_population

from d2a_test_helpers import REPO, copy_store, run_cli

SMOKE = ("--preset", "smoke")


@pytest.fixture(scope="module")
def track_template(tmp_path_factory):
    store = tmp_path_factory.mktemp("humans-template") / "store"
    res = run_cli("make-track", "straightaway", *SMOKE, "--json", store=store)
    assert res.code == 0, res.stderr
    return store


@pytest.fixture(scope="module")
def track_store(track_template, tmp_path_factory):
    """A store with the track, shared by this module's tests (they train different intents)."""
    return copy_store(track_template, tmp_path_factory.mktemp("humans"))


@pytest.fixture
def fresh_track_store(track_template, tmp_path):
    """A store with only the track: for tests that must train from nothing, whatever ran before
    them on this xdist worker."""
    return copy_store(track_template, tmp_path)


def test_train_humans_population_and_idempotence(cli, fresh_track_store):
    track_store = fresh_track_store
    res = cli("train-humans", "--intent", "pass", "--intent", "stay", "--track", "straightaway", *SMOKE, "--json",
              store=track_store)
    assert res.code == 0, res.stderr
    pops = res.json["populations"]
    assert [p["intent"] for p in pops] == ["pass", "stay"]
    # progress on stderr (plain lines, as stderr is not a terminal), with the metres reached
    lines = [line for line in res.stderr.splitlines() if line.startswith("pass: ") and "env steps" in line]
    assert lines and "upd/s" in lines[-1] and " m" in lines[-1].split("reached")[-1]
    store = Store(track_store)
    track_id = store.resolve("track/straightaway")
    for pop in pops:
        assert pop["track"] == "straightaway" and not pop["cached"]
        assert [c["fraction"] for c in pop["checkpoints"]] == [0.5, 1.0]
        assert [c["env_step"] for c in pop["checkpoints"]] == [120, 240]
        # the expert is chosen by the documented rule, and the population says whether it meets the intent
        assert pop["expert"] == pop["checkpoints"][choose_expert(pop["intent"], pop["checkpoints"])]["id"]
        assert pop["expert_meets_intent"] == meets_intent(pop["intent"], store.read_json(pop["expert"], "eval.json")["metrics"])
        assert pop["expert_rule"] == EXPERT_RULE and pop["training_code_version"] == TRAINING_CODE_VERSION
        assert all(c["meets_intent"] == meets_intent(pop["intent"], c["metrics"]) for c in pop["checkpoints"])
        expert = next(c for c in pop["checkpoints"] if c["id"] == pop["expert"])
        assert expert["performance"] == 1.0 and all(c["performance"] >= 0.0 for c in pop["checkpoints"])
        assert pop["runtime"]["device"] == "cpu" and pop["runtime"]["cpu_kernels"] and pop["runtime"]["mkl_on_amd"]
        for c in pop["checkpoints"]:
            m = c["metrics"]
            assert m["episodes"] == 2
            assert {"progress_m", "return", "collision", "mean_speed_m_s", "overtakes", "share_left"} <= set(m)
            art = store.get(c["id"])
            assert art.kind == "human" and art.labels["intent"] == pop["intent"]
            assert art.inputs[0] == track_id and len(art.inputs) == 3  # track + 2 opponent replays
            assert {"agent.pt", "eval.json"} <= set(art.files)
        assert store.resolve(f"humans/straightaway/{pop['intent']}") == pop["id"]
        assert store.resolve(f"humans/straightaway/{pop['intent']}/expert") == pop["expert"]
        curve = store.read_bytes(pop["id"], "curve.jsonl").decode().splitlines()
        assert len(curve) >= 2
    # the same command again returns the stored result instead of training
    start = time.monotonic()
    again = cli("train-humans", "--intent", "pass", "--track", "track/straightaway", *SMOKE, "--json",
                store=track_store)
    assert again.code == 0 and again.json["populations"][0]["cached"]
    assert again.json["populations"][0]["id"] == pops[0]["id"]
    assert time.monotonic() - start < 30
    # ... and says so, with the code it came from
    made = again.json["populations"][0]["cached_from"]
    assert made["training_code_version"] == TRAINING_CODE_VERSION and "git_commit" in made and made["created"]
    said = " ".join(again.stderr.split())
    assert "reusing stored population" in said and f"training code version {TRAINING_CODE_VERSION}" in said


def test_a_result_of_other_training_code_is_not_reused(track_store, monkeypatch):
    """Bumping the training-code version changes the run key: the same command trains again."""
    resolved = config_mod.load("smoke", None, [])
    store = Store(track_store)
    first = train_population(store, "straightaway", "stay", resolved, seed=0)
    assert first["training_code_version"] == TRAINING_CODE_VERSION
    # the version is read where the run key is made and where the result records it
    monkeypatch.setattr(run_state_mod, "TRAINING_CODE_VERSION", TRAINING_CODE_VERSION + 1)
    monkeypatch.setattr(humans_mod, "TRAINING_CODE_VERSION", TRAINING_CODE_VERSION + 1)
    newer = train_population(store, "straightaway", "stay", resolved, seed=0)
    assert not newer["cached"] and newer["id"] != first["id"]
    assert newer["training_code_version"] == TRAINING_CODE_VERSION + 1
    # the alias now names the newer run, and the result says which run it named before
    assert store.resolve("humans/straightaway/stay") == newer["id"]
    assert {"alias": "humans/straightaway/stay", "previous": first["id"], "now": newer["id"]} in newer["aliases_moved"]
    # rerunning the first command answers from the store and points the aliases back at its result
    monkeypatch.setattr(run_state_mod, "TRAINING_CODE_VERSION", TRAINING_CODE_VERSION)
    monkeypatch.setattr(humans_mod, "TRAINING_CODE_VERSION", TRAINING_CODE_VERSION)
    again = train_population(store, "straightaway", "stay", resolved, seed=0)
    assert again["cached"] and again["id"] == first["id"]
    assert store.resolve("humans/straightaway/stay") == first["id"]
    assert store.resolve("humans/straightaway/stay/expert") == first["expert"]
    assert {"alias": "humans/straightaway/stay", "previous": newer["id"], "now": first["id"]} in again["aliases_moved"]


def test_resume_after_sigkill(cli, track_store):
    args = ["train-humans", "--intent", "left", "--track", "straightaway", *SMOKE,
            "--set", "humans.env_steps=480", "--set", "humans.checkpoints=4", "--set", "humans.snapshot_every=40",
            "--json"]
    cmd = [sys.executable, "-m", "d2a_cli", *args, "--store", str(track_store)]
    # Run states of earlier tests' runs in this store do not count: wait for this run's own.
    earlier_states = set((Path(track_store) / "runs").glob("*/state.pt"))
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    store = Store(track_store)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        humans = [a for a in store.list("human") if a.labels["intent"] == "left"]
        # The resume point is the run state written just after each checkpoint artifact.
        if humans and set((Path(track_store) / "runs").glob("*/state.pt")) - earlier_states:
            break
        time.sleep(0.2)
    else:
        proc.kill()
        pytest.fail("no checkpoint appeared")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    first = humans[0]
    res = cli(*args, store=track_store)
    assert res.code == 0, res.stderr
    pop = res.json["populations"][0]
    assert pop["resumed_from_env_step"] is not None and pop["resumed_from_env_step"] >= first.labels["env_step"]
    assert [c["env_step"] for c in pop["checkpoints"] if not c.get("filled")] == [120, 240, 360, 480]
    assert next(c for c in pop["checkpoints"] if not c.get("filled"))["id"] == first.id
    # the snapshots taken before and after the kill fill the span; their files are gone
    assert all(c["env_step"] % 40 == 0 for c in pop["checkpoints"])
    assert not list((Path(track_store) / "runs").glob("*/snapshots/*"))
    assert store.verify() == []


def test_snapshots_fill_the_imperfect_span_without_changing_the_run(cli, track_store):
    """With `humans.snapshot_every`, snapshots are evaluated after training and added until
    `fill_imperfect` checkpoints are below 75 % of the expert; the evenly spaced checkpoints, their
    evaluations and the expert are those of the same run without snapshots."""
    args = ["train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE,
            "--set", "humans.env_steps=360", "--set", "humans.checkpoints=3", "--json"]
    plain = cli(*args, store=track_store)
    filled = cli(*args, "--set", "humans.snapshot_every=40", store=track_store)
    assert plain.code == 0 and filled.code == 0, plain.stderr + filled.stderr
    a, b = plain.json["populations"][0], filled.json["populations"][0]
    steps = [c["env_step"] for c in b["checkpoints"]]
    assert steps == sorted(steps)
    evenly = [c for c in b["checkpoints"] if not c.get("filled")]
    added = [c for c in b["checkpoints"] if c.get("filled")]
    assert [c["env_step"] for c in evenly] == [120, 240, 360]
    assert [c["metrics"] for c in evenly] == [c["metrics"] for c in a["checkpoints"]]
    assert b["expert_env_step"] == a["expert_env_step"] and not any(c["id"] == b["expert"] for c in added)
    # snapshots on the 40-step grid, none before the first update (smoke prefills 64 steps)
    assert added and all(c["env_step"] % 40 == 0 and c["env_step"] not in (120, 240, 360) for c in added)
    assert all(c["env_step"] > 64 for c in added)
    below = sum(1 for c in b["checkpoints"] if c["id"] != b["expert"] and c["performance"] < 0.75)
    all_snapshots = [s for s in range(80, 360, 40) if s not in (120, 240)]
    assert below >= 5 or len(added) == len(all_snapshots)
    # a snapshot is a stored human like any checkpoint, and the run's snapshot files are gone
    store = Store(track_store)
    assert all(store.get(c["id"]).kind == "human" for c in added)
    assert not list((Path(track_store) / "runs").glob("*/snapshots/*.pt"))
    # fill_imperfect=0: nothing is added
    unfilled = cli(*args, "--set", "humans.snapshot_every=40", "--set", "humans.fill_imperfect=0", store=track_store)
    assert unfilled.code == 0 and not any(c.get("filled") for c in unfilled.json["populations"][0]["checkpoints"])


def test_evaluation_episode_logs_show_each_checkpoint_without_changing_it(cli, track_store, tmp_path):
    """`humans.eval_logs=2`: each checkpoint keeps its first two evaluation episodes as MCAP logs
    (`episodes/*.mcap`, exported by `d2a artifacts export`, their outcome in the metadata); the
    evaluations and expert are those of the same run without logs."""
    from d2a_core.sim.episode_log.reader import read_episode

    args = ["train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE,
            "--set", "humans.env_steps=360", "--set", "humans.checkpoints=3", "--json"]
    plain = cli(*args, store=track_store)
    logged = cli(*args, "--set", "humans.eval_logs=2", store=track_store)
    assert plain.code == 0 and logged.code == 0, plain.stderr + logged.stderr
    a, b = plain.json["populations"][0], logged.json["populations"][0]
    assert [c["metrics"] for c in b["checkpoints"]] == [c["metrics"] for c in a["checkpoints"]]
    assert b["expert_env_step"] == a["expert_env_step"]
    store = Store(track_store)
    assert "eval_logs" not in store.get(a["checkpoints"][0]["id"]).config["humans"]  # older run keys hold
    for checkpoint in b["checkpoints"]:
        out = tmp_path / checkpoint["id"][:12]
        assert cli("artifacts", "export", checkpoint["id"], str(out), store=track_store).code == 0
        logs = sorted((out / "episodes").glob("*.mcap"))
        assert len(logs) == 2
        episodes = store.read_json(checkpoint["id"], "eval.json")["episodes"]
        for log in logs:
            episode = read_episode(log)
            outcome = episode.metadata["outcome"]
            assert episode.metadata["intent"] == "stay" and len(episode) > 1
            assert any(outcome["progress_m"] == pytest.approx(e["progress_m"]) for e in episodes)


def test_non_finite_loss_stops_with_a_clear_error(cli, track_store):
    res = cli("train-humans", "--intent", "right", "--track", "straightaway", *SMOKE,
              "--set", "dreamer.model_lr=1e30", "--set", "dreamer.actor_lr=1e30", "--json", store=track_store)
    assert res.code == 1
    assert "non-finite" in res.json["error"]["message"]
    assert not [a for a in Store(track_store).list("population") if a.labels["intent"] == "right"]


def test_train_humans_usage_errors(cli, track_store, tmp_path):
    res = cli("train-humans", "--intent", "overtake", "--track", "straightaway", *SMOKE, "--json", store=track_store)
    assert res.code == 2 and "overtake" in res.json["error"]["message"]
    res = cli("train-humans", "--intent", "pass", "--track", "monza", *SMOKE, "--json", store=track_store)
    assert res.code == 2 and "make-track monza" in res.json["error"]["message"]
    # the assistant's charge on its own actions has no meaning for a driver
    res = cli("train-humans", "--intent", "pass", "--track", "straightaway", *SMOKE, "--set", "dreamer.action_cost=1",
              "--json", store=track_store)
    assert res.code == 2 and "dreamer.action_cost" in res.json["error"]["message"]


def test_same_seed_and_config_give_the_same_population_id(cli, fresh_track_store, tmp_path):
    """Reproducible to the byte: a fresh store, the same commands, the same artifact ids (the
    curve keeps wall-clock timings out of the hashed files). Both runs train from nothing: the
    module's shared store may already hold this run key, trained in the test process itself
    (test_a_result_of_other_training_code_is_not_reused), whose population records another
    runtime (the MKL vendor check "not tried" there, the CLI tries it first thing) and so has
    another id, with the same checkpoints."""
    first = cli("train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE, "--json",
                store=fresh_track_store)
    assert first.code == 0, first.stderr
    assert not first.json["populations"][0]["cached"]
    fresh = tmp_path / "fresh"
    assert cli("make-track", "straightaway", *SMOKE, "--json", store=fresh).code == 0
    # another interpreter (its own string-hash seed), not another child of the tests' CLI zygote
    # and `--device cpu` spelled out: the first run's default, as another string object
    second = cli("train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE, "--device", "cpu", "--json",
                 store=fresh, fresh_process=True)
    assert second.code == 0, second.stderr
    a, b = first.json["populations"][0], second.json["populations"][0]
    assert not b["cached"] and a["id"] == b["id"]
    assert [c["id"] for c in a["checkpoints"]] == [c["id"] for c in b["checkpoints"]]


def test_the_drivers_world_model_learning_rate_is_their_own(cli, track_store):
    """`humans.model_lr` sets the drivers' world-model rate; unset, `dreamer.model_lr` does (the
    assistant shares `dreamer` and keeps its rate)."""
    import torch

    for extra, expected in (([], 2e-4), (["--set", "humans.model_lr=5e-4"], 5e-4)):
        res = cli("train-humans", "--intent", "pass", "--track", "straightaway", *SMOKE,
                  "--set", "humans.env_steps=120", "--set", "humans.checkpoints=1", "--set", "dreamer.model_lr=2e-4",
                  *extra, "--json", store=track_store)
        assert res.code == 0, res.stderr
        checkpoint = res.json["populations"][0]["checkpoints"][0]["id"]
        state = torch.load(Store(track_store).path(checkpoint, "agent.pt"), weights_only=False)
        assert state["config"]["model_lr"] == expected
        assert [g["lr"] for g in state["optimizers"]["model"]["param_groups"]] == [expected]


def test_a_side_population_leaves_the_intents_aliases_and_survives_gc(cli, fresh_track_store):
    """`--no-alias` (e.g. another seed's population, for held-out humans): humans/<track>/<intent>
    keeps pointing at the main population, and the side one, kept by its own `.../side/<id>`
    alias, survives `d2a artifacts gc` with every checkpoint."""
    args = ["train-humans", "--intent", "left", "--track", "straightaway", *SMOKE, "--set", "humans.env_steps=240",
            "--set", "humans.checkpoints=2", "--json"]
    main = cli(*args, store=fresh_track_store)
    assert main.code == 0, main.stderr
    side = cli(*args, "--no-alias", "--seed", "1", store=fresh_track_store)
    assert side.code == 0, side.stderr
    store = Store(fresh_track_store)
    main_id, side_pop = main.json["populations"][0]["id"], side.json["populations"][0]
    assert side_pop["id"] != main_id and side_pop["aliases_moved"] == []
    # the JSON names what finds each population: the main one by the intent's aliases, the side one by its own
    assert main.json["populations"][0]["aliases"] == {"humans/straightaway/left": main_id,
                                                     "humans/straightaway/left/expert": main.json["populations"][0]["expert"]}
    assert side_pop["aliases"] == {f"humans/straightaway/left/side/{side_pop['id'][:12]}": side_pop["id"]}
    assert store.resolve("humans/straightaway/left") == main_id
    assert store.resolve(f"humans/straightaway/left/side/{side_pop['id'][:12]}") == side_pop["id"]
    assert cli("artifacts", "gc", "--json", store=fresh_track_store).code == 0
    for ref in [side_pop["id"], *(c["id"] for c in side_pop["checkpoints"])]:
        store.get(ref)  # raises if gc removed it


def test_the_drivers_own_keys_override_the_shared_dreamer_settings():
    """`humans.model_lr` reaches the drivers' DreamerV3 config; unset, the drivers take
    `dreamer.model_lr` like the assistant. The retired `humans.terminal_weight` loads only unset."""
    plain = config_mod.load("smoke", overrides=["dreamer.model_lr=2e-4"]).config
    own = config_mod.load("smoke", overrides=["dreamer.model_lr=2e-4", "humans.model_lr=5e-4"]).config
    assert humans_mod.driver_dreamer_config(plain).model_lr == 2e-4
    assert humans_mod.driver_dreamer_config(own).model_lr == 5e-4
    assert own.dreamer.model_lr == 2e-4  # the shared section, which the assistant reads, is untouched
    assert Config.model_validate({"humans": {"terminal_weight": None}}) == Config()
    with pytest.raises(ValueError, match="'terminal_weight' is a retired setting"):
        Config.model_validate({"humans": {"terminal_weight": 20.0}})
