"""The CLI under failures: every case exits 0/1/2/3 as documented, names what is
at fault, and prints no Python traceback."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from d2a_core.artifacts import Store

from d2a_test_helpers import REPO, kill_after_state_saved, run_cli

SMOKE = ("--preset", "smoke")


def _no_traceback(res) -> None:
    assert "Traceback" not in res.stderr, res.stderr


def cli(*args, store=None, **kw):
    res = run_cli(*args, store=store, **kw)
    _no_traceback(res)
    return res


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A store with the smoke straightaway (2 opponents), built once; tests work on copies."""
    store = tmp_path_factory.mktemp("built") / "store"
    res = run_cli("make-track", "straightaway", *SMOKE, "--json", store=store)
    assert res.code == 0, res.stderr
    return store


@pytest.fixture
def store(built, tmp_path):
    copy = tmp_path / "store"
    shutil.copytree(built, copy, symlinks=True)
    return copy


def _flip(path: Path, offset: int) -> None:
    os.chmod(path, 0o644)
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def _manifest(store: Path, art_id: str) -> Path:
    return store / "manifests" / art_id[:2] / f"{art_id}.json"


# --------------------------------------------------------------------------- 1. gc beside a running job
def test_gc_while_train_humans_runs_keeps_its_checkpoints(store):
    """The issue's reproduction: `train-humans ... & sleep; d2a artifacts gc; wait` must succeed."""
    cmd = [sys.executable, "-m", "d2a_cli", "train-humans", "--intent", "pass", "--track", "straightaway", *SMOKE,
           "--seed", "7", "--set", "humans.checkpoints=3", "--json", "--store", str(store)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    view = Store(store)
    deadline = time.monotonic() + 240
    while not view.list("human"):  # the first checkpoint exists and has no alias yet
        assert proc.poll() is None and time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.2)
    gcs = []
    while proc.poll() is None:
        gcs.append(cli("artifacts", "gc", "--json", store=store))
        time.sleep(0.3)
    out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert all(g.code == 0 for g in gcs) and gcs
    assert not any(g.json["artifacts"] for g in gcs), "gc removed something the run needed"
    pop = json.loads(out)["populations"][0]
    assert len(pop["checkpoints"]) == 3
    assert Store(store).verify() == []


def test_a_killed_run_state_survives_gc_and_resumes(store):
    args = ["train-humans", "--intent", "stay", "--track", "straightaway", *SMOKE, "--set", "humans.checkpoints=3",
            "--json"]
    kill_after_state_saved(args, store)
    assert cli("artifacts", "gc", "--json", store=store).code == 0
    res = cli(*args, store=store)
    assert res.code == 0, res.stderr
    assert res.json["populations"][0]["resumed_from_env_step"] is not None


# --------------------------------------------------------------------------- 2. bad alias files
@pytest.mark.parametrize("damage", ["bytes", "directory"])
def test_a_bad_alias_file_is_reported_and_other_commands_work(store, damage):
    ref = store / "refs" / "track" / "straightaway" / "opponents" / "1.ref"
    if damage == "bytes":
        ref.write_bytes(bytes(range(200, 256)) + b"\x00" * 8)
    else:
        ref.unlink()
        ref.mkdir()
    res = cli("artifacts", "verify", "--json", store=store)
    assert res.code == 3 and [p["alias"] for p in res.json["problems"]] == ["track/straightaway/opponents/1"]
    assert "track/straightaway/opponents/1" in res.stderr
    assert cli("artifacts", "ls", "--json", store=store).code == 0
    assert cli("artifacts", "show", "track/straightaway", "--json", store=store).code == 0
    res = cli("artifacts", "show", "track/straightaway/opponents/1", "--json", store=store)
    assert res.code == 3 and "track/straightaway/opponents/1" in res.json["error"]["message"]
    res = cli("artifacts", "gc", "--json", store=store)
    assert res.code == 3 and "opponents/1" in res.json["error"]["message"]
    res = cli("artifacts", "verify", "--repair", "--json", store=store)
    assert res.code == 0 and res.json["repaired"] == 1
    assert cli("artifacts", "verify", store=store).code == 0
    assert cli("artifacts", "gc", "--json", store=store).code == 0


# --------------------------------------------------------------------------- 3. reads check hashes
def test_a_flipped_blob_is_refused_on_read_and_a_rebuild_repairs_it(store, tmp_path):
    view = Store(store)
    replay = view.get("track/straightaway/opponents/0")
    blob = store / "objects" / replay.files["replay.mcap"]["sha256"][:2] / replay.files["replay.mcap"]["sha256"]
    _flip(blob, 4000)
    res = cli("artifacts", "export", "track/straightaway/opponents/0", str(tmp_path / "out"), "--json", store=store)
    assert res.code == 3 and replay.id[:12] in res.json["error"]["message"]
    assert not (tmp_path / "out" / "replay.mcap").exists()
    res = cli("train-humans", "--intent", "pass", "--track", "straightaway", *SMOKE, "--json", store=store)
    assert res.code == 3 and replay.id[:12] in res.json["error"]["message"]
    track = view.get("track/straightaway")
    tblob = store / "objects" / track.files["track.npz"]["sha256"][:2] / track.files["track.npz"]["sha256"]
    _flip(tblob, 200)
    res = cli("train-humans", "--intent", "pass", "--track", "straightaway", *SMOKE, "--json", store=store)
    assert res.code == 3 and track.id[:12] in res.json["error"]["message"]
    assert cli("make-track", "straightaway", *SMOKE, "--json", store=store).code == 0
    assert cli("artifacts", "verify", store=store).code == 0  # the rebuild replaced both blobs


# --------------------------------------------------------------------------- 4. truncated manifests
def test_truncated_manifests_are_all_listed_and_verify_repair_restores_the_store(store):
    view = Store(store)
    replays = [view.resolve(f"track/straightaway/opponents/{i}") for i in range(2)]
    for rid in replays:
        path = _manifest(store, rid)
        os.chmod(path, 0o644)
        path.write_bytes(path.read_bytes()[:100])
    res = cli("artifacts", "verify", "--json", store=store)
    assert res.code == 3 and {p["artifact"] for p in res.json["problems"]} >= set(replays)
    res = cli("artifacts", "ls", "--kind", "track", "--json", store=store)
    assert res.code == 0 and len(res.json["artifacts"]) == 1 and sorted(res.json["unreadable"]) == sorted(replays)
    res = cli("artifacts", "gc", "--json", store=store)
    assert res.code == 3 and "verify --repair" in res.json["error"]["message"]
    res = cli("artifacts", "verify", "--repair", "--json", store=store)
    assert res.code == 0, res.stderr
    assert cli("artifacts", "gc", "--json", store=store).code == 0
    assert cli("make-track", "straightaway", *SMOKE, "--json", store=store).code == 0
    res = cli("artifacts", "verify", "--json", store=store)
    assert res.code == 0 and res.json["ok"]


# --------------------------------------------------------------------------- 5. partial make-track
def test_an_incomplete_replay_set_is_never_used(store):
    view = Store(store)
    track_id = view.resolve("track/straightaway")
    gone = view.resolve("track/straightaway/opponents/1")
    # what a kill between the two replays leaves: the track and replay 0, no aliases
    _manifest(store, gone).unlink()
    shutil.rmtree(store / "refs")
    res = cli("train-humans", "--intent", "pass", "--track", track_id[:12], *SMOKE, "--json", store=store)
    assert res.code == 2
    message = res.json["error"]["message"]
    assert "1 of 2" in message and "make-track" in message


# --------------------------------------------------------------------------- 6. unusable stores
def test_a_store_path_that_is_a_file_or_holds_a_file_for_objects(tmp_path):
    as_file = tmp_path / "file"
    as_file.write_text("x")
    for args in (("artifacts", "verify"), ("artifacts", "ls"), ("artifacts", "gc", "--dry-run")):
        res = cli(*args, "--json", store=as_file)
        assert res.code == 1 and str(as_file) in res.json["error"]["message"], args
    objects_file = tmp_path / "store"
    objects_file.mkdir()
    (objects_file / "objects").write_text("x")
    res = cli("make-track", "straightaway", *SMOKE, "--json", store=objects_file)
    assert res.code == 1 and "objects" in res.json["error"]["message"]


def _can_mount() -> bool:
    if not shutil.which("unshare") or os.geteuid() != 0:
        return False
    probe = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                           capture_output=True)
    return probe.returncode == 0


def _in_mount(setup: str, *args: str, store: Path):
    """Run the CLI in a private mount namespace after `setup` (a read-only bind, a tiny tmpfs)."""
    line = " ".join(f"'{a}'" for a in [sys.executable, "-m", "d2a_cli", *args, "--store", str(store)])
    proc = subprocess.run(["unshare", "-m", "sh", "-c", f"{setup} && exec {line}"], capture_output=True, text=True,
                          cwd=REPO, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


@pytest.mark.skipif(not _can_mount(), reason="needs root and unshare to mount a read-only or full filesystem")
def test_a_read_only_store(store):
    ro = f"mount --bind {store} {store} && mount -o remount,ro,bind {store}"
    proc = _in_mount(ro, "artifacts", "gc", "--dry-run", "--json", store=store)
    assert proc.returncode == 0, proc.stderr
    assert _in_mount(ro, "artifacts", "verify", store=store).returncode == 0
    for args in (("artifacts", "tag", "track/straightaway", "mine"), ("artifacts", "gc"),
                 ("make-track", "straightaway", "--preset", "smoke", "--seed", "3")):
        proc = _in_mount(ro, *args, "--json", store=store)
        assert proc.returncode == 1, (args, proc.stderr)
        assert "Read-only file system" in proc.stdout and str(store) in proc.stdout


@pytest.mark.skipif(not _can_mount(), reason="needs root and unshare to mount a read-only or full filesystem")
def test_a_full_disk(tmp_path):
    store = tmp_path / "full"
    store.mkdir()
    proc = _in_mount(f"mount -t tmpfs -o size=96k tmpfs {store}", "make-track", "straightaway", *SMOKE, "--json",
                     store=store)
    assert proc.returncode == 1 and "No space left on device" in proc.stdout


@pytest.mark.skipif(not _can_mount(), reason="needs root and unshare to mount a read-only or full filesystem")
def test_a_full_disk_while_a_run_saves_its_state(tmp_path):
    """A run directory on a 64 KiB tmpfs and a state of 1 MB: the error names the state's path and
    the OS reason, no temp file stays behind, and the previous state is untouched."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    script = (
        "import sys, torch; from pathlib import Path; from d2a_core.training.run_state import save_atomic\n"
        "from d2a_core.errors import StoreError\n"
        f"path = Path({str(run_dir)!r}) / 'state.pt'\n"
        "save_atomic({'small': torch.zeros(8)}, path)\n"
        "try:\n    save_atomic({'big': torch.zeros(250_000)}, path)\nexcept StoreError as exc:\n    print(exc)\n"
        "print(sorted(p.name for p in path.parent.iterdir()))\n"
        "from d2a_core.training.run_state import load_checked\n"
        "print(sorted(load_checked(path, 'cpu', 'state', '')))\n")
    proc = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {run_dir} && "
                           f"exec {sys.executable} -c \"$0\"", script], capture_output=True, text=True, cwd=REPO,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    message, listing, kept = proc.stdout.splitlines()[:3]
    assert "cannot save the run state" in message and "No space left on device" in message
    assert str(run_dir / "state.pt") in message and "enforce fail" not in message
    assert listing == "['state.pt']" and kept == "['small']"


# --------------------------------------------------------------------------- 7. NaN and infinity
def test_non_finite_config_values_are_usage_errors(store):
    for value in ("reward.c_pass=.nan", "dreamer.model_lr=.inf", "opponents.pace_max=-.inf", "reward.c_pass=1e999"):
        res = cli("config", "show", *SMOKE, "--set", value, "--json")
        assert res.code == 2, value
        err = json.loads(res.stdout)["error"]["message"]  # valid JSON, no bare NaN
        assert value.split("=")[0] in err and "finite" in err
    res = cli("make-track", "straightaway", *SMOKE, "--set", "vehicle.mass_kg=.nan", "--json", store=store)
    assert res.code == 2 and "vehicle.mass_kg" in res.json["error"]["message"]


# --------------------------------------------------------------------------- 8. track inputs
def _write_csv(path: Path, x, y, w=4.0, z=None) -> Path:
    cols = "x_m, y_m, w_tr_right_m, w_tr_left_m" + (", z_m" if z is not None else "")
    rows = [f"{float(a)!r},{float(b)!r},{w},{w}" + (f",{float(c)!r}" if z is not None else "") for a, b, c in
            zip(x, y, z if z is not None else x)]
    path.write_text(f"# {cols}\n" + "\n".join(rows) + "\n")
    return path


def test_bad_track_inputs_exit_2_naming_the_file_and_where(store, tmp_path):
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    cases = {
        "figure8.csv": (_write_csv(tmp_path / "figure8.csv", 100 * np.sin(t), 50 * np.sin(2 * t)), "crosses itself"),
        "huge.csv": (_write_csv(tmp_path / "huge.csv", [i * (1e300 if i == 5 else 10.0) for i in range(20)],
                                [0.0] * 20), "huge.csv:7"),
        "climb.csv": (_write_csv(tmp_path / "climb.csv", [10.0 * i for i in range(40)], [0.0] * 40,
                                 z=[1e6 if i == 20 else 0.0 for i in range(40)]), "climbs"),
        "tight.csv": (_write_csv(tmp_path / "tight.csv", np.arange(300.0), 3 * np.sin(np.arange(300.0) / 3), w=1.5),
                      "bend at s="),
    }
    for name, (path, expected) in cases.items():
        res = cli("make-track", str(path), *SMOKE, "--json", store=store)
        assert res.code == 2, (name, res.stderr)
        assert name in res.json["error"]["message"] and expected in res.json["error"]["message"], res.json
    spec = (REPO / "tracks" / "straightaway.yaml").read_text()
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text(spec.replace("sample_spacing_m: 0.5", "sample_spacing_m: 1.0e-9"))
    res = cli("make-track", str(tiny), *SMOKE, "--json", store=store)
    assert res.code == 2 and "sample_spacing_m" in res.json["error"]["message"]
    res = cli("make-track", "straightaway", *SMOKE, "--set", "tracks.csv.fine_spacing_m=1e-9", "--json", store=store)
    assert res.code in (0, 2)  # a spec track does not use the CSV grid; it must not blow up either
    junk = tmp_path / "junk.yaml"
    junk.write_bytes(bytes(range(256)))
    res = cli("config", "show", "--config", str(junk), "--json")
    assert res.code == 2 and "junk.yaml" in res.json["error"]["message"]
    existing = tmp_path / "a-file"
    existing.write_text("x")
    res = cli("artifacts", "export", "track/straightaway", str(existing), "--json", store=store)
    assert res.code == 2 and "a-file" in res.json["error"]["message"]


# --------------------------------------------------------------------------- 9. messages
def test_messages_name_what_the_user_typed(store, tmp_path):
    view = Store(store)
    ids = [a.id for a in view.list()]
    # find two ids sharing a 4-character prefix by adding small artifacts (deterministic ids)
    seen = {i[:4]: i for i in ids}
    for n in range(3000):
        art = view.put("blob", {"f": str(n).encode()})
        if art.id[:4] in seen:
            break
        seen[art.id[:4]] = art.id
    res = cli("train-humans", "--intent", "pass", "--track", art.id[:4], *SMOKE, "--json", store=store)
    assert res.code == 2 and "ambiguous" in res.json["error"]["message"]
    assert "━" not in res.stderr  # no progress bar before an argument error
    res = cli("artifacts", "show", art.id[:3], "--json", store=store)
    assert res.code == 2 and "at least 4 characters" in res.json["error"]["message"]
    # a dangling alias is named by the alias typed
    view.untag("track/straightaway")
    (store / "refs" / "track" / "straightaway.ref").write_text("ab" * 32 + "\n")
    res = cli("train-humans", "--intent", "pass", "--track", "track/straightaway", *SMOKE, "--json", store=store)
    assert res.code == 3 and "'track/straightaway'" in res.json["error"]["message"]
    # a name that cannot become an alias is refused before anything is written
    empty = tmp_path / "empty"
    for name in ("..", "-x", ".hidden"):
        res = cli("make-track", "straightaway", *SMOKE, f"--name={name}", "--json", store=empty)
        assert res.code == 2 and name in res.json["error"]["message"]
    assert not (empty / "manifests").exists() or not any((empty / "manifests").rglob("*.json"))
