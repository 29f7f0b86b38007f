"""A store shared with someone else, and recoveries that must recover: a store's files may be
written by anyone, so nothing read from one may run code or write outside the places asked for,
and `verify --repair` followed by the same command must leave a working store."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from d2a_core.artifacts import Store
from d2a_core.artifacts.manifest import artifact_id, canonical_json
from d2a_test_helpers import REPO, copy_store, kill_after_state_saved, run_cli

SMOKE = ("--preset", "smoke")
HUMANS = ("train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE, "--set", "humans.checkpoints=3",
          "--set", "humans.env_steps=480", "--json")


def cli(*args, store):
    res = run_cli(*args, store=store)
    assert "Traceback" not in res.stderr, res.stderr
    return res


class _Planted:
    """Unpickling this writes a marker file: what a malicious checkpoint would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('ran')",))


def _planted_torch_file(path: Path, marker: Path) -> None:
    torch.save({"world_model": _Planted(marker)}, path)


def _forge(store_dir: Path, art_id: str, name: str, replacement: Path) -> str:
    """Re-store an artifact with one file replaced: the manifest is sealed like a real one, so
    hashes and `verify` find nothing wrong (whoever writes a store writes its manifests)."""
    store = Store(store_dir)
    art = store.get(art_id)
    files = {n: (replacement if n == name else store.path(art_id, n)) for n in art.files}
    return store.put(art.kind, files, inputs=art.inputs, config=art.config, seed=art.seed,
                     labels=dict(art.labels, forged=True)).id


ASSISTANT = ("train-assistant", "--track", "straightaway", "--pair", "pass-stay", "--method", "dreamer", *SMOKE,
             "--json")


@pytest.fixture(scope="module")
def one_assistant(pair_store_template, tmp_path_factory):
    """The pair store with one smoke assistant (dreamer), built once for this module."""
    store = copy_store(pair_store_template, tmp_path_factory.mktemp("one-assistant"))
    res = cli(*ASSISTANT, store=store)
    assert res.code == 0, res.stderr
    return store, res.json


@pytest.fixture
def assistants(one_assistant, tmp_path):
    store, result = one_assistant
    return copy_store(store, tmp_path), result


def test_a_planted_pickle_in_a_checkpoint_runs_nothing_and_exits_3(assistants, tmp_path):
    store, result = assistants
    final = result["assistants"][0]["id"]
    marker = tmp_path / "ran"
    _planted_torch_file(tmp_path / "agent.pt", marker)
    forged = _forge(store, final, "agent.pt", tmp_path / "agent.pt")
    assert cli("artifacts", "verify", "--json", store=store).code == 0  # the forgery is well sealed
    res = cli("eval", "--track", "straightaway", "--pair", "pass-stay", "--assistant", forged, "--episodes", "1",
              "--json", store=store)
    assert res.code == 3, res.stderr
    assert forged[:12] in res.stderr and "nothing in it was executed" in res.stderr
    assert not marker.exists()


def test_a_damaged_or_planted_run_state_exits_3_naming_the_run_and_a_resume_says_it_resumed(pair_store_template,
                                                                                              tmp_path):
    store = copy_store(pair_store_template, tmp_path)
    state = kill_after_state_saved(HUMANS, store)
    good = state.read_bytes()
    # a flipped byte: named, with the way out
    damaged = bytearray(good)
    damaged[len(damaged) // 2] ^= 0x10
    state.write_bytes(bytes(damaged))
    res = cli(*HUMANS, store=store)
    assert res.code == 3, res.stderr
    assert str(state.parent) in res.stderr and "delete" in res.stderr
    # a pickle dropped in place of the state (no checksum to forge): refused, nothing runs
    marker = tmp_path / "ran"
    _planted_torch_file(state, marker)
    res = cli(*HUMANS, store=store)
    assert res.code == 3, res.stderr
    assert not marker.exists()
    # the real state resumes; the population says from where, in its stored record too
    state.write_bytes(good)
    res = cli(*HUMANS, store=store)
    assert res.code == 0, res.stderr
    pop = res.json["populations"][0]
    assert pop["resumed_from_env_step"] is not None
    stored = Store(store).read_json(pop["id"], "population.json")
    assert stored["resumed_from_env_step"] == pop["resumed_from_env_step"]


def test_gc_removes_the_temp_file_of_a_killed_state_save(pair_store_template, tmp_path):
    store = copy_store(pair_store_template, tmp_path)
    run_dir = store / "runs" / ("ab" * 32)
    run_dir.mkdir(parents=True)
    (run_dir / "state.pt.tmp4242").write_bytes(b"half a state")
    res = cli("artifacts", "gc", "--json", store=store)
    assert res.code == 0, res.stderr
    assert not (run_dir / "state.pt.tmp4242").exists()


def test_a_second_identical_run_exits_naming_the_first(pair_store_template, tmp_path):
    store = copy_store(pair_store_template, tmp_path)
    args = (*HUMANS[:-1], "--set", "humans.env_steps=4000", "--json")
    cmd = [sys.executable, "-m", "d2a_cli", *args, "--store", str(store)]
    before = set((store / "runs").glob("*/lock"))
    first = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not set((store / "runs").glob("*/lock")) - before:
            assert first.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        time.sleep(1.0)
        res = cli(*args, store=store)
        assert res.code == 1, res.stderr
        assert "already being trained by process" in res.stderr and str(first.pid) in res.stderr
    finally:
        first.kill()
        first.wait()


def test_export_refuses_a_file_name_that_leaves_the_target(assistants, tmp_path):
    store, _ = assistants
    view = Store(store)
    track = view.get("track/straightaway")
    # a hand-made manifest, sealed with the right id and checksum, naming ../../escaped
    files = dict(track.files)
    files["../../escaped"] = next(iter(track.files.values()))
    body = {k: v for k, v in track.manifest.items() if k not in ("id", "sha256")}
    body["files"] = files
    forged_id = artifact_id(body)
    stored = dict(body, id=forged_id)
    import hashlib

    stored["sha256"] = hashlib.sha256(canonical_json(stored)).hexdigest()
    path = store / "manifests" / forged_id[:2] / f"{forged_id}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(canonical_json(stored))
    out = tmp_path / "a" / "b" / "out"
    res = cli("artifacts", "export", forged_id, str(out), store=store)
    assert res.code == 3, res.stderr
    assert forged_id[:12] in res.stderr
    assert not (tmp_path / "a" / "escaped").exists() and not (out / "../../escaped").exists()
    assert cli("artifacts", "verify", store=store).code == 3
    # a link inside the destination does not carry a copy outside either
    out2 = tmp_path / "out2"
    out2.mkdir()
    outside = tmp_path / "outside"
    outside.mkdir()
    (out2 / "track.npz").symlink_to(outside / "track.npz")
    res = cli("artifacts", "export", "track/straightaway", str(out2), store=store)
    assert res.code == 2, res.stderr
    assert not (outside / "track.npz").exists()


def test_gc_never_follows_a_link_out_of_the_store(assistants, tmp_path):
    store, _ = assistants
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "precious.txt").write_text("keep me")
    tmp = store / "tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.symlink_to(victim, target_is_directory=True)
    res = cli("artifacts", "gc", "--json", store=store)
    assert res.code == 3, res.stderr
    assert "link" in res.stderr
    assert (victim / "precious.txt").read_text() == "keep me"


def _blob_of(store: Path, art_id: str, name: str) -> Path:
    digest = Store(store).get(art_id).files[name]["sha256"]
    return store / "objects" / digest[:2] / digest


def _flip(path: Path) -> None:
    os.chmod(path, 0o644)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


def test_repair_then_the_same_command_rebuilds_what_was_quarantined(assistants):
    store, first = assistants
    args = ASSISTANT
    run = first["assistants"][0]
    evaluation = cli("eval", "--track", "straightaway", "--pair", "pass-stay", "--method", "dreamer",
                     "--episodes", "1", "--json", store=store)
    assert evaluation.code == 0, evaluation.stderr
    eval_id = evaluation.json["evaluations"][0]["id"]
    _flip(_blob_of(store, run["id"], "agent.pt"))
    eval_blob = _blob_of(store, eval_id, "eval.json")
    _flip(eval_blob)
    repair = cli("artifacts", "verify", "--repair", "--json", store=store)
    assert repair.json["repaired"] == 2, repair.stdout
    assert cli("artifacts", "verify", store=store).code == 3  # the two artifacts lack a blob now
    again = cli(*args, store=store)
    assert again.code == 0, again.stderr
    assert again.json["assistants"][0]["cached"] is False and again.json["assistants"][0]["id"] == run["id"]
    reeval = cli("eval", "--track", "straightaway", "--pair", "pass-stay", "--method", "dreamer",
                 "--episodes", "1", "--json", store=store)
    assert reeval.code == 0, reeval.stderr
    assert reeval.json["evaluations"][0]["cached"] is False
    res = cli("artifacts", "verify", "--json", store=store)
    assert res.code == 0, res.stdout + res.stderr


def test_read_done_reruns_a_cell_whose_output_lost_a_blob(pair_store_template, tmp_path):
    from d2a_core.pipelines.grid_run import RECORD_FORMAT, read_done, record_path

    store_dir = copy_store(pair_store_template, tmp_path)
    store = Store(store_dir)
    pop = store.resolve("humans/straightaway/stay")
    key = "k" * 16
    path = record_path(store.root, key)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"format": RECORD_FORMAT, "key": key, "ids": {"humans/straightaway/stay": pop}}))
    assert read_done(store, key) is not None
    checkpoint = store.get(pop).inputs[0]
    blob = _blob_of(store_dir, checkpoint, "agent.pt")
    quarantine = tmp_path / "q"
    quarantine.mkdir()
    os.replace(blob, quarantine / blob.name)  # what verify --repair does to a damaged blob
    assert read_done(Store(store_dir), key) is None


@pytest.mark.parametrize("args, needle", [
    (("eval", "--track", "straightaway", "--pair", "pass-stay", "--episodes", "100000000"), "--episodes"),
    (("eval", "--track", "straightaway", "--pair", "pass-stay", "--eval-seed", "-1"), "--eval-seed"),
    (("intent-swap", "--track", "straightaway", "--pair", "pass-stay", "--trials", "100000000"), "--trials"),
    (("reproduce", "--preset", "smoke", "--seeds", "100000000"), "--seeds"),
    (("config", "show", "--set", "dreamer.units=" + "9" * 4400), "4300"),
    (("config", "show", "--preset", "smoke", "--set", "humans.env_steps=3"), "checkpoints x num_envs"),
])
def test_bad_inputs_exit_2_with_a_short_message(args, needle, tmp_path):
    res = cli(*args, store=tmp_path / "store")
    assert res.code == 2, res.stderr
    assert needle in res.stderr and len(res.stderr) < 2000


@pytest.mark.parametrize("text", [
    "a: &a [*a]\n",                                                       # contains itself
    "".join(f"l{k}: &l{k} [{', '.join([f'*l{k - 1}'] * 9)}]\n" if k else "l0: &l0 [lol]\n" for k in range(9)),
])
def test_yaml_aliases_are_refused_fast(text, tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text(text)
    started = time.monotonic()
    res = cli("config", "show", "--preset", "smoke", "--config", str(config), store=tmp_path / "store")
    assert res.code == 2, res.stderr[:2000]
    assert "alias" in res.stderr and len(res.stderr) < 2000
    assert time.monotonic() - started < 10


def test_report_out_that_is_a_file_is_refused_before_building(tmp_path):
    store = tmp_path / "store"
    target = tmp_path / "report.md"
    target.write_text("mine")
    started = time.monotonic()
    res = cli("report", "--out", str(target), store=store)
    assert res.code == 2, res.stderr
    assert str(target) in res.stderr and target.read_text() == "mine"
    assert time.monotonic() - started < 20


def test_a_killed_evaluation_leaves_its_logs_in_the_store_where_gc_removes_them(assistants, tmp_path):
    store, _ = assistants
    system_tmp = tmp_path / "systmp"
    system_tmp.mkdir()
    cmd = [sys.executable, "-m", "d2a_cli", "eval", "--track", "straightaway", "--pair", "pass-stay",
           "--method", "dreamer", "--episodes", "50", "--store", str(store)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=dict(os.environ, TMPDIR=str(system_tmp)))
    deadline = time.monotonic() + 120
    while not list((store / "tmp").glob("scratch-eval-*/**/*.mcap")):
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    # while it runs, gc keeps its scratch directory
    assert cli("artifacts", "gc", "--json", store=store).code == 0
    assert list((store / "tmp").glob("scratch-eval-*"))
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not list(system_tmp.glob("d2a-*"))
    res = cli("artifacts", "gc", "--json", store=store)
    assert res.code == 0, res.stderr
    assert not list((store / "tmp").glob("scratch-*"))
