"""`d2a train-assistant` through the CLI: every method end to end on smoke, artifacts and lineage,
the stored result, resume after SIGKILL, and usage errors."""

from __future__ import annotations

import io
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from d2a_core.artifacts import Store
from d2a_core.training.methods import method_names

from d2a_test_helpers import REPO, copy_store

SMOKE = ("--preset", "smoke")
PAIR = ("--track", "straightaway", "--pair", "pass-stay")


@pytest.fixture(scope="module")
def pair_store(trained_assistants, tmp_path_factory):
    return copy_store(trained_assistants[0], tmp_path_factory.mktemp("assistant"))


def test_every_method_trains_end_to_end_and_is_stored_with_its_lineage(cli, trained_assistants):
    pair_store, result = trained_assistants
    methods = method_names(implemented_only=True)
    store = Store(pair_store)
    pops = [store.resolve("humans/straightaway/pass"), store.resolve("humans/straightaway/stay")]
    results = result["assistants"]
    assert [r["method"] for r in results] == methods
    for r in results:
        assert not r["cached"] and r["pair"] == "pass-stay" and r["populations"] == pops
        assert set(r["training_episodes"]) == set(pops) and min(r["training_episodes"].values()) > 0
        assert [c["env_step"] for c in r["checkpoints"]] == [120, 240]
        art = store.get(r["id"])
        assert art.kind == "assistant" and art.labels["method"] == r["method"] and art.labels["pair"] == "pass-stay"
        assert set(pops) <= set(art.inputs)  # traced back to the humans, and through them to track and replays
        assert store.resolve(f"assistants/straightaway/pass-stay/{r['method']}/seed0") == r["checkpoints"][-1]["id"]
        run_art = store.get(f"assistant-runs/straightaway/pass-stay/{r['method']}/seed0")
        assert run_art.kind == "assistant-run" and run_art.id == r["run_id"]
        # the paired panel: 1 weak + the expert per intent, one episode each, in both conditions
        summary = r["checkpoints"][-1]["metrics"]
        assert summary["pairs"] == 4
        assert {"pass/weak/progress_gain", "stay/expert/progress_ratio"} <= set(summary)
        infers = r["method"] not in ("dreamer", "dreamer-ail")
        assert ("intent_f1" in summary) == infers
        steps = np.load(io.BytesIO(store.read_bytes(r["id"], "steps.npz")))
        assert steps["terms"].shape[1] == 5 and ("y_hat" in steps) == infers
        curve = [line for line in store.read_bytes(r["run_id"], "curve.jsonl").decode().splitlines()]
        assert len(curve) >= 2 and '"assist/task"' in curve[-1]
        assert ('"wm/intent_accuracy"' in curve[-1] or '"intent/accuracy"' in curve[-1]) == infers
        assert {"acting/assistant", "acting/humans", "simulation", "learning", "evaluation"} <= set(r["time_shares"])
        assert ("expert_filtering" in r["time_shares"]) and sum(r["time_shares"].values()) == pytest.approx(1, abs=1e-3)
    # the methods' runs differ (different run keys) and the same command again is the stored result
    assert len({r["id"] for r in results}) == len(methods)
    again = cli("train-assistant", *PAIR, "--method", "dreamer", *SMOKE, "--json", store=pair_store)
    assert again.code == 0 and again.json["assistants"][0]["cached"]
    assert again.json["assistants"][0]["id"] == results[methods.index("dreamer")]["id"]
    assert "reusing stored assistant" in " ".join(again.stderr.split())
    table = cli("train-assistant", *PAIR, "--method", "dreamer", *SMOKE, store=pair_store)
    assert table.code == 0 and "crit. e" in table.stdout and "→" in table.stdout
    assert store.verify() == []


def test_several_populations_of_one_intent_train_together(cli, pair_store):
    """`--humans A,B`: the second pass population's drivers take part in training and the run is
    traced to it; the first of the list stays the intent's reference (expert, panel)."""
    store = Store(pair_store)
    other = cli("train-humans", "--intent", "pass", "--track", "straightaway", *SMOKE, "--set", "humans.checkpoints=2",
                "--seed", "1", "--no-alias", "--json", store=pair_store)
    assert other.code == 0, other.stderr
    pass0, pass1 = store.resolve("humans/straightaway/pass"), other.json["populations"][0]["id"]
    stay = store.resolve("humans/straightaway/stay")
    res = cli("train-assistant", *PAIR, "--method", "dreamer", "--humans", f"{pass0},{pass1}", "--humans", stay,
              *SMOKE, "--set", "assistant.env_steps=480", "--no-alias", "--json", store=pair_store)
    assert res.code == 0, res.stderr
    r = res.json["assistants"][0]
    assert r["populations"] == [pass0, pass1, stay]
    assert r["training_episodes"][pass1] > 0 and r["training_episodes"][pass0] > 0
    assert {pass0, pass1, stay} <= set(store.get(r["id"]).inputs)
    panel_ids = {h["id"] for h in r["panel"]}
    first = store.read_json(pass0, "population.json")
    assert first["expert"] in panel_ids
    assert not panel_ids & {c["id"] for c in other.json["populations"][0]["checkpoints"]}
    # the same population twice, or an empty entry, is a usage error
    res = cli("train-assistant", *PAIR, "--humans", f"{pass0},{pass0}", "--humans", stay, *SMOKE, "--json",
              store=pair_store)
    assert res.code == 2 and "twice" in res.json["error"]["message"]
    res = cli("train-assistant", *PAIR, "--humans", f"{pass0},", "--humans", stay, *SMOKE, "--json", store=pair_store)
    assert res.code == 2 and "empty" in res.json["error"]["message"]


def test_a_side_run_with_no_alias_leaves_the_method_and_seed_aliases(cli, trained_assistants, tmp_path):
    store_path = copy_store(trained_assistants[0], tmp_path)
    store = Store(store_path)
    names = ("assistants/straightaway/pass-stay/dreamer/seed0", "assistant-runs/straightaway/pass-stay/dreamer/seed0")
    before = [store.resolve(n) for n in names]
    side = cli("train-assistant", *PAIR, "--method", "dreamer", *SMOKE, "--set", "assistant.log_every=120",
               "--no-alias", "--json", store=store_path)
    assert side.code == 0, side.stderr
    result = side.json["assistants"][0]
    assert not result["cached"] and result["aliases_moved"] == []
    assert [store.resolve(n) for n in names] == before  # still the main run
    assert result["checkpoints"][-1]["id"] not in before and store.get(result["run_id"]).kind == "assistant-run"
    # kept by its own alias: gc leaves the side run and its checkpoints
    side_alias = f"assistant-runs/straightaway/pass-stay/dreamer/seed0/side/{result['run_id'][:12]}"
    assert store.resolve(side_alias) == result["run_id"]
    assert cli("artifacts", "gc", "--json", store=store_path).code == 0
    for ref in [result["run_id"], *(c["id"] for c in result["checkpoints"])]:
        store.get(ref)  # raises if gc removed it
    # the same side run again with the default: the stored result, and now the aliases follow it
    again = cli("train-assistant", *PAIR, "--method", "dreamer", *SMOKE, "--set", "assistant.log_every=120",
                "--json", store=store_path)
    assert again.code == 0 and again.json["assistants"][0]["cached"]
    assert [store.resolve(n) for n in names] == [result["checkpoints"][-1]["id"], result["run_id"]]


def test_same_seed_and_config_give_the_same_assistant_ids(cli, trained_assistants, pair_store_template, tmp_path):
    """Trained again in a fresh copy of the same populations: the same checkpoint and run ids
    (timings live in the manifest's provenance, outside the id), also when a value the first run
    took by default is given on the command line (`--device cpu`: the same value as another
    string object, which once changed the pickled checkpoint's bytes)."""
    store = copy_store(pair_store_template, tmp_path)
    # another interpreter (its own string-hash seed), not another child of the tests' CLI zygote
    res = cli("train-assistant", *PAIR, "--method", "dreamer", *SMOKE, "--device", "cpu", "--json", store=store,
              fresh_process=True)
    assert res.code == 0, res.stderr
    again = res.json["assistants"][0]
    before = next(r for r in trained_assistants[1]["assistants"] if r["method"] == "dreamer")
    assert not again["cached"] and again["run_id"] == before["run_id"]
    assert [c["id"] for c in again["checkpoints"]] == [c["id"] for c in before["checkpoints"]]
    notes = Store(store).get(again["run_id"]).manifest["provenance"]["notes"]
    assert set(notes["time_shares"]) >= {"learning", "acting/humans"}
    # where the config came from, beside the id (the same id came from the same preset either way)
    assert notes["config_source"] == {"preset": "smoke", "config_file": None, "overrides": [], "pair": "pass-stay"}
    pop = Store(store).get("humans/straightaway/stay").manifest["provenance"]["notes"]
    assert pop["config_source"]["preset"] == "smoke" and pop["config_source"]["overrides"] == ["humans.checkpoints=4"]


def _train_one(cli, template, tmp_path, method: str, override: str):
    """One smoke assistant of `method` with one `--set` override and one checkpoint, on a copy of
    the pair store: (store path, store, the final checkpoint's artifact, the run's JSON result)."""
    store_path = copy_store(template, tmp_path)
    res = cli("train-assistant", *PAIR, "--method", method, *SMOKE, "--set", override,
              "--set", "assistant.checkpoints=1", "--json", store=store_path)
    assert res.code == 0, res.stderr
    store = Store(store_path)
    run = res.json["assistants"][0]
    return store_path, store, store.get(run["id"]), run


def test_an_assistant_takes_its_pairs_values_and_records_them(cli, pair_store_template, tmp_path):
    """A `pairs:` section of the config file reaches the run of that pair only: the stored config
    holds the pair's value and the run's config source names the pair."""
    user = tmp_path / "pairs.yaml"
    user.write_text("assistant:\n  checkpoints: 1\n"
                    "pairs:\n  stay-pass:\n    assistant:\n      reward:\n        w_interv: 0.25\n"
                    "  left-right:\n    assistant:\n      reward:\n        w_interv: 0.75\n")
    store_path = copy_store(pair_store_template, tmp_path / "store")
    res = cli("train-assistant", *PAIR, "--method", "dreamer", *SMOKE, "--config", str(user), "--json",
              store=store_path)
    assert res.code == 0, res.stderr
    store = Store(store_path)
    run = res.json["assistants"][0]
    assert store.get(run["id"]).config["assistant"]["reward"]["w_interv"] == 0.25
    source = store.get(run["run_id"]).manifest["provenance"]["notes"]["config_source"]
    assert source["pair"] == "pass-stay" and source["config_file"] == str(user)


def test_a_partner_window_is_recorded_and_evaluated_with(cli, pair_store_template, tmp_path):
    """`assistant.partner_window=4`: the config record names it (the default record leaves it
    out, so runs made before the key keep their run keys), the world model reads the env's
    observation plus 3 earlier human actions, and `d2a eval` and `d2a intent-swap` drive the
    assistant with the same view."""
    import torch

    from d2a_core.config.section import record
    from d2a_core.sim.race_env import RaceEnv
    from d2a_core.tracks.sources import load_track_source
    from d2a_core.training.config import AssistantConfig

    assert "partner_window" not in record(AssistantConfig()) and "partner_window" in AssistantConfig().model_dump()
    store_path, store, art, _ = _train_one(cli, pair_store_template, tmp_path, "dream2assist",
                                           "assistant.partner_window=4")
    assert art.config["assistant"]["partner_window"] == 4
    weights = dict(_flat(torch.load(store.path(art.id, "agent.pt"), weights_only=False)))
    env_width = RaceEnv(load_track_source("straightaway").track).observation_space.shape[0]
    assert weights["world_model.encoder.hidden.0.linear.weight"].shape[1] == env_width + 6
    res = cli("eval", *PAIR, "--episodes", "1", "--json", store=store_path)
    assert res.code == 0, res.stderr
    assert res.json["evaluations"][0]["assistant"] == art.id
    res = cli("intent-swap", *PAIR, "--trials", "1", "--json", store=store_path)
    assert res.code == 0, res.stderr


def test_dreamer_ails_residual_stays_within_its_bound_in_training_and_evaluation(
        cli, pair_store_template, tmp_path):
    """`dreamer_ail.residual_bound=0.3`: recorded in the checkpoint's config, every action of
    training and of `d2a eval` lies in [-0.3, 0.3], and the learner's whole range maps onto it."""
    store_path, store, art, _ = _train_one(cli, pair_store_template, tmp_path, "dreamer-ail",
                                           "dreamer_ail.residual_bound=0.3")
    assert art.config["dreamer_ail"]["residual_bound"] == 0.3
    trained = np.load(io.BytesIO(store.read_bytes(art.id, "steps.npz")))["assistant_action"]
    res = cli("eval", *PAIR, "--method", "dreamer-ail", "--episodes", "1", "--json", store=store_path)
    assert res.code == 0, res.stderr
    evaluation = res.json["evaluations"][0]
    assert evaluation["assistant"] == art.id
    evaluated = np.load(io.BytesIO(store.read_bytes(evaluation["id"], "steps.npz")))["assistant_action"]
    for actions in (trained, evaluated):
        assert np.abs(actions).max() <= 0.3 + 1e-6
    # the learner's own range maps onto [-0.3, 0.3]: exploring, it reaches the bound but not past it
    from d2a_core.sim.race_env import RaceEnv
    from d2a_core.tracks.sources import load_track_source
    from d2a_core.stored_agents import load_assistant

    env = RaceEnv(load_track_source("straightaway").track)
    agent, *_ = load_assistant(store, art.id, env.observation_space, env.action_space)
    obs, _ = env.reset(seed=0)
    n = 256
    record = {"obs": np.repeat(obs[None], n, 0).astype(np.float32), "is_first": np.ones(n, bool),
              "reward": np.zeros(n, np.float32), "is_terminal": np.zeros(n, bool)}
    sampled, _ = agent.policy(record, None, explore=True)
    assert 0.25 < np.abs(sampled).max() <= 0.3 + 1e-6


def test_reward_relabelling_is_recorded_and_trains_and_a_hand_set_learner_key_is_refused(
        cli, pair_store_template, tmp_path):
    """`assistant.reward_relabel=true`: recorded in the run's config with the learner key it sets
    (both absent by default, so older runs keep their keys), the curve shows how much relabelling
    changed the reward targets; `dreamer.reward_relabel_head` set by hand exits 2 naming the
    assistant's key."""
    from d2a_core.agents.dreamer.config import DreamerConfig
    from d2a_core.config.section import record

    assert "reward_relabel_head" not in record(DreamerConfig())
    store_path, store, art, run = _train_one(cli, pair_store_template, tmp_path, "dream2assist",
                                             "assistant.reward_relabel=true")
    assert art.config["dreamer"]["reward_relabel_head"] == "intent" and art.config["assistant"]["reward_relabel"]
    curve = store.read_bytes(run["run_id"], "curve.jsonl").decode().splitlines()
    assert '"wm/reward_relabel_change"' in curve[-1]
    res = cli("train-assistant", *PAIR, "--method", "dream2assist", *SMOKE, "--set", "dreamer.reward_relabel_head=intent",
              "--json", store=store_path)
    assert res.code == 2 and "assistant.reward_relabel" in res.json["error"]["message"], res.stdout


def _flat(state, prefix=""):
    """(dotted name, tensor) of every tensor in a nested state dict."""
    for key, value in state.items():
        if isinstance(value, dict):
            yield from _flat(value, f"{prefix}{key}.")
        elif hasattr(value, "shape"):
            yield f"{prefix}{key}", value


@pytest.mark.parametrize("method, seed", [("dream2assist", 1), ("dreamer-ail", 2)])
def test_resume_after_sigkill(cli, pair_store, method, seed):
    args = ["train-assistant", *PAIR, "--method", method, *SMOKE, "--seed", str(seed),
            "--set", "assistant.env_steps=480", "--set", "assistant.checkpoints=4", "--json"]
    cmd = [sys.executable, "-m", "d2a_cli", *args, "--store", str(pair_store)]
    earlier_states = set((Path(pair_store) / "runs").glob("*/state.pt"))
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    store = Store(pair_store)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        mine = [a for a in store.list("assistant") if a.labels["seed"] == seed and a.labels["method"] == method]
        if mine and set((Path(pair_store) / "runs").glob("*/state.pt")) - earlier_states:
            break
        time.sleep(0.2)
    else:
        proc.kill()
        pytest.fail("no checkpoint appeared")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    res = cli(*args, store=pair_store)
    assert res.code == 0, res.stderr
    r = res.json["assistants"][0]
    assert r["resumed_from_env_step"] is not None and r["resumed_from_env_step"] >= mine[0].labels["env_step"]
    assert [c["env_step"] for c in r["checkpoints"]] == [120, 240, 360, 480]
    assert r["checkpoints"][0]["id"] == mine[0].id
    assert store.verify() == []


def test_usage_errors_name_what_to_do(cli, pair_store):
    res = cli("train-assistant", "--track", "straightaway", "--pair", "left-right", *SMOKE, "--json", store=pair_store)
    assert res.code == 2
    assert "d2a train-humans --intent left --track straightaway" in res.json["error"]["message"]
    res = cli("train-assistant", "--track", "straightaway", "--pair", "pass-overtake", *SMOKE, "--json",
              store=pair_store)
    assert res.code == 2 and "pass-stay, left-right" in res.json["error"]["message"]
    res = cli("train-assistant", *PAIR, "--method", "dream2asist", *SMOKE, "--json", store=pair_store)
    assert res.code == 2 and "unknown method 'dream2asist'" in res.json["error"]["message"]
    stay = Store(pair_store).resolve("humans/straightaway/stay")
    res = cli("train-assistant", *PAIR, "--humans", stay, "--humans", stay, *SMOKE, "--json", store=pair_store)
    assert res.code == 2 and "of intent 'stay', not 'pass'" in res.json["error"]["message"]
    res = cli("train-assistant", *PAIR, "--humans", stay, *SMOKE, "--json", store=pair_store)
    assert res.code == 2 and "one population per intent" in res.json["error"]["message"]
    # humans trained on another observation layout: exit 2 naming the setting, nothing stored
    before = {art.id for art in Store(pair_store).list()}
    res = cli("train-assistant", *PAIR, *SMOKE, "--set", "env.edge_lookahead_m=[10.0]", "--json", store=pair_store)
    assert res.code == 2 and "env.edge_lookahead_m" in res.json["error"]["message"]
    assert {art.id for art in Store(pair_store).list()} == before


def test_every_methods_checkpoint_loads_through_the_restricted_unpickler(trained_assistants):
    """What every method stores (a torch state dict; no-rssm's holds numpy arrays) loads with
    nothing but tensors and plain data, as it did with the unrestricted unpickler."""
    import torch

    from d2a_core.training.torch_files import load_torch

    store_dir, result = trained_assistants
    store = Store(store_dir)
    for run in result["assistants"]:
        path = store.path(run["id"], "agent.pt")
        safe, full = load_torch(path, run["id"]), torch.load(path, weights_only=False)
        assert sorted(safe) == sorted(full)
        flat_safe = torch.utils._pytree.tree_flatten(safe)[0]
        flat_full = torch.utils._pytree.tree_flatten(full)[0]
        assert len(flat_safe) == len(flat_full)
        for a, b in zip(flat_safe, flat_full):
            if isinstance(a, torch.Tensor):
                assert torch.equal(a, b)
            elif isinstance(a, np.ndarray):
                assert np.array_equal(a, b)
            else:
                assert a == b
