"""SIGKILL at random points of `make-track` and of a smoke `train-humans`: nothing corrupt or
partial is ever visible, a rerun finishes with the same ids, and a killed training resumes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

from fault_helpers import REPO, assert_consistent, d2a, rng, run

from d2a_core.artifacts import Store

KILLS = int(os.environ.get("D2A_FAULT_KILLS", "12"))
# four opponents make the write phase long enough for kills to land between replays
TRACK_ARGS = ("make-track", "straightaway", "--preset", "smoke", "--set", "opponents.count=4", "--json")


def _count(store: Path) -> int:
    """Manifests on disk (cheap enough to poll while a writer runs)."""
    return len(list((store / "manifests").glob("??/*.json")))


def _clean_run_ids(tmp_path: Path) -> dict:
    ref = tmp_path / "reference"
    res = run(*TRACK_ARGS, store=ref)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_sigkill_make_track_at_random_points(tmp_path):
    expected = _clean_run_ids(tmp_path)
    store = tmp_path / "store"
    pick = rng("make-track-kills")
    landed = {"before any artifact": 0, "between artifacts": 0, "after the last artifact": 0}
    for _ in range(KILLS):
        before = _count(store)
        proc = subprocess.Popen(d2a(*TRACK_ARGS, store=store), cwd=REPO, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        # kill points spread over the whole write phase: wait for a random number of new artifacts
        # (0: during start-up or the first write), then a random moment more
        target = before + pick.randint(0, 4)
        deadline = time.monotonic() + 120
        while proc.poll() is None and _count(store) < target and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(pick.uniform(0.0, 0.3))
        proc.send_signal(signal.SIGKILL)
        _, err = proc.communicate()
        assert "Traceback" not in err
        assert_consistent(store)
        after = len(Store(store).list())
        if proc.returncode == 0:
            landed["after the last artifact"] += 1
        elif after > before:
            landed["between artifacts"] += 1
        else:
            landed["before any artifact"] += 1
        if after == 5:  # a full set was stored by an earlier run: start again from empty
            res = run("artifacts", "gc", "--json", store=store)
            assert res.returncode == 0, res.stderr
            for alias in list(Store(store).refs()):
                Store(store).untag(alias)
            assert run("artifacts", "gc", "--json", store=store).returncode == 0
    print(f"make-track kills: {landed}")
    res = run(*TRACK_ARGS, store=store)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert result["id"] == expected["id"] and [o["id"] for o in result["opponents"]] == \
        [o["id"] for o in expected["opponents"]]
    assert_consistent(store)
    report = json.loads(run("artifacts", "gc", "--json", store=store).stdout)
    assert report["artifacts"] == [] and not any((store / "tmp").iterdir())


def test_sigkill_train_humans_then_resume(tmp_path):
    store = tmp_path / "store"
    assert run("make-track", "straightaway", "--preset", "smoke", "--json", store=store).returncode == 0
    args = ("train-humans", "--intent", "stay", "--track", "straightaway", "--preset", "smoke",
            "--set", "humans.env_steps=360", "--set", "humans.checkpoints=3", "--json")
    pick = rng("train-humans-kills")
    kills = 0
    for _ in range(2):
        proc = subprocess.Popen(d2a(*args, store=store), cwd=REPO, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        view = Store(store)
        start = len(view.list("human"))
        deadline = time.monotonic() + 240
        while len(view.list("human")) == start and proc.poll() is None:  # wait for a new checkpoint
            assert time.monotonic() < deadline
            time.sleep(0.1)
        time.sleep(pick.uniform(0.0, 1.5))  # then kill somewhere in the next stretch of training
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.wait()
        assert_consistent(store)
        # once train-humans records its run holds, a gc here must not eat what the resume needs
        if list((store / "runs").glob("*/holds.json")):
            assert run("artifacts", "gc", "--json", store=store).returncode == 0
    res = run(*args, store=store)
    assert res.returncode == 0, res.stderr
    pop = json.loads(res.stdout)["populations"][0]
    assert [c["env_step"] for c in pop["checkpoints"]] == [120, 240, 360]
    assert kills == 0 or pop["resumed_from_env_step"] is not None or pop["cached"]
    assert_consistent(store)
    print(f"train-humans kills: {kills}")
