"""Bundles: artifacts with their whole lineage in one file, to hand to someone else's store.

A bundle is a tar file (`d2a artifacts pack`) holding

    d2a-bundle.json            {"format": 1, "roots": [ids], "artifacts": [ids], "aliases": {alias: id}}
    manifests/<id>.json        each artifact's manifest, byte for byte as stored
    objects/<sha256>           each file's blob

for the named artifacts and every artifact they were made from (their inputs, recursively), so
the receiving store can evaluate an assistant without anything else. The aliases are those of
the sending store that name an artifact in the bundle (`track/straightaway`, `humans/...`).

Importing trusts nothing in the file. Before anything enters the store, every member must be a
plain file with one of the names above (no links, no paths that climb out), every manifest must
match its id and checksum and name only plain file names, every blob must match its hash, every
input must be in the bundle or already in the store, and every file passes the caller's
`check_file` (d2a passes the restricted torch loader for `*.pt` files: a checkpoint whose pickle
asks for anything but tensors and plain data is refused without running). Any failure raises
IntegrityError (exit 3) and leaves the store as it was. Then blobs, manifests (inputs first) and
aliases land the way the store writes its own, so a killed import leaves no half artifact. Each
root also gets `imported/<first 12 hex of its id>`, which keeps it (and its lineage) from gc
whatever happens to the bundle's other aliases.
"""

from __future__ import annotations

import io
import json
import os
import re
import tarfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from d2a_core.artifacts.fsutil import BadFile, fsync_dir, os_reason, sha256_file, storage_errors
from d2a_core.artifacts.store import Store, alias_problem
from d2a_core.errors import IntegrityError, StoreError, UsageError

BUNDLE_FORMAT = 1
INDEX = "d2a-bundle.json"
_MEMBER = re.compile(r"^(manifests/[0-9a-f]{64}\.json|objects/[0-9a-f]{64})$")

FileCheck = Callable[[str, Path, str], None]
"""check(file name in its artifact, path of its bytes, what to call it in an error): raise
IntegrityError to refuse the bundle."""


def closure(store: Store, refs: Iterable[str]) -> list[str]:
    """The ids of `refs` and of everything they were made from, inputs before the artifacts that
    use them."""
    order: list[str] = []
    seen: set[str] = set()

    def visit(art_id: str) -> None:
        if art_id in seen:
            return
        seen.add(art_id)
        for parent in store.get(art_id).inputs:
            visit(parent)
        order.append(art_id)

    for ref in refs:
        visit(store.resolve(ref))
    return order


def pack(store: Store, refs: list[str], out: Path) -> dict[str, Any]:
    """Write the bundle of `refs` to `out` (atomically: a killed pack leaves no file there)."""
    if not refs:
        raise UsageError("name at least one artifact to pack")
    roots = [store.resolve(r) for r in refs]
    ids = closure(store, roots)
    in_bundle = set(ids)
    aliases = {alias: target for alias, target in sorted(store.refs().items()) if target in in_bundle}
    index = {"format": BUNDLE_FORMAT, "roots": roots, "artifacts": ids, "aliases": aliases}
    if out.is_dir():
        raise UsageError(f"--out {out} is a directory; name the bundle file")
    tmp = out.with_name(f".{out.name}.tmp{os.getpid()}")
    blobs: set[str] = set()
    size = 0
    try:
        with storage_errors(f"cannot write the bundle {out}", out), tarfile.open(tmp, "w") as tar:
            _add_bytes(tar, INDEX, json.dumps(index, indent=1, sort_keys=True).encode())
            for art_id in ids:
                art = store.get(art_id)
                for name, info in sorted(art.files.items()):
                    if info["sha256"] not in blobs:
                        blobs.add(info["sha256"])
                        tar.add(store.path(art_id, name), arcname=f"objects/{info['sha256']}", recursive=False,
                                filter=_plain)
                        size += info["size"]
                _add_bytes(tar, f"manifests/{art_id}.json", store.manifest_bytes(art_id))
        with storage_errors(f"cannot write the bundle {out}", out):
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, out)
            fsync_dir(out.parent)
    finally:
        tmp.unlink(missing_ok=True)
    return {"bundle": str(out), "roots": roots, "artifacts": len(ids), "files": len(blobs), "bytes": size,
            "aliases": aliases}


def _plain(info: tarfile.TarInfo) -> tarfile.TarInfo:
    """A member as a reader elsewhere should see it: a read-only file of nobody's."""
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.mode = 0o444
    info.mtime = 0
    return info


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = _plain(tarfile.TarInfo(name))
    info.size = len(data)
    tar.addfile(info, io.BytesIO(data))


def unpack(store: Store, bundle: Path, check_file: FileCheck | None = None) -> dict[str, Any]:
    """Import a bundle into `store` after checking all of it (see the module docstring)."""
    if not bundle.is_file():
        raise UsageError(f"bundle {bundle} is not a file")
    with store.scratch_dir("import") as scratch:
        index = _extract(bundle, scratch)
        manifests = _check(store, bundle, scratch, index, check_file)
        return _land(store, scratch, index, manifests)


def _refuse(bundle: Path, why: str) -> IntegrityError:
    return IntegrityError(f"bundle {bundle} was refused, nothing was imported: {why}")


def _extract(bundle: Path, scratch: Path) -> dict[str, Any]:
    """The members into `scratch`, each checked to be a plain file with a bundle name first."""
    index = None
    try:
        with tarfile.open(bundle, "r:*") as tar:
            for member in tar:
                if member.name == INDEX or _MEMBER.match(member.name):
                    if not member.isreg():
                        raise _refuse(bundle, f"member {member.name!r} is not a plain file (a link?)")
                    target = scratch / member.name
                    if target.exists():
                        raise _refuse(bundle, f"member {member.name!r} appears twice")
                    target.parent.mkdir(parents=True, exist_ok=True)
                    source = tar.extractfile(member)
                    assert source is not None
                    with source, open(target, "wb") as sink:
                        while chunk := source.read(1 << 20):
                            sink.write(chunk)
                else:
                    raise _refuse(bundle, f"member {member.name[:200]!r} is not a bundle file name")
    except tarfile.TarError as exc:
        raise _refuse(bundle, f"not a readable tar file ({exc})") from None
    except OSError as exc:
        raise StoreError(f"cannot read bundle {bundle}: {os_reason(exc)}") from None
    try:
        index = json.loads((scratch / INDEX).read_bytes())
    except FileNotFoundError:
        raise _refuse(bundle, f"it has no {INDEX}") from None
    except (ValueError, UnicodeDecodeError):
        raise _refuse(bundle, f"{INDEX} is not JSON") from None
    full_id = re.compile(r"^[0-9a-f]{64}$")
    if not (isinstance(index, dict) and index.get("format") == BUNDLE_FORMAT
            and isinstance(index.get("artifacts"), list) and isinstance(index.get("roots"), list)
            and isinstance(index.get("aliases"), dict)
            and all(isinstance(i, str) and full_id.match(i) for i in [*index["artifacts"], *index["roots"]])
            and all(isinstance(t, str) for t in index["aliases"].values())):
        raise _refuse(bundle, f"{INDEX} is not a bundle index of format {BUNDLE_FORMAT}")
    return index


def _check(store: Store, bundle: Path, scratch: Path, index: dict[str, Any],
           check_file: FileCheck | None) -> dict[str, dict[str, Any]]:
    ids: list[str] = index["artifacts"]
    listed = set(ids)
    present = {p.stem for p in (scratch / "manifests").glob("*.json")} if (scratch / "manifests").is_dir() else set()
    if present != listed:
        raise _refuse(bundle, "its manifests are not the artifacts its index lists")
    if not set(index["roots"]) <= listed or not set(index["aliases"].values()) <= listed:
        raise _refuse(bundle, "its index names roots or aliases outside the bundle")
    for alias in index["aliases"]:
        if not isinstance(alias, str) or alias_problem(alias):
            raise _refuse(bundle, f"alias {str(alias)[:100]!r} is not a valid alias")
    manifests: dict[str, dict[str, Any]] = {}
    for art_id in ids:
        try:
            manifests[art_id] = store.parse_manifest((scratch / "manifests" / f"{art_id}.json").read_bytes(), art_id)
        except BadFile as exc:
            raise _refuse(bundle, f"artifact {art_id[:12]}: {exc}") from None
    for art_id, manifest in manifests.items():
        missing = [i for i in manifest["inputs"] if i not in listed and not store.has(i)]
        if missing:
            raise _refuse(bundle, f"artifact {art_id[:12]} was made from {missing[0][:12]}, which is neither in "
                                  "the bundle nor in the store")
    hashed: set[str] = set()
    for art_id, manifest in manifests.items():
        for name, info in sorted(manifest["files"].items()):
            blob = scratch / "objects" / info["sha256"]
            what = f"artifact {art_id[:12]} ({manifest['kind']}) file {name!r}"
            if info["sha256"] not in hashed:
                if not blob.is_file():
                    raise _refuse(bundle, f"{what} is missing")
                digest, size = sha256_file(blob)
                if digest != info["sha256"] or size != info["size"]:
                    raise _refuse(bundle, f"{what} does not match its hash")
                hashed.add(info["sha256"])
            if check_file is not None:
                try:
                    check_file(name, blob, what)
                except IntegrityError as exc:
                    raise _refuse(bundle, str(exc)) from None
    return manifests


def _land(store: Store, scratch: Path, index: dict[str, Any], manifests: dict[str, dict[str, Any]]) -> dict[str, Any]:
    new = [i for i in index["artifacts"] if not store.has(i)]
    store.adopt(new, {i: manifests[i] for i in new}, scratch / "manifests", scratch / "objects")
    aliases_set, aliases_kept = {}, {}
    # every root gets a name of its own, so nothing imported is left for gc when the store's own
    # results keep the bundle's aliases
    for root in index["roots"]:
        store.tag(root, f"imported/{root[:12]}")
        aliases_set[f"imported/{root[:12]}"] = root
    for alias, target in sorted(index["aliases"].items()):
        try:
            current = store.resolve(alias)
        except Exception:  # noqa: BLE001 - no such alias (or a broken one): the bundle's goes in
            current = None
        if current in (None, target):
            store.tag(target, alias)
            aliases_set[alias] = target
        else:  # the receiving store's own results keep their names
            aliases_kept[alias] = current
    return {"roots": index["roots"], "artifacts": len(index["artifacts"]), "imported": len(new),
            "already_present": len(index["artifacts"]) - len(new), "aliases": aliases_set,
            "aliases_kept": aliases_kept}
