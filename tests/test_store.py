"""The artifact store through its Python API: round trip, dedupe, lineage, refs, verify, gc."""

from __future__ import annotations

import os
import stat

import pytest

from d2a_core.artifacts import Store, artifact_id
from d2a_core.errors import AmbiguousRefError, IntegrityError, NotFoundError, UsageError


def test_round_trip_files_and_manifest(store_dir, tmp_path):
    src = tmp_path / "weights.bin"
    payload = os.urandom(3 * (1 << 20) + 17)  # several chunks, odd size
    src.write_bytes(payload)
    store = Store(store_dir)
    art = store.put("ckpt", {"weights.bin": src, "meta.json": b'{"a": 1}'},
                    config={"dreamer": {"units": 64}}, seed=3, labels={"intent": "pass"})
    again = store.get(art.id)
    assert store.read_bytes(art.id, "weights.bin") == payload
    assert store.read_bytes(art.id, "meta.json") == b'{"a": 1}'
    assert again.kind == "ckpt" and again.seed == 3 and again.labels == {"intent": "pass"}
    assert again.config == {"dreamer": {"units": 64}}
    assert again.files["weights.bin"]["size"] == len(payload)
    prov = again.manifest["provenance"]
    assert {"created", "command", "code", "packages"} <= set(prov)
    assert {"version", "git_commit", "dirty"} <= set(prov["code"])
    assert prov["packages"]["python"]
    # the id is the hash of the manifest without its timestamps/provenance
    assert artifact_id(again.manifest) == art.id
    # blobs are read-only on disk
    mode = store.path(art.id, "weights.bin").stat().st_mode
    assert not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)


def test_same_content_and_config_dedupes(store_dir):
    store = Store(store_dir)
    a = store.put("track", {"t.npz": b"x" * 1000}, config={"k": 1}, seed=0)
    b = store.put("track", {"t.npz": b"x" * 1000}, config={"k": 1}, seed=0)
    assert a.id == b.id
    assert len(store.list()) == 1
    assert len(list((store_dir / "objects").glob("??/*"))) == 1
    c = store.put("track", {"t.npz": b"x" * 1000}, config={"k": 2}, seed=0)
    d = store.put("track", {"t.npz": b"x" * 1000}, config={"k": 1}, seed=1)
    assert len({a.id, c.id, d.id}) == 3
    assert len(list((store_dir / "objects").glob("??/*"))) == 1  # the blob is shared


def test_streaming_writer_and_torch_checkpoint(store_dir):
    torch = pytest.importorskip("torch")
    store = Store(store_dir)
    state = {"w": torch.arange(1000, dtype=torch.float32)}
    with store.create("ckpt", seed=0) as writer:
        with writer.open("model.pt") as fh:
            torch.save(state, fh)
    loaded = torch.load(store.path(writer.artifact.id, "model.pt"))
    assert torch.equal(loaded["w"], state["w"])
    with store.create("ckpt", seed=0) as writer2:
        with writer2.open("model.pt") as fh:
            torch.save(state, fh)
    assert writer2.artifact.id == writer.artifact.id  # torch.save is byte-stable


def test_failed_write_leaves_nothing(store_dir):
    store = Store(store_dir)
    with pytest.raises(RuntimeError):
        with store.create("ckpt") as writer:
            writer.add_bytes("a.bin", b"abc")
            raise RuntimeError("training crashed")
    assert store.list() == []
    assert list((store_dir / "tmp").iterdir()) == []
    assert list((store_dir / "objects").glob("??/*")) == []


def test_lineage_and_resolution(store_dir):
    store = Store(store_dir)
    track = store.put("track", {"t": b"track"})
    opp = store.put("replay", {"r": b"replay"}, inputs=[track.id])
    ckpt = store.put("ckpt", {"c": b"ckpt"}, inputs=[track.id, opp.id])
    store.tag(track.id, "track/hairpin")
    store.tag(ckpt.id, "humans/hairpin/pass")
    store.tag(ckpt.id, "humans/hairpin/pass/expert")  # an alias may extend another
    assert store.resolve("track/hairpin") == track.id
    assert store.resolve("humans/hairpin/pass/expert") == ckpt.id
    assert store.resolve(ckpt.id[:10]) == ckpt.id
    tree = store.lineage("humans/hairpin/pass")
    assert tree["id"] == ckpt.id
    assert [n["id"] for n in tree["inputs"]] == [track.id, opp.id]
    assert tree["inputs"][0]["aliases"] == ["track/hairpin"]
    assert tree["inputs"][1]["inputs"][0]["id"] == track.id  # recursive
    with pytest.raises(NotFoundError, match="track/hairpn.*closest known: track/hairpin"):
        store.resolve("track/hairpn")
    with pytest.raises(NotFoundError, match="no artifact"):
        store.put("ckpt", {"c": b"x"}, inputs=["does-not-exist"])
    with pytest.raises(UsageError):
        store.tag(track.id, "../escape")


def test_ambiguous_prefix_is_reported(store_dir):
    store = Store(store_dir)
    seen: dict[str, str] = {}
    for i in range(3000):  # deterministic ids: the first 4-hex-digit clash comes at a fixed i
        art_id = store.put("blob", {"f": str(i).encode()}).id
        if art_id[:4] in seen:
            break
        seen[art_id[:4]] = art_id
    else:
        pytest.fail("no prefix clash found")
    # a usage error, but not a NotFoundError: a caller falling back on "not found" must not hide it
    with pytest.raises(AmbiguousRefError, match="ambiguous"):
        store.resolve(art_id[:4])
    assert store.resolve(art_id[:12]) == art_id
    with pytest.raises(NotFoundError, match="at least 4 characters"):
        store.resolve(art_id[:3])  # shorter than the minimum prefix: say so


def test_finished_finds_the_latest_whole_result_of_a_run_key(store_dir):
    store = Store(store_dir)
    track = store.put("track", {"t": b"track"})
    first = store.put("evaluation", {"e": b"first"}, inputs=[track.id], labels={"run_key": "k1"})
    second = store.put("evaluation", {"e": b"second"}, inputs=[track.id], labels={"run_key": "k1"})
    other = store.put("evaluation", {"e": b"other"}, labels={"run_key": "k2"})
    assert store.finished("evaluation", "k1").id == second.id
    assert store.finished("evaluation", "k2").id == other.id
    assert store.finished("evaluation", "k3") is None
    assert store.finished("intent-swap", "k1") is None  # the kind is part of the question
    # a result whose input lost its blob is not whole: the run must build it again
    blob = store.path(track.id, "t")
    os.chmod(blob.parent, 0o755)
    blob.unlink()
    assert store.finished("evaluation", "k1") is None
    assert first.id != second.id


def test_verify_detects_corrupted_blob_and_manifest(store_dir):
    store = Store(store_dir)
    good = store.put("track", {"t": b"good data"})
    bad = store.put("ckpt", {"c": b"will be corrupted"})
    edited = store.put("ckpt", {"c": b"manifest will be edited"})
    assert store.verify() == []
    blob = store.path(bad.id, "c")
    os.chmod(blob, 0o644)
    blob.write_bytes(b"will be CORRUPTED")
    manifest = store_dir / "manifests" / edited.id[:2] / f"{edited.id}.json"
    os.chmod(manifest, 0o644)
    manifest.write_text(manifest.read_text().replace('"seed":null', '"seed":7'))
    problems = {p.artifact for p in store.verify()}
    assert problems == {bad.id, edited.id}
    assert good.id not in problems
    with pytest.raises(IntegrityError):
        store.read_bytes(bad.id, "c")


def test_gc_keeps_what_refs_reach(store_dir):
    store = Store(store_dir)
    track = store.put("track", {"t": b"track"})
    ckpt = store.put("ckpt", {"c": b"ckpt"}, inputs=[track.id])
    orphan = store.put("ckpt", {"c": b"orphan"})
    store.tag(ckpt.id, "humans/x")
    (store_dir / "tmp" / "999-stale").write_bytes(b"half a file")
    dry = store.gc(dry_run=True)
    assert dry.artifacts == [orphan.id] and len(dry.blobs) == 1 and dry.temp_files == ["999-stale"]
    assert {a.id for a in store.list()} == {track.id, ckpt.id, orphan.id}  # nothing removed
    report = store.gc()
    assert report.artifacts == [orphan.id]
    assert {a.id for a in store.list()} == {track.id, ckpt.id}
    assert store.read_bytes("humans/x", "c") == b"ckpt"
    assert store.verify() == []
    assert not any((store_dir / "tmp").iterdir())
