"""`d2a artifacts ...` through the CLI with --json, including exit codes."""

from __future__ import annotations

import os

from d2a_core.artifacts import Store


def _populate(store_dir):
    store = Store(store_dir)
    track = store.put("track", {"track.npz": b"track bytes"}, config={"k": 1}, seed=0)
    opp = store.put("replay", {"lap.mcap": b"lap"}, inputs=[track.id])
    ckpt = store.put("ckpt", {"model.pt": b"weights"}, inputs=[track.id, opp.id], labels={"intent": "pass"})
    store.tag(track.id, "track/hairpin")
    store.tag(ckpt.id, "humans/hairpin/pass/expert")
    return track, opp, ckpt


def test_ls_and_show_with_lineage(cli, store_dir):
    track, opp, ckpt = _populate(store_dir)
    res = cli("artifacts", "ls", "--json", store=store_dir)
    assert res.code == 0, res.stderr
    rows = {r["id"]: r for r in res.json["artifacts"]}
    assert set(rows) == {track.id, opp.id, ckpt.id}
    assert rows[track.id]["aliases"] == ["track/hairpin"]
    assert rows[ckpt.id]["labels"] == {"intent": "pass"}
    res = cli("artifacts", "ls", "--kind", "replay", "--json", store=store_dir)
    assert [r["id"] for r in res.json["artifacts"]] == [opp.id]

    res = cli("artifacts", "show", "humans/hairpin/pass/expert", "--json", store=store_dir)
    assert res.code == 0, res.stderr
    out = res.json
    assert out["id"] == ckpt.id and out["manifest"]["kind"] == "ckpt"
    lineage = out["lineage"]
    assert [n["id"] for n in lineage["inputs"]] == [track.id, opp.id]
    assert lineage["inputs"][1]["inputs"][0]["id"] == track.id
    # human output works too and names the lineage
    res = cli("artifacts", "show", ckpt.id[:8], store=store_dir)
    assert res.code == 0 and "lineage" in res.stdout and track.id[:12] in res.stdout


def test_global_options_before_subcommand_and_env_store(cli, store_dir):
    track, _, _ = _populate(store_dir)
    res = cli("--json", "--store", str(store_dir), "artifacts", "show", "track/hairpin")
    assert res.code == 0 and res.json["id"] == track.id
    res = cli("artifacts", "show", "track/hairpin", "--json", env={"D2A_STORE": str(store_dir)})
    assert res.code == 0 and res.json["id"] == track.id


def test_missing_id_or_alias_exits_2_with_suggestions(cli, store_dir):
    _populate(store_dir)
    res = cli("artifacts", "show", "track/hairpn", "--json", store=store_dir)
    assert res.code == 2
    err = res.json["error"]
    assert "track/hairpn" in err["message"] and "track/hairpin" in err["message"]
    assert "track/hairpn" in res.stderr


def test_tag_and_resolve_prefix(cli, store_dir):
    track, _, ckpt = _populate(store_dir)
    res = cli("artifacts", "tag", ckpt.id[:10], "humans/hairpin/pass", "--json", store=store_dir)
    assert res.code == 0 and res.json == {"alias": "humans/hairpin/pass", "id": ckpt.id}
    assert Store(store_dir).resolve("humans/hairpin/pass") == ckpt.id
    res = cli("artifacts", "tag", "nope", "x", store=store_dir)
    assert res.code == 2


def test_verify_exit_codes(cli, store_dir):
    track, _, ckpt = _populate(store_dir)
    res = cli("artifacts", "verify", "--json", store=store_dir)
    assert res.code == 0 and res.json["ok"] and res.json["checked"] == 3
    blob = Store(store_dir).path(ckpt.id, "model.pt")
    os.chmod(blob, 0o644)
    blob.write_bytes(b"weightz")
    res = cli("artifacts", "verify", "--json", store=store_dir)
    assert res.code == 3
    assert [p["artifact"] for p in res.json["problems"]] == [ckpt.id]
    assert ckpt.id in res.stderr


def test_gc_dry_run_then_real(cli, store_dir):
    _populate(store_dir)
    orphan = Store(store_dir).put("ckpt", {"model.pt": b"nobody points here"})
    res = cli("artifacts", "gc", "--dry-run", "--json", store=store_dir)
    assert res.code == 0 and res.json["artifacts"] == [orphan.id] and res.json["dry_run"]
    assert len(Store(store_dir).list()) == 4
    res = cli("artifacts", "gc", "--json", store=store_dir)
    assert res.code == 0 and res.json["artifacts"] == [orphan.id]
    assert len(Store(store_dir).list()) == 3      # the replay survives: the expert's lineage reaches it


def test_export_copies_files_under_their_names(cli, store_dir, tmp_path):
    track, _, _ = _populate(store_dir)
    res = cli("artifacts", "export", "track/hairpin", str(tmp_path / "out"), "--json", store=store_dir)
    assert res.code == 0 and res.json["id"] == track.id
    assert (tmp_path / "out" / "track.npz").read_bytes() == b"track bytes"
