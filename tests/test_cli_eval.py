"""`d2a eval`: the selection rule, pairing (a zero assistant changes nothing), the JSON shape,
the stored evaluation, and errors that name what to run."""

from __future__ import annotations

import io

import numpy as np
import pytest

from d2a_core.artifacts import Store
from d2a_core.evaluation.paired import select_humans
from d2a_core.pipelines.evaluate import CRITERION, METRICS, evaluate
from d2a_core.sim.episode_log.reader import read_episode

from d2a_test_helpers import copy_store

SMOKE = ("--preset", "smoke")
PAIR = ("--track", "straightaway", "--pair", "pass-stay")


@pytest.fixture(scope="module")
def eval_store(trained_assistants, tmp_path_factory):
    return copy_store(trained_assistants[0], tmp_path_factory.mktemp("eval"))


def synthetic(returns, expert):
    cps = [{"id": f"c{k}", "env_step": k, "metrics": {"return": r}} for k, r in enumerate(returns)]
    return {"expert": f"c{expert}", "checkpoints": cps}


def test_selection_rule_on_a_synthetic_population():
    # performance = return / 100 here (weakest 0, expert 100)
    pop = synthetic([0, 5, 18, 25, 41, 55, 62, 79, 85, 95, 100], expert=10)
    chosen = select_humans(pop, "pass", 0)
    imperfect = [h.id for h in chosen if h.group == "imperfect"]
    near = [h.id for h in chosen if h.group == "near_perfect"]
    # nearest to 0, 0.2, 0.4, 0.6, 0.8 in turn, numbered by performance
    assert imperfect == ["c0", "c2", "c4", "c6", "c7"]
    assert [h.number for h in chosen if h.group == "imperfect"] == [1, 2, 3, 4, 5]
    assert near == ["c8", "c9", "c10"]  # >= 75 % and not imperfect, the expert included
    # performance is relative to the weakest checkpoint: a tight population still spans 0..1
    top = select_humans(synthetic([80, 90, 85, 95, 99, 97, 100], expert=6), "stay", 1)
    assert [h.id for h in top if h.group == "imperfect"] == ["c0", "c2", "c1", "c3", "c5"]  # 0 .25 .5 .75 .85
    assert [h.id for h in top if h.group == "near_perfect"] == ["c4", "c6"]
    # an expert that is the weakest (every checkpoint returns the same): nothing under 75 %, the five weakest
    flat = select_humans(synthetic([5, 5, 5, 5, 5, 5, 5], expert=6), "stay", 1)
    assert [h.id for h in flat if h.group == "imperfect"] == ["c0", "c1", "c2", "c3", "c4"]
    few = select_humans(synthetic([10, 100], expert=1), "stay", 1)
    assert [(h.id, h.group) for h in few] == [("c0", "imperfect"), ("c1", "near_perfect")]


class ZeroAssistant:
    """Always a_A = 0, no intent estimate."""

    def __init__(self):
        self.calls = 0

    def initial_state(self, n):
        return None

    def policy(self, obs_batch, state=None, explore=True):
        self.calls += 1
        return np.zeros((len(obs_batch["obs"]), 2), np.float32), state

    def intent_probs(self, state):
        return None

    def observe(self, transition):
        raise AssertionError("evaluation must not train")

    def updates_due(self, env_steps):
        return 0

    def train_step(self):
        return {}

    def state_dict(self, include_replay=False):
        return {}

    def load_state_dict(self, state):
        pass


def test_an_assistant_that_outputs_zeros_changes_nothing(eval_store, monkeypatch):
    """Pairing: the same specs unassisted and with a zero assistant give identical episodes."""
    zero = ZeroAssistant()
    monkeypatch.setattr("d2a_core.pipelines.evaluate.load_assistant",
                        lambda store, ref, o, a, device="cpu": (zero, None, ("pass", "stay"), 1))
    # its own eval seed: the zero assistant's evaluation is stored under its run key, which must
    # not be the key a later real evaluation of the same assistant looks up
    out = evaluate(Store(eval_store), "straightaway", "pass-stay", method="dreamer", episodes=2, n_envs=3,
                   eval_seed=7)
    e = out["evaluations"][0]
    assert zero.calls > 0 and e["humans"]
    for human in e["humans"]:
        assert human["episodes"] == 2
        assert all(human["delta"][m] == 0.0 for m in (*METRICS, CRITERION)), human
        assert human["unassisted"] == human["assisted"]
    for block in e["intents"].values():
        for group in ("imperfect", "near_perfect"):
            if group in block:
                assert all(block[group][m] == {"mean": 0.0, "std": 0.0} for m in METRICS)


def test_eval_reports_the_paper_table_and_stores_each_evaluation(cli, eval_store, tmp_path):
    res = cli("eval", *PAIR, "--baseline", "dreamer", "--episodes", "2", "--json", store=eval_store)
    assert res.code == 0, res.stderr
    evals = res.json["evaluations"]
    assert [(e["method"], e["seed"]) for e in evals] == [("dream2assist", 0), ("dreamer", 0)]
    store = Store(eval_store)
    for e in evals:
        assert e["assistant"] == store.resolve(f"assistants/straightaway/pass-stay/{e['method']}/seed0")
        for intent in ("pass", "stay"):
            block = e["intents"][intent]
            assert set(block["imperfect"]) == {*METRICS, CRITERION, f"{CRITERION}_unassisted"}
            assert set(block["imperfect"]["progress_m"]) == {"mean", "std"}
            assert (block["intent_f1"] is None) == (e["method"] == "dreamer")
        groups = {(h["intent"], h["group"]) for h in e["humans"]}
        assert ("pass", "imperfect") in groups and ("stay", "near_perfect") in groups
        # the safety rule: exactly the groups whose collision or off-track rate rose by more than
        # 0.05 are flagged
        rose = {(i, g, m) for i, b in e["intents"].items() for g in ("imperfect", "near_perfect")
                for m in ("collision", "off_track") if g in b and b[g][m]["mean"] > 0.05 + 1e-9}
        assert {(f["intent"], f["group"], f["metric"]) for f in e["safety_flags"]} == rose
        episodes = store.read_json(e["id"], "eval.json")["unassisted"]
        for i, h in enumerate(e["humans"]):
            assert set(h) >= {"id", "intent", "group", "unassisted", "assisted", "delta"}
            assert h["delta"]["progress_m"] == pytest.approx(h["assisted"]["progress_m"] - h["unassisted"]["progress_m"],
                                                             abs=1e-5)
            # the human's own intent criterion, from its episodes (pass: finished ahead)
            key = {"pass": "finished_ahead", "stay": "finished_never_ahead"}[h["intent"]]
            mine = [r for r in episodes if r["human"] == i]
            assert h["unassisted"][CRITERION] == pytest.approx(np.mean([r[key] for r in mine]), abs=1e-6)
            assert h["unassisted"]["off_track"] == pytest.approx(np.mean([r["off_track"] for r in mine]), abs=1e-6)
        art = store.get(e["id"])
        assert art.kind == "evaluation" and e["assistant"] in art.inputs
        assert set(h["id"] for h in e["humans"]) <= set(art.inputs)
        assert store.resolve(f"eval/straightaway/pass-stay/{e['method']}/seed0") == e["id"]
        stored = store.read_json(e["id"], "eval.json")
        # pairing: every assisted episode has an unassisted twin with the same seed and opponent replay
        twins = {(r["human"], r["seed"]): r for r in stored["unassisted"]}
        for r in stored["assisted"]:
            assert twins[(r["human"], r["seed"])]["label"] == r["label"]
        steps = np.load(io.BytesIO(store.read_bytes(e["id"], "steps.npz")))
        assert ("p_true" in steps) == (e["method"] != "dreamer")
        # the assistant's latent states along each human's first episode, labelled by the true intent
        latents = np.load(io.BytesIO(store.read_bytes(e["id"], "latents.npz")))
        first = [k for k, r in enumerate(stored["assisted"]) if r["seed"] == stored["assisted"][0]["seed"]]
        assert sorted(set(latents["episode"].tolist())) == first
        assert latents["features"].shape == (sum(stored["assisted"][k]["steps"] for k in first), 32)  # smoke deter
        assert set(latents["label"].tolist()) == {0, 1}
    d2a = evals[0]
    assert d2a["intent_f1"] is not None and len(d2a["intent_confusion"]) == 2
    # every episode of both conditions is an MCAP log in the evaluation: read one back after export
    stored = store.read_json(d2a["id"], "eval.json")
    logs = [name for name in store.get(d2a["id"]).files if name.endswith(".mcap")]
    assert len(logs) == len(stored["assisted"]) + len(stored["unassisted"])
    out = cli("artifacts", "export", d2a["id"], str(tmp_path / "out"), store=eval_store)
    assert out.code == 0, out.stderr
    row = stored["assisted"][0]
    episode = read_episode(tmp_path / "out" / "episodes" / "assisted" / f"human{row['human']:03d}-seed{row['seed']}.mcap")
    assert len(episode) == row["steps"] + 1  # the reset observation and every step
    assistant = episode.state["assistant"]
    probs = assistant["intent_probs.pass"][1:] + assistant["intent_probs.stay"][1:]
    np.testing.assert_allclose(probs, 1.0, atol=1e-5)
    assert set(assistant["true_intent"]) == {row["intent"]}
    assert {"human_action.steer", "assistant_action.accel", "applied_action.steer", "ds", "de", "speed",
            "reward_terms.task"} <= set(episode.state["ego"])
    assert episode.metadata["condition"] == "assisted" and episode.metadata["method"] == "dream2assist"
    assert episode.metadata["seed"] == row["seed"] and "ego" in episode.poses
    again = cli("eval", *PAIR, "--seed", "0", "--episodes", "2", "--json", store=eval_store)
    assert again.code == 0 and again.json["evaluations"][0]["cached"]
    assert again.json["evaluations"][0]["id"] == d2a["id"]
    # the human-readable table (cached, so instant): the intent criterion before -> after
    table = cli("eval", *PAIR, "--seed", "0", "--episodes", "2", store=eval_store)
    assert table.code == 0 and "finished ahead" in table.stdout and "→" in table.stdout


def test_dreamer_ail_is_evaluated_and_swapped_like_any_baseline_and_traces_to_its_demonstrations(cli, eval_store):
    """`eval --baseline dreamer-ail`: the same protocol (no intent F1: it has no estimate), its
    lineage names the experts' demonstrations it imitated; `intent-swap` drives it too."""
    res = cli("eval", *PAIR, "--baseline", "dreamer-ail", "--episodes", "1", "--json", store=eval_store)
    assert res.code == 0, res.stderr
    ail = next(e for e in res.json["evaluations"] if e["method"] == "dreamer-ail")
    assert ail["intent_f1"] is None
    store = Store(eval_store)
    demos = [i for i in store.get(ail["assistant"]).inputs if store.get(i).kind == "demonstrations"]
    assert len(demos) == 1
    made_by = [store.get(i) for i in store.get(demos[0]).inputs if store.get(i).kind == "human"]
    assert sorted(h.labels["intent"] for h in made_by) == ["pass", "stay"]  # each intent's expert
    res = cli("intent-swap", *PAIR, "--method", "dreamer-ail", "--trials", "1", "--window", "1", "3", "--json",
              store=eval_store)
    assert res.code == 0, res.stderr


def test_eval_errors_name_what_to_run(cli, eval_store):
    res = cli("eval", *PAIR, "--seed", "3", "--json", store=eval_store)
    assert res.code == 2
    assert "d2a train-assistant --track straightaway --pair pass-stay --method dream2assist --seed 3" in \
        res.json["error"]["message"]
    Store(eval_store).untag("assistants/straightaway/pass-stay/no-rssm/seed0")
    res = cli("eval", *PAIR, "--baseline", "no-rssm", "--json", store=eval_store)
    assert res.code == 2 and "--method no-rssm" in res.json["error"]["message"]
    res = cli("eval", *PAIR, "--baseline", "dreamr", "--json", store=eval_store)
    assert res.code == 2 and "unknown method 'dreamr'" in res.json["error"]["message"]
    res = cli("eval", "--track", "straightaway", "--pair", "left-right", "--json", store=eval_store)
    assert res.code == 2 and "left-right" in res.json["error"]["message"]
    res = cli("eval", *PAIR, "--episodes", "0", "--json", store=eval_store)
    assert res.code == 2 and "--episodes" in res.stderr + res.stdout
    res = cli("eval", *PAIR, "--humans", "nonexistent", "--humans", "humans/straightaway/stay", "--json",
              store=eval_store)
    assert res.code == 2 and "nonexistent" in res.json["error"]["message"]


def test_intent_swap_reports_recovery_for_each_direction_and_stores_the_trials(cli, eval_store):
    res = cli("intent-swap", *PAIR, "--baseline", "dreamer", "--trials", "2", "--window", "1", "3", "--json",
              store=eval_store)
    assert res.code == 0, res.stderr
    swaps = res.json["intent_swaps"]
    assert [(s["method"], s["seed"]) for s in swaps] == [("dream2assist", 0), ("dreamer", 0)]
    store = Store(eval_store)
    for s in swaps:
        assert set(s["metrics"]) == {"pass-to-stay", "stay-to-pass"}
        for direction, curve in s["directions"].items():
            if s["method"] == "dreamer":
                assert curve is None  # no intent estimate, no curve
                continue
            assert curve["trials"] == 2 and curve["time_s"][20] == 0.0
            assert len(curve["accuracy"]) == len(curve["time_s"])
        art = store.get(s["id"])
        assert art.kind == "intent-swap" and s["assistant"] in art.inputs
        stored = store.read_json(s["id"], "swap.json")
        assert all(10 <= spec["swap_step"] <= 30 for spec in stored["specs"])  # the 1-3 s window at dt 0.1
        assert sum(name.endswith(".mcap") for name in art.files) == 2 * len(stored["specs"])
        assert store.resolve(f"intent-swap/straightaway/pass-stay/{s['method']}/seed0") == s["id"]
    bad = cli("intent-swap", *PAIR, "--window", "5", "2", "--json", store=eval_store)
    assert bad.code == 2 and "--window" in bad.json["error"]["message"]


def test_held_out_means_populations_the_assistant_did_not_train_with(cli, eval_store):
    """The assistant's own populations named explicitly are not held out (the plain alias);
    others are (the alias gets /humans-<ids>)."""
    store = Store(eval_store)
    own = [store.resolve("humans/straightaway/pass"), store.resolve("humans/straightaway/stay")]
    res = cli("eval", *PAIR, "--method", "dreamer", "--humans", own[0], "--humans", own[1], "--episodes", "1",
              "--json", store=eval_store)
    assert res.code == 0, res.stderr
    e = res.json["evaluations"][0]
    assert e["held_out"] is False and store.resolve("eval/straightaway/pass-stay/dreamer/seed0") == e["id"]
    other = cli("train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE, "--seed", "1", "--json",
                store=eval_store)
    assert other.code == 0, other.stderr
    stay1 = other.json["populations"][0]["id"]
    res = cli("eval", *PAIR, "--method", "dreamer", "--humans", own[0], "--humans", stay1, "--episodes", "1",
              "--json", store=eval_store)
    assert res.code == 0, res.stderr
    e = res.json["evaluations"][0]
    assert e["held_out"] is True
    assert store.resolve(f"eval/straightaway/pass-stay/dreamer/seed0/humans-{own[0][:8]}-{stay1[:8]}") == e["id"]


def test_eval_of_a_named_checkpoint_keeps_the_final_alias(cli, eval_store, trained_assistants):
    """`--assistant` evaluates any assistant artifact (here the run's first checkpoint, not its
    final one) under its own alias, leaving `eval/.../seed0` to the final assistant."""
    store = Store(eval_store)
    run = next(a for a in trained_assistants[1]["assistants"] if a["method"] == "dream2assist")
    first = run["checkpoints"][0]
    assert first["id"] != store.resolve("assistants/straightaway/pass-stay/dream2assist/seed0")
    before = store.refs().get("eval/straightaway/pass-stay/dream2assist/seed0")
    own = [a for p in run["populations"] for a in ("--humans", p)]  # other tests move the humans aliases
    res = cli("eval", *PAIR, "--assistant", first["id"][:12], *own, "--episodes", "1", "--json", store=eval_store)
    assert res.code == 0, res.stderr
    (e,) = res.json["evaluations"]
    assert (e["method"], e["seed"], e["assistant"]) == ("dream2assist", 0, first["id"])
    assert e["assistant_env_step"] == first["env_step"]
    assert store.resolve(f"eval/straightaway/pass-stay/dream2assist/seed0/checkpoint-{first['id'][:12]}") == e["id"]
    assert store.refs().get("eval/straightaway/pass-stay/dream2assist/seed0") == before
    # the final one by its alias is the default evaluation's assistant
    final = cli("eval", *PAIR, "--assistant", "assistants/straightaway/pass-stay/dream2assist/seed0", *own,
                "--episodes", "1", "--json", store=eval_store)
    assert final.code == 0, final.stderr
    assert store.resolve("eval/straightaway/pass-stay/dream2assist/seed0") == final.json["evaluations"][0]["id"]
    # usage errors: mixed with --seed, not an assistant
    mixed = cli("eval", *PAIR, "--assistant", first["id"], "--seed", "0", "--json", store=eval_store)
    assert mixed.code == 2 and "--assistant" in mixed.json["error"]["message"]
    pop = cli("eval", *PAIR, "--assistant", "humans/straightaway/pass", "--json", store=eval_store)
    assert pop.code == 2 and "not an assistant" in pop.json["error"]["message"]


def test_a_repeated_evaluation_takes_its_alias_back(cli, eval_store, trained_assistants):
    """An evaluation asked for again (stored, so returned as it is) is again the one its alias names."""
    run = next(a for a in trained_assistants[1]["assistants"] if a["method"] == "dream2assist")
    own = [a for p in run["populations"] for a in ("--humans", p)]
    alias = "eval/straightaway/pass-stay/dream2assist/seed0"
    args = (*PAIR, "--assistant", "assistants/straightaway/pass-stay/dream2assist/seed0", *own, "--json")
    one = cli("eval", *args, "--episodes", "1", store=eval_store)
    two = cli("eval", *args, "--episodes", "2", store=eval_store)
    assert one.code == 0 and two.code == 0, two.stderr
    assert Store(eval_store).resolve(alias) == two.json["evaluations"][0]["id"] != one.json["evaluations"][0]["id"]
    again = cli("eval", *args, "--episodes", "1", store=eval_store)
    assert again.json["evaluations"][0]["cached"]
    assert Store(eval_store).resolve(alias) == one.json["evaluations"][0]["id"]
