"""Random single-bit flips in blobs, manifests and alias files of a real store (a smoke track and
its replays): `verify` reports every one, and reading the damaged artifact through the store is
refused; a few go through the CLI to check that train-humans refuses a damaged replay (exit 3)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from fault_helpers import rng, run

from d2a_core.artifacts import Store
from d2a_core.errors import IntegrityError

FLIPS = int(os.environ.get("D2A_FAULT_FLIPS", "600"))
CLI_FLIPS = int(os.environ.get("D2A_FAULT_CLI_FLIPS", "6"))


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    store = tmp_path_factory.mktemp("flips") / "store"
    assert run("make-track", "straightaway", "--preset", "smoke", "--json", store=store).returncode == 0
    return store


def _files(store: Path) -> dict[str, list[Path]]:
    return {
        "blob": sorted((store / "objects").glob("??/*")),
        "manifest": sorted((store / "manifests").glob("??/*.json")),
        "ref": sorted((store / "refs").rglob("*.ref")),
    }


def _owners(store: Store, path: Path, kind: str) -> set[str]:
    """Aliases whose reading must fail after `path` was damaged."""
    refs = store.refs()
    if kind == "ref":
        return {path.relative_to(store.root / "refs").as_posix()[: -len(".ref")]}
    if kind == "manifest":
        return {a for a, t in refs.items() if t == path.stem}
    owners = set()
    for alias, target in refs.items():
        manifest = json.loads((store.root / "manifests" / target[:2] / f"{target}.json").read_bytes())
        if any(f["sha256"] == path.name for f in manifest["files"].values()):
            owners.add(alias)
    return owners


def _read_all(store: Store, alias: str) -> None:
    art = store.get(alias)
    for name in art.files:
        store.path(alias, name)


def test_every_flip_is_reported_by_verify_and_refused_on_read(built, tmp_path):
    store_dir = tmp_path / "store"
    shutil.copytree(built, store_dir)
    files = _files(store_dir)
    pick = rng("flips")
    counts = {kind: 0 for kind in files}
    for _ in range(FLIPS):
        kind = pick.choice(sorted(files))
        path = pick.choice(files[kind])
        original = path.read_bytes()
        offset = pick.randrange(len(original))
        damaged = bytearray(original)
        damaged[offset] ^= 1 << pick.randrange(8)
        os.chmod(path, 0o644)
        path.write_bytes(bytes(damaged))
        try:
            store = Store(store_dir)  # a fresh reader: nothing cached from before the flip
            problems = store.verify()
            assert problems, f"verify missed a flip at byte {offset} of {kind} {path}"
            owners = _owners(store, path, kind)
            for alias in owners:
                with pytest.raises(IntegrityError):
                    _read_all(Store(store_dir), alias)
        finally:
            path.write_bytes(original)
            os.chmod(path, 0o444 if kind != "ref" else 0o644)
        counts[kind] += 1
    assert Store(store_dir).verify() == []
    print(f"flips: {counts}")


def test_train_humans_refuses_a_flipped_replay_or_track(built, tmp_path):
    pick = rng("cli-flips")
    store = Store(built)
    targets = [store.get("track/straightaway")] + [store.get(f"track/straightaway/opponents/{i}") for i in range(2)]
    for k in range(CLI_FLIPS):
        store_dir = tmp_path / f"store{k}"
        shutil.copytree(built, store_dir)
        art = pick.choice(targets)
        info = next(iter(sorted(art.files.items(), key=lambda kv: -kv[1]["size"])))[1]
        blob = store_dir / "objects" / info["sha256"][:2] / info["sha256"]
        data = bytearray(blob.read_bytes())
        data[pick.randrange(len(data))] ^= 1 << pick.randrange(8)
        os.chmod(blob, 0o644)
        blob.write_bytes(bytes(data))
        res = run("train-humans", "--intent", "pass", "--track", "straightaway", "--preset", "smoke", "--json",
                  store=store_dir)
        assert res.returncode == 3, res.stderr
        assert art.id[:12] in json.loads(res.stdout)["error"]["message"]
