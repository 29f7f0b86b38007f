"""`d2a artifacts pack` / `import`: an assistant handed to another store evaluates the same there,
and a bundle that is damaged, climbs out of the store or carries a code-running checkpoint is
refused with exit 3 before anything is written."""

from __future__ import annotations

import hashlib
import io
import json
import os
import tarfile
from pathlib import Path

import pytest
import torch

from d2a_core.artifacts import Store
from d2a_core.artifacts.manifest import artifact_id, canonical_json
from d2a_test_helpers import run_cli

ASSISTANT = "assistants/straightaway/pass-stay/dream2assist/seed0"


@pytest.fixture(scope="module")
def bundle(trained_assistants, tmp_path_factory):
    store, _ = trained_assistants
    out = tmp_path_factory.mktemp("bundle") / "assistant.tar"
    res = run_cli("artifacts", "pack", ASSISTANT, "-o", str(out), "--json", store=store)
    assert res.code == 0, res.stderr
    return out, res.json


def _members(path: Path) -> dict[str, bytes]:
    with tarfile.open(path) as tar:
        return {m.name: tar.extractfile(m).read() for m in tar if m.isreg()}


def _write(path: Path, members: dict[str, bytes], extra: list[tarfile.TarInfo] = ()) -> Path:
    with tarfile.open(path, "w") as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        for info in extra:
            tar.addfile(info)
    return path


def _store_is_empty(store: Path) -> bool:
    return not any(p.is_file() for sub in ("objects", "manifests", "refs") for p in (store / sub).rglob("*"))


def test_an_imported_assistant_evaluates_with_the_same_numbers(trained_assistants, bundle, tmp_path, cli):
    source, _ = trained_assistants
    path, packed = bundle
    assistant_id = Store(source).resolve(ASSISTANT)
    assert packed["roots"] == [assistant_id] and packed["aliases"][ASSISTANT] == assistant_id
    target = tmp_path / "store"
    res = cli("artifacts", "import", str(path), "--json", store=target)
    assert res.code == 0, res.stderr
    assert res.json["imported"] == packed["artifacts"] and res.json["aliases"][ASSISTANT] == assistant_id
    assert Store(target).resolve(f"imported/{assistant_id[:12]}") == assistant_id
    assert cli("artifacts", "verify", "--json", store=target).code == 0
    args = ("eval", "--track", "straightaway", "--pair", "pass-stay", "--assistant", assistant_id,
            "--episodes", "1", "--json")
    here, there = cli(*args, store=source), cli(*args, store=target)
    assert here.code == 0 and there.code == 0, there.stderr
    # the evaluation's id hashes every number it stored
    assert there.json["evaluations"][0]["id"] == here.json["evaluations"][0]["id"]
    again = cli("artifacts", "import", str(path), "--json", store=target)
    assert again.code == 0 and again.json["imported"] == 0


class _RunsCode:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_a_checkpoint_that_runs_code_is_refused_even_with_every_hash_recomputed(bundle, tmp_path, cli):
    path, packed = bundle
    members = _members(path)
    index = json.loads(members["d2a-bundle.json"])
    old_id = packed["roots"][0]
    manifest = json.loads(members[f"manifests/{old_id}.json"])
    marker = tmp_path / "ran"
    evil = io.BytesIO()
    torch.save({"weights": _RunsCode(marker)}, evil)
    data = evil.getvalue()
    digest = hashlib.sha256(data).hexdigest()
    # a forger who knows the format: the blob, the manifest's entry, its id and checksum, the index
    del members[f"objects/{manifest['files']['agent.pt']['sha256']}"]
    members[f"objects/{digest}"] = data
    manifest["files"]["agent.pt"] = {"sha256": digest, "size": len(data)}
    body = {k: v for k, v in manifest.items() if k not in ("id", "sha256")}
    new_id = artifact_id(body)
    manifest = dict(body, id=new_id)
    manifest["sha256"] = hashlib.sha256(canonical_json(manifest)).hexdigest()
    del members[f"manifests/{old_id}.json"]
    members[f"manifests/{new_id}.json"] = canonical_json(manifest)
    index["roots"] = [new_id]
    index["artifacts"] = [new_id if i == old_id else i for i in index["artifacts"]]
    index["aliases"] = {a: new_id if t == old_id else t for a, t in index["aliases"].items()}
    members["d2a-bundle.json"] = json.dumps(index).encode()
    forged = _write(tmp_path / "forged.tar", members)

    target = tmp_path / "store"
    res = cli("artifacts", "import", str(forged), "--json", store=target)
    assert res.code == 3, res.stderr
    assert "agent.pt" in res.json["error"]["message"] and "nothing was imported" in res.json["error"]["message"]
    assert not marker.exists()
    assert _store_is_empty(target)


def test_damaged_and_escaping_bundles_are_refused(bundle, tmp_path, cli):
    path, _ = bundle
    members = _members(path)
    blob = next(n for n in members if n.startswith("objects/"))
    flipped = dict(members, **{blob: bytes([members[blob][0] ^ 1]) + members[blob][1:]})
    climbing = dict(members, **{"../outside": b"x"})
    link = tarfile.TarInfo(blob)
    link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
    linked = {n: d for n, d in members.items() if n != blob}
    cases = {
        "does not match its hash": _write(tmp_path / "flipped.tar", flipped),
        "not a bundle file name": _write(tmp_path / "climbing.tar", climbing),
        "not a plain file": _write(tmp_path / "linked.tar", linked, [link]),
    }
    (tmp_path / "junk.tar").write_bytes(b"not a tar file at all")
    cases["not a readable tar file"] = tmp_path / "junk.tar"
    for why, bad in cases.items():
        target = tmp_path / f"store-{bad.stem}"
        res = cli("artifacts", "import", str(bad), "--json", store=target)
        assert res.code == 3, (why, res.stderr)
        assert why in res.json["error"]["message"]
        assert _store_is_empty(target)
    assert not (tmp_path / "outside").exists()
