"""The store under faults, through its Python API: gc roots, bad refs, hash-checked
reads, unreadable manifests and their repair, unusable store paths."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from d2a_core.artifacts import Store
from d2a_core.errors import IntegrityError, NotFoundError, StoreError


def _flip(path: Path, offset: int = -1) -> None:
    """Flip one bit of a stored (read-only) file in place."""
    os.chmod(path, 0o644)
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def _manifest(store_dir: Path, art_id: str) -> Path:
    return store_dir / "manifests" / art_id[:2] / f"{art_id}.json"


# --------------------------------------------------------------------------- 1. gc roots
HOLDER = textwrap.dedent(
    """
    import sys, time
    from d2a_core.artifacts import Store
    store = Store(sys.argv[1])
    with store.lease():
        art = store.put("human", {"agent.pt": b"checkpoint nobody has aliased yet"})
        print(art.id, flush=True)
        sys.stdin.readline()          # hold until the test says so
    """
)


def test_gc_keeps_what_a_live_process_leases_and_drops_the_lease_when_it_dies(store_dir):
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(store_dir)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        art_id = proc.stdout.readline().strip()
        store = Store(store_dir)
        report = store.gc()
        assert report.artifacts == [] and store.get(art_id).kind == "human"
        assert any(art_id in ids for ids in report.held.values())
    finally:
        proc.kill()
        proc.wait()
    # the kernel released the dead process's lock: its lease is stale, and what it held is garbage
    report = store.gc()
    assert report.artifacts == [art_id] and len(report.stale_leases) == 1
    assert not any((store_dir / "leases").iterdir())


def test_gc_keeps_what_a_run_state_holds_until_released(store_dir):
    store = Store(store_dir)
    track = store.put("track", {"t": b"track"})
    ckpt = store.put("human", {"agent.pt": b"ckpt"}, inputs=[track.id])
    store.hold_run("runkey1", [ckpt.id])
    holds = json.loads((store_dir / "runs" / "runkey1" / "holds.json").read_text())
    assert holds == {"format": 1, "artifacts": [ckpt.id]}
    report = store.gc()
    assert report.artifacts == [] and report.held == {"run runkey1": [ckpt.id]}
    assert store.read_bytes(ckpt.id, "agent.pt") == b"ckpt"  # and its input is kept with it
    store.release_run("runkey1")
    assert sorted(store.gc().artifacts) == sorted([track.id, ckpt.id])
    with pytest.raises(NotFoundError):
        store.hold_run("runkey1", [ckpt.id])  # holding what is gone is an error, not a silent promise


def test_gc_removes_nothing_when_a_root_is_unreadable_and_repair_unblocks_it(store_dir):
    store = Store(store_dir)
    orphan = store.put("ckpt", {"c": b"orphan"})
    held = store.put("ckpt", {"c": b"held"})
    store.hold_run("k", [held.id])
    (store_dir / "runs" / "k" / "holds.json").write_bytes(b"\x00garbage")
    with pytest.raises(IntegrityError, match="holds.json"):
        store.gc()
    assert {a.id for a in store.list()} == {orphan.id, held.id}
    problems = store.verify(repair=True)
    assert [p.path for p in problems if p.repaired] == [str(store_dir / "runs" / "k" / "holds.json")]
    assert sorted(store.gc().artifacts) == sorted([orphan.id, held.id])


def test_tag_checks_under_the_lock_that_the_artifact_still_exists(store_dir, monkeypatch):
    """make-track beside gc once left a dangling track alias: gc ran between lookup and tag."""
    store = Store(store_dir)
    art = store.put("track", {"t": b"x"})
    real_get = Store.get

    def get_then_collected(self, ref):
        found = real_get(self, ref)
        _manifest(store_dir, art.id).unlink()  # what a gc in another process did right after the lookup
        return found

    monkeypatch.setattr(Store, "get", get_then_collected)
    with pytest.raises(NotFoundError):
        store.tag(art.id, "track/x")
    monkeypatch.undo()
    assert store.refs() == {}


# --------------------------------------------------------------------------- 2. bad refs
@pytest.mark.parametrize("damage", ["random bytes", "directory", "flipped"])
def test_one_bad_alias_file_is_reported_and_the_rest_works(store_dir, damage):
    store = Store(store_dir)
    good = store.put("track", {"t": b"good"})
    store.tag(good.id, "track/good")
    bad = store.put("track", {"t": b"bad"})
    store.tag(bad.id, "track/bad")
    ref = store_dir / "refs" / "track" / "bad.ref"
    if damage == "random bytes":
        ref.write_bytes(os.urandom(64) + b"\xff")
    elif damage == "directory":
        ref.unlink()
        ref.mkdir()
    else:
        _flip(ref, 0)  # still looks like text: only an exact id + newline is accepted
    refs = store.refs()
    assert refs["track/good"] == good.id and refs.get("track/bad") != bad.id
    assert len(store.list()) == 2 and store.get("track/good").id == good.id
    problems = store.verify()
    assert [p.alias for p in problems] == ["track/bad"]
    with pytest.raises(IntegrityError, match="track/bad"):
        store.resolve("track/bad")
    with pytest.raises(IntegrityError, match="track/bad"):
        store.gc()  # it cannot know what the alias protected (a flipped id points nowhere)
    store.verify(repair=True)
    assert store.verify() == [] and store.gc().artifacts == [bad.id]


# --------------------------------------------------------------------------- 3. hash-checked reads
def test_reads_check_hashes_and_a_rebuild_replaces_a_corrupt_blob(store_dir, tmp_path):
    store = Store(store_dir)
    art = store.put("replay", {"replay.mcap": b"lap data " * 1000})
    blob = store.path(art.id, "replay.mcap")
    _flip(blob, 100)
    fresh = Store(store_dir)  # another process: nothing verified yet
    with pytest.raises(IntegrityError, match="does not match its hash"):
        fresh.path(art.id, "replay.mcap")
    with pytest.raises(IntegrityError):
        fresh.export(art.id, tmp_path / "out")
    assert not (tmp_path / "out" / "replay.mcap").exists()  # no corrupted copy left behind
    again = fresh.put("replay", {"replay.mcap": b"lap data " * 1000})
    assert again.id == art.id and fresh.verify() == []
    assert fresh.path(art.id, "replay.mcap").read_bytes() == b"lap data " * 1000


def test_a_flip_anywhere_in_a_manifest_is_refused_on_read(store_dir):
    store = Store(store_dir)
    art = store.put("track", {"t": b"x"}, labels={"name": "oval"})
    path = _manifest(store_dir, art.id)
    created = path.read_bytes().index(b'"created"') + 14  # a digit of the (unhashed) timestamp
    _flip(path, created)
    with pytest.raises(IntegrityError, match=art.id[:12]):
        Store(store_dir).get(art.id)
    assert [p.artifact for p in Store(store_dir).verify()] == [art.id]


def test_every_bit_of_a_manifest_is_covered(store_dir):
    """Each single-bit flip, at every byte, is refused: also in the name of the checksum field,
    which once made a damaged manifest pass for an older one without a checksum."""
    store = Store(store_dir)
    art = store.put("track", {"t": b"x"}, labels={"name": "oval"})
    path = _manifest(store_dir, art.id)
    original = path.read_bytes()
    key = original.rindex(b'"sha256":"')  # the top-level checksum (sorted last), not a file's hash
    offsets = list(range(key, key + 10)) + list(range(0, len(original), max(1, len(original) // 40)))
    for offset in offsets:
        for bit in range(8):
            damaged = bytearray(original)
            damaged[offset] ^= 1 << bit
            os.chmod(path, 0o644)
            path.write_bytes(bytes(damaged))
            with pytest.raises(IntegrityError):
                Store(store_dir).get(art.id)
    path.write_bytes(original)
    assert Store(store_dir).get(art.id).id == art.id


# --------------------------------------------------------------------------- 4. unreadable manifests
def test_truncated_manifests_are_all_listed_and_repair_restores_a_working_store(store_dir):
    store = Store(store_dir)
    track = store.put("track", {"t": b"track"})
    replays = [store.put("replay", {"r": f"replay {i}".encode()}, inputs=[track.id]) for i in range(3)]
    store.tag(track.id, "track/t")
    for i, rep in enumerate(replays):
        store.tag(rep.id, f"track/t/opponents/{i}")
    for rep in replays[:2]:
        path = _manifest(store_dir, rep.id)
        os.chmod(path, 0o644)
        path.write_bytes(path.read_bytes()[:40])
    assert [a.id for a in store.list("track")] == [track.id]  # one bad replay does not hide the track
    unreadable: list[str] = []
    assert [a.id for a in store.list("replay", unreadable=unreadable)] == [replays[2].id]
    assert sorted(unreadable) == sorted(r.id for r in replays[:2])
    problems = store.verify()
    assert {p.artifact for p in problems if p.artifact} == {r.id for r in replays[:2]}
    with pytest.raises(IntegrityError):
        store.gc()  # aliases reach them: what they need cannot be known
    repaired = store.verify(repair=True)
    assert all(p.repaired for p in repaired)
    assert store.verify() == []
    assert store.gc().artifacts == []
    assert (store_dir / "quarantine").is_dir()
    # a rebuild brings them back under the same ids
    again = store.put("replay", {"r": b"replay 0"}, inputs=[track.id])
    assert again.id == replays[0].id and store.verify() == []


# --------------------------------------------------------------------------- 6. unusable store paths
def test_a_store_path_that_is_a_file_is_an_error_not_an_empty_store(tmp_path):
    path = tmp_path / "store"
    path.write_text("not a store")
    store = Store(path)
    for call in (store.list, store.verify, store.gc, lambda: store.put("x", {"a": b"1"})):
        with pytest.raises(StoreError, match="not a directory"):
            call()


def test_objects_being_a_file_names_the_path(store_dir):
    store_dir.mkdir()
    (store_dir / "objects").write_text("oops")
    with pytest.raises(StoreError, match="objects"):
        Store(store_dir).put("x", {"a": b"1"})


def test_a_failing_disk_leaves_the_store_consistent(store_dir, monkeypatch):
    store = Store(store_dir)
    kept = store.put("track", {"t": b"kept"})
    import d2a_core.artifacts.store as store_mod

    def full(fd):  # delayed allocation: a full disk often shows up only at fsync
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(store_mod.os, "fsync", full)
    with pytest.raises(StoreError, match="No space left on device"):
        store.put("ckpt", {"c": b"x" * 100})
    monkeypatch.undo()
    assert [a.id for a in store.list()] == [kept.id] and store.verify() == []
    assert not any((store_dir / "tmp").iterdir())


def test_an_old_lease_file_of_a_dead_process_is_collected(store_dir):
    store = Store(store_dir)
    store.put("x", {"a": b"1"})
    stale = store_dir / "leases" / "12345-deadbeef.json"
    stale.write_text(json.dumps({"pid": 12345, "artifacts": []}))
    time.sleep(0.01)
    report = store.gc()
    assert report.stale_leases == ["12345-deadbeef.json"] and not stale.exists()
