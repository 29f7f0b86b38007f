"""`d2a reproduce`: the grid's expansion and order, a smoke grid end to end on the local executor,
a rerun that does nothing, resume after SIGKILL of the driver, a failing cell, and the same grid
on a local Ray cluster.

The smoke grid is one track, one pair, `dreamer` (the fastest method), one seed: 7 cells, about
45 s with --jobs 2 on the loaded 2-core development machine. The tests that change a store work
on a copy of the end-to-end run's store.
"""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from d2a_core.artifacts import Store
from d2a_core.errors import UsageError
from d2a_core.pipelines import grid_run
from d2a_core.pipelines.executors import CellOutcome, plan, prepare
from d2a_core.pipelines.grid import DepId, DepIds, GridOptions, dependents, expand

from d2a_test_helpers import REPO, built_once, copy_store, run_cli

GRID = ("--preset", "smoke", "--track", "straightaway", "--pair", "pass-stay", "--method", "dreamer")
ONE_SEED = (*GRID, "--seeds", "1")


def reproduce(store: Path, *args: str, timeout: float = 400):
    return run_cli("reproduce", *args, "--json", store=store, timeout=timeout)


def by_name(result: dict) -> dict[str, dict]:
    return {c["name"]: c for c in result["cells"]}


# --------------------------------------------------------------------------- expansion (no training)
def test_grid_expands_in_dependency_order_with_the_subcommands_argv():
    cells = expand(GridOptions(preset="smoke", tracks=["straightaway", "hairpin"], pairs=["pass-stay", "left-right"],
                               methods=["dreamer", "dream2assist"], seeds=2, humans_seeds=[3],
                               overrides=["humans.checkpoints=4", "train-assistant/*/seed1:assistant.env_steps=480"]))
    kinds = [c.kind for c in cells]
    assert kinds.count("make-track") == 2
    assert kinds.count("train-humans") == 2 * 4  # per track, each intent of the pairs, once
    assert kinds.count("train-assistant") == 2 * 2 * 2 * 2  # track x pair x method x seed
    assert kinds.count("eval") == kinds.count("intent-swap") == 4
    assert kinds[-1] == "report" and kinds.count("report") == 1
    names = [c.name for c in cells]
    assert len(set(names)) == len(names)
    for k, cell in enumerate(cells):  # every dependency comes before its cell
        assert all(d in names[:k] for d in cell.deps), cell.name
    cell = {c.name: c for c in cells}

    track = cell["make-track/hairpin"]
    assert track.argv == ("make-track", "hairpin", "--seed", "0", "--preset", "smoke", "--set", "humans.checkpoints=4")
    assert track.artifact == "track/hairpin" and track.deps == ()
    humans = cell["train-humans/hairpin/left/seed3"]
    assert humans.argv == ("train-humans", "--intent", "left", "--track", "hairpin", "--seed", "3", "--preset", "smoke",
                           "--set", "humans.checkpoints=4")
    assert humans.deps == ("make-track/hairpin",) and humans.artifact == "humans/hairpin/left"

    # every seed trains with the pair's two populations, passed by id once they exist
    for seed in (0, 1):
        a = cell[f"train-assistant/hairpin/left-right/dream2assist/seed{seed}"]
        assert a.deps == ("train-humans/hairpin/left/seed3", "train-humans/hairpin/right/seed3")
        assert list(a.argv[:7]) == ["train-assistant", "--track", "hairpin", "--pair", "left-right", "--method",
                                    "dream2assist"]
        assert a.argv[7:11] == ("--humans", DepId("train-humans/hairpin/left/seed3", "humans/hairpin/left"),
                                "--humans", DepId("train-humans/hairpin/right/seed3", "humans/hairpin/right"))
        assert a.argv[11:13] == ("--seed", str(seed))
        assert a.artifact == f"assistants/hairpin/left-right/dream2assist/seed{seed}"
        # the scoped override reaches seed 1 only; the unscoped one every config-taking cell
        assert ("assistant.env_steps=480" in a.argv) == (seed == 1)
        assert "humans.checkpoints=4" in a.argv

    ev = cell["eval/straightaway/pass-stay"]
    assert ev.argv == ("eval", "--track", "straightaway", "--pair", "pass-stay", "--method", "dream2assist",
                       "--baseline", "dreamer", "--seed", "0", "--seed", "1", "--episodes", "1", "--eval-seed", "0",
                       "--envs", "2")
    assert set(ev.deps) == {f"train-assistant/straightaway/pass-stay/{m}/seed{s}" for m in ("dreamer", "dream2assist")
                            for s in (0, 1)} | {f"train-humans/straightaway/{i}/seed3" for i in ("pass", "stay")}
    assert dict(ev.expects) == {"humans/straightaway/pass": DepId("train-humans/straightaway/pass/seed3",
                                                                  "humans/straightaway/pass"),
                                "humans/straightaway/stay": DepId("train-humans/straightaway/stay/seed3",
                                                                  "humans/straightaway/stay")}
    swap = cell["intent-swap/straightaway/pass-stay"]
    assert swap.argv[0] == "intent-swap" and "--trials" in swap.argv and swap.deps == ev.deps
    assert cell["report"].argv == ("report", "--track", "straightaway", "--track", "hairpin", "--pair", "pass-stay",
                                   "--pair", "left-right")
    assert set(cell["report"].deps) == {c.name for c in cells if c.kind in ("eval", "intent-swap")}

    # a failed population blocks its track's pair and the report, not the other track
    blocked = dependents(cells, "train-humans/hairpin/left/seed3")
    assert "eval/hairpin/left-right" in blocked and "report" in blocked
    assert not any("straightaway" in n or "hairpin/pass-stay" in n for n in blocked)

    with pytest.raises(UsageError, match="takes no config"):
        expand(GridOptions(preset="smoke", overrides=["eval:assistant.env_steps=1"]))
    assert any(c.argv[:7] == ("train-assistant", "--track", "straightaway", "--pair", "pass-stay", "--method",
                              "dreamer-ail") for c in expand(GridOptions(preset="smoke")))  # every method by default
    with pytest.raises(UsageError, match="unknown method"):
        expand(GridOptions(preset="smoke", methods=["dream2asist"]))
    with pytest.raises(UsageError, match="pair 'pass-left-right'"):
        expand(GridOptions(preset="smoke", pairs=["pass-left-right"]))


def test_a_cells_key_follows_its_inputs(tmp_path):
    cells = expand(GridOptions(preset="smoke", methods=["dreamer"], seeds=1))
    cell = {c.name: c for c in cells}
    a = cell["train-assistant/straightaway/pass-stay/dreamer/seed0"]
    outcomes = {c.name: CellOutcome(c) for c in cells}
    for name, pop in (("train-humans/straightaway/pass/seed0", "p" * 64),
                      ("train-humans/straightaway/stay/seed0", "s" * 64)):
        outcomes[name].ids = {cell[name].artifact: pop}
    argv, _, key = prepare(a, outcomes, {})
    assert argv[7:11] == ["--humans", "p" * 64, "--humans", "s" * 64]
    outcomes["train-humans/straightaway/stay/seed0"].ids = {"humans/straightaway/stay": "t" * 64}
    assert prepare(a, outcomes, {})[2] != key  # another population: another cell
    # an eval's argv names aliases and seeds, not ids: its key follows what its dependencies yielded
    ev = cell["eval/straightaway/pass-stay"]
    outcomes[a.name].ids = {a.artifact: "a" * 64}
    eval_key = prepare(ev, outcomes, {})[2]
    outcomes[a.name].ids = {a.artifact: "b" * 64}
    assert prepare(ev, outcomes, {})[2] != eval_key
    again = expand(GridOptions(preset="smoke", methods=["dreamer"], seeds=1, overrides=["assistant.env_steps=480"]))
    b = {c.name: c for c in again}[a.name]
    assert prepare(b, outcomes, {})[2] != prepare(a, outcomes, {})[2]  # another config: another cell
    # an assistant's config is its pair's: under `quick`, left-right takes its `pairs:` values
    quick = {c.name: c for c in expand(GridOptions(preset="quick", pairs=["pass-stay", "left-right"],
                                                   methods=["dreamer"], seeds=1))}
    ps, lr = (quick[f"train-assistant/straightaway/{p}/dreamer/seed0"].config for p in ("pass-stay", "left-right"))
    assert ps[3] == "pass-stay" and lr[3] == "left-right"
    assert grid_run.config_fingerprint(*lr) != grid_run.config_fingerprint(*ps)
    assert grid_run.config_fingerprint(*ps) == grid_run.config_fingerprint(*ps[:3])
    assert quick["train-humans/straightaway/left/seed0"].config[3] is None
    # nothing stored: every cell pending, and a dry run writes nothing
    assert {o.status for o in plan(cells, Store(tmp_path / "none"))} == {"pending"}
    assert not (tmp_path / "none").exists()


def test_several_humans_seeds_train_every_assistant_on_all_their_populations():
    """`--humans-seed 0 --humans-seed 2`: the first seed's populations stay the reference (aliases,
    evaluation), the others are side populations, and every assistant gets all of an intent's
    populations in one `--humans A,B`, its reference first."""
    cells = expand(GridOptions(preset="smoke", methods=["dreamer"], seeds=1, humans_seeds=[0, 2]))
    cell = {c.name: c for c in cells}
    ref, side = cell["train-humans/straightaway/pass/seed0"], cell["train-humans/straightaway/pass/seed2"]
    assert "--no-alias" not in ref.argv and ref.artifact == "humans/straightaway/pass"
    assert side.argv[7] == "--no-alias"
    assert side.argv[:7] == ("train-humans", "--intent", "pass", "--track", "straightaway", "--seed", "2")
    assert side.artifact == "humans/straightaway/pass/side"
    a = cell["train-assistant/straightaway/pass-stay/dreamer/seed0"]
    assert a.argv[7:11] == (
        "--humans", DepIds((DepId("train-humans/straightaway/pass/seed0", "humans/straightaway/pass"),
                            DepId("train-humans/straightaway/pass/seed2", None))),
        "--humans", DepIds((DepId("train-humans/straightaway/stay/seed0", "humans/straightaway/stay"),
                            DepId("train-humans/straightaway/stay/seed2", None))))
    assert set(a.deps) == {f"train-humans/straightaway/{i}/seed{h}" for i in ("pass", "stay") for h in (0, 2)}
    ev = cell["eval/straightaway/pass-stay"]
    assert dict(ev.expects) == {f"humans/straightaway/{i}": DepId(f"train-humans/straightaway/{i}/seed0",
                                                                  f"humans/straightaway/{i}") for i in ("pass", "stay")}

    # the side cells' results name their own alias; the assistant gets "ref,side" per intent
    outcomes = {c.name: CellOutcome(c) for c in cells}
    for intent, h, pop in (("pass", 0, "p"), ("pass", 2, "q"), ("stay", 0, "s"), ("stay", 2, "t")):
        aliases = ({f"humans/straightaway/{intent}": pop * 64, f"humans/straightaway/{intent}/expert": "e" * 64}
                   if h == 0 else {f"humans/straightaway/{intent}/side/{pop * 12}": pop * 64})
        result = {"populations": [{"track": "straightaway", "intent": intent, "id": pop * 64, "aliases": aliases}]}
        ids, main = grid_run.produced("train-humans", result)
        assert ids == aliases and main == pop * 64
        o = outcomes[f"train-humans/straightaway/{intent}/seed{h}"]
        o.ids, o.id = ids, main
    argv, expects, _ = prepare(a, outcomes, {})
    assert argv[7:11] == ["--humans", "p" * 64 + "," + "q" * 64, "--humans", "s" * 64 + "," + "t" * 64]
    assert prepare(ev, outcomes, {})[1] == {"humans/straightaway/pass": "p" * 64, "humans/straightaway/stay": "s" * 64}
    assert str(a.argv[8]) == "<id of humans/straightaway/pass>,<id of train-humans/straightaway/pass/seed2>"

    with pytest.raises(UsageError, match="distinct"):
        expand(GridOptions(preset="smoke", methods=["dreamer"], humans_seeds=[1, 1]))
    # one seed: the grid of before, cell for cell
    assert [c.argv for c in expand(GridOptions(preset="smoke", methods=["dreamer"], humans_seeds=[0]))] == \
        [c.argv for c in expand(GridOptions(preset="smoke", methods=["dreamer"]))]


# --------------------------------------------------------------------------- the smoke grid, local
def _run_local_grid(directory: Path) -> tuple[str, dict, float]:
    store = directory / "store"
    started = time.monotonic()
    res = reproduce(store, *ONE_SEED, "--jobs", "2")
    assert res.code == 0, res.stdout + res.stderr
    return str(store), res.json, time.monotonic() - started


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """The smoke grid run once per session (shared by the xdist workers); read it or copy it."""
    store, result, seconds = built_once(tmp_path_factory, "reproduce-local", _run_local_grid)
    return Path(store), result, seconds


def test_smoke_grid_end_to_end_on_the_local_executor(local_run):
    store_dir, result, _ = local_run
    store = Store(store_dir)
    cells = by_name(result)
    assert list(cells) == ["make-track/straightaway", "train-humans/straightaway/pass/seed0",
                           "train-humans/straightaway/stay/seed0",
                           "train-assistant/straightaway/pass-stay/dreamer/seed0",
                           "eval/straightaway/pass-stay", "intent-swap/straightaway/pass-stay", "report"]
    assert {c["status"] for c in result["cells"]} == {"ran"}
    assert all(c["seconds"] > 0 for c in result["cells"])
    # each cell's aliases point at what it made: the subcommands' own artifacts
    for c in result["cells"]:
        for alias, art_id in c["ids"].items():
            assert store.resolve(alias) == art_id
    assert result["report"] == store.resolve("report/latest") == cells["report"]["id"]
    assert store.get(result["report"]).kind == "report"
    pops = [cells[f"train-humans/straightaway/{i}/seed0"]["id"] for i in ("pass", "stay")]
    run = store.read_json("assistant-runs/straightaway/pass-stay/dreamer/seed0", "run.json")
    assert run["populations"] == pops and run["seed"] == 0
    ev = store.read_json("eval/straightaway/pass-stay/dreamer/seed0", "eval.json")["result"]
    assert ev["assistant"] == cells["train-assistant/straightaway/pass-stay/dreamer/seed0"]["id"]
    assert ev["populations"] == pops
    assert store.get("intent-swap/straightaway/pass-stay/dreamer/seed0").kind == "intent-swap"
    # the cell's subprocess was the subcommand with the grid's thread count
    pop = store.read_json(pops[0], "population.json")
    assert pop["runtime"]["torch_threads"] == 1
    assert store.verify() == []


def test_a_finished_grid_rerun_runs_nothing(local_run, tmp_path):
    store_dir, first = copy_store(local_run[0], tmp_path), local_run[1]
    manifests = sorted((store_dir / "manifests").rglob("*.json"))
    started = time.monotonic()
    res = reproduce(store_dir, *ONE_SEED, "--jobs", "2")
    assert res.code == 0, res.stderr
    assert [(c["name"], c["status"], c["seconds"]) for c in res.json["cells"]] == \
        [(c["name"], "done", 0.0) for c in first["cells"]]
    assert res.json["report"] == first["report"]
    assert sorted((store_dir / "manifests").rglob("*.json")) == manifests  # nothing new in the store
    assert res.json["seconds"] < 5 and time.monotonic() - started < 60  # no subcommand was started
    dry = reproduce(store_dir, *ONE_SEED, "--dry-run")
    assert dry.code == 0 and dry.json["dry_run"] and dry.json["report"] == first["report"]
    assert {c["status"] for c in dry.json["cells"]} == {"done"}
    # a bigger grid on the same store: the finished cells are done, the new ones pending
    more = reproduce(store_dir, *GRID, "--seeds", "2", "--dry-run")
    status = {c["name"]: c["status"] for c in more.json["cells"]}
    assert status["train-assistant/straightaway/pass-stay/dreamer/seed0"] == "done"
    assert status["train-assistant/straightaway/pass-stay/dreamer/seed1"] == "pending"
    assert status["eval/straightaway/pass-stay"] == status["report"] == "pending"
    seed1 = by_name(more.json)["train-assistant/straightaway/pass-stay/dreamer/seed1"]
    assert seed1["argv"][7:11] == ["--humans", by_name(first)["train-humans/straightaway/pass/seed0"]["id"],
                                   "--humans", by_name(first)["train-humans/straightaway/stay/seed0"]["id"]]


def _processes_using(path: Path) -> list[int]:
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if str(path) in cmdline and "d2a_cli" in cmdline:
            found.append(int(proc.name))
    return found


def test_resume_after_sigkill_of_the_driver(local_run, tmp_path):
    store_dir = copy_store(local_run[0], tmp_path)
    longer = ("--set", "train-assistant/*/seed1:assistant.env_steps=480",
              "--set", "train-assistant/*/seed1:assistant.checkpoints=4")
    args = [*GRID, "--seeds", "2", *longer, "--jobs", "1"]
    cmd = [sys.executable, "-m", "d2a_cli", "reproduce", *args, "--json", "--store", str(store_dir)]
    driver = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline:  # the seed-1 assistant has stored its first checkpoint
            if list((store_dir / "runs").glob("*/state.pt")):
                break
            assert driver.poll() is None, "the driver ended before the cell was killed"
            time.sleep(0.2)
        else:
            pytest.fail("no checkpoint appeared")
        assert _processes_using(store_dir)  # the cell's subcommand is running
    finally:
        driver.send_signal(signal.SIGKILL)
        driver.wait(timeout=30)
    # the cell's subprocess dies with the driver: no orphan goes on writing to the store
    deadline = time.monotonic() + 20
    while _processes_using(store_dir) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _processes_using(store_dir) == []

    res = reproduce(store_dir, *args)
    assert res.code == 0, res.stdout + res.stderr
    status = {c["name"]: c["status"] for c in res.json["cells"]}
    assert status == {"make-track/straightaway": "done", "train-humans/straightaway/pass/seed0": "done",
                      "train-humans/straightaway/stay/seed0": "done",
                      "train-assistant/straightaway/pass-stay/dreamer/seed0": "done",
                      "train-assistant/straightaway/pass-stay/dreamer/seed1": "ran",
                      "eval/straightaway/pass-stay": "ran", "intent-swap/straightaway/pass-stay": "ran",
                      "report": "ran"}
    seed1 = by_name(res.json)["train-assistant/straightaway/pass-stay/dreamer/seed1"]
    record = json.loads(next(p for p in (store_dir / "reproduce" / "cells").glob("*.json")
                             if json.loads(p.read_text())["name"] == seed1["name"]).read_text())
    trained = record["result"]["assistants"][0]
    assert trained["resumed_from_env_step"] is not None and trained["resumed_from_env_step"] >= 120
    assert [c["env_step"] for c in trained["checkpoints"]] == [120, 240, 360, 480]
    store = Store(store_dir)
    assert store.resolve("eval/straightaway/pass-stay/dreamer/seed1")
    assert res.json["report"] == store.resolve("report/latest")
    assert store.verify() == []


def test_a_failing_cell_is_reported_while_independent_cells_finish(local_run, tmp_path):
    store_dir = copy_store(local_run[0], tmp_path)
    res = reproduce(store_dir, *GRID, "--seeds", "2", "--jobs", "2",
                    "--set", "train-assistant/*/seed0:assistant.num_envs=0")
    assert res.code == 1
    cells = by_name(res.json)
    failed = cells["train-assistant/straightaway/pass-stay/dreamer/seed0"]
    assert failed["status"] == "failed" and "assistant.num_envs" in failed["error"]
    assert "attempts" not in failed  # a config error is not retried
    assert cells["train-assistant/straightaway/pass-stay/dreamer/seed1"]["status"] == "ran"
    assert cells["make-track/straightaway"]["status"] == "done"
    assert cells["train-humans/straightaway/pass/seed0"]["status"] == "done"
    for name in ("eval/straightaway/pass-stay", "intent-swap/straightaway/pass-stay", "report"):
        assert cells[name]["status"] == "blocked"
    assert "train-assistant/straightaway/pass-stay/dreamer/seed0" in cells["eval/straightaway/pass-stay"]["error"]
    assert res.json["report"] is None
    assert Store(store_dir).resolve("assistants/straightaway/pass-stay/dreamer/seed1") == \
        cells["train-assistant/straightaway/pass-stay/dreamer/seed1"]["id"]


def test_the_filesystem_probe_names_what_fails(tmp_path, monkeypatch):
    assert grid_run.probe_filesystem(str(tmp_path / "probe")) == []
    # a lock that another process holds must not be granted here
    with grid_run.held_probe_lock(str(tmp_path)) as held:
        assert grid_run.probe_filesystem(str(tmp_path / "probe"), held) == []
    monkeypatch.setattr(os, "link", lambda a, b: (_ for _ in ()).throw(OSError(1, "Operation not permitted")))
    assert any("hard links" in p for p in grid_run.probe_filesystem(str(tmp_path / "probe")))


# --------------------------------------------------------------------------- Ray
def _files(store: Store, art_id: str) -> dict[str, str]:
    return {name: f["sha256"] for name, f in store.get(art_id).manifest["files"].items()}


def test_the_same_grid_on_a_local_ray_cluster(local_run, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'd2a[ray]')")
    local_dir, local, _ = local_run
    res = reproduce(tmp_path / "store", *ONE_SEED, "--executor", "ray", "--jobs", "2")
    assert res.code == 0, res.stdout + res.stderr
    assert [(c["name"], c["status"]) for c in res.json["cells"]] == [(c["name"], "ran") for c in local["cells"]]
    a, b = Store(local_dir), Store(tmp_path / "store")
    la, ra = by_name(local), by_name(res.json)
    # the deterministic artifacts have the same ids: track, opponent replays, every human checkpoint
    assert ra["make-track/straightaway"]["id"] == la["make-track/straightaway"]["id"]
    assert a.refs()["track/straightaway/opponents/0"] == b.refs()["track/straightaway/opponents/0"]
    for intent in ("pass", "stay"):
        name = f"train-humans/straightaway/{intent}/seed0"
        pa, pb = (s.read_json(o[name]["id"], "population.json") for s, o in ((a, la), (b, ra)))
        assert [c["id"] for c in pa["checkpoints"]] == [c["id"] for c in pb["checkpoints"]]
        assert pa["expert"] == pb["expert"]
    # every cell's artifact is the same artifact (timings are kept out of hashed files)
    def ids(cells):
        return {n: (c.get("id"), c.get("ids")) for n, c in cells.items()}

    assert ids(ra) == ids(la)
    name = "train-assistant/straightaway/pass-stay/dreamer/seed0"
    assert _files(a, la[name]["id"]) == _files(b, ra[name]["id"])  # the assistant's weights, panel, steps
    ea, eb = (s.read_json("eval/straightaway/pass-stay/dreamer/seed0", "eval.json")["result"] for s in (a, b))
    assert [h["delta"] for h in ea["humans"]] == [h["delta"] for h in eb["humans"]]
    sa, sb = (np.load(io.BytesIO(s.read_bytes("eval/straightaway/pass-stay/dreamer/seed0", "steps.npz")))
              for s in (a, b))
    assert all(np.array_equal(sa[k], sb[k]) for k in sa.files)
    assert b.resolve("report/latest") == res.json["report"]


def test_a_stop_that_lands_while_a_cell_launches_stops_that_cell(tmp_path, monkeypatch):
    """Ctrl-C (terminate_cells) arriving between a cell's launch and its registration must still
    reach the cell: it ends within seconds, not when its 30 s command would have."""
    import threading

    from d2a_core.pipelines import grid_run

    real_popen = grid_run.subprocess.Popen

    def launching(cmd, **kwargs):
        threading.Thread(target=grid_run.terminate_cells).start()
        time.sleep(0.3)  # the stop lands while this cell is being launched
        return real_popen(["sleep", "30"], **kwargs)

    monkeypatch.setattr(grid_run.subprocess, "Popen", launching)
    spec = grid_run.CellSpec(name="cell", kind="make-track", argv=["make-track", "straightaway"], key="stop-test",
                             store=str(tmp_path / "store"))
    started = time.monotonic()
    try:
        outcome = grid_run.run_cell(spec)
    finally:
        grid_run._STOPPING.clear()
    assert time.monotonic() - started < 10
    assert outcome["status"] == "failed"
