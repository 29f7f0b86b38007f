"""A content-addressed artifact store on a local filesystem.

Layout under the store root::

    objects/ab/abcdef...        immutable blobs named by their sha256 (read-only files)
    manifests/ab/<id>.json      one canonical manifest per artifact (read-only)
    refs/<alias>.ref            aliases such as track/hairpin -> an artifact id
    tmp/                        files being written (same filesystem, so renames are atomic)
    lock                        flock: writers share it, gc takes it exclusively

Safety: every file is written to tmp/, fsynced, then renamed into place, so a reader never sees
half a file. An artifact becomes visible only when its manifest lands, after all its blobs; a
ref is written only to an existing manifest. A process killed mid-write leaves only orphan
temp files, which `gc` removes. Writers hold a shared lock for their whole life and `gc` an
exclusive one, so gc never deletes a blob that a live writer is about to reference.
"""

from __future__ import annotations

import contextlib
import difflib
import fcntl
import hashlib
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

from d2a_core.artifacts.manifest import (
    MANIFEST_FORMAT,
    Artifact,
    artifact_id,
    canonical_json,
    provenance,
)
from d2a_core.errors import IntegrityError, NotFoundError, UsageError

CHUNK = 1 << 20
HEX = re.compile(r"^[0-9a-f]+$")
ALIAS = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*(/[A-Za-z0-9][A-Za-z0-9_.+-]*)*$")
FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*(/[A-Za-z0-9][A-Za-z0-9_.+-]*)*$")
MIN_PREFIX = 4


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def sha256_file(path: Path) -> tuple[str, int]:
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return digest.hexdigest(), size


class _HashingWriter:
    """A binary file object that hashes what it writes (so a blob is hashed in one pass)."""

    def __init__(self, fh: IO[bytes]):
        self._fh = fh
        self._digest = hashlib.sha256()
        self.size = 0

    def write(self, data: bytes) -> int:
        self._digest.update(data)
        self.size += len(data)
        return self._fh.write(data)

    def flush(self) -> None:
        self._fh.flush()

    def hexdigest(self) -> str:
        return self._digest.hexdigest()

    # torch.save and numpy.save only need write/flush; seekable() = False makes torch stream.
    def seekable(self) -> bool:
        return False

    def writable(self) -> bool:
        return True


@dataclass
class VerifyProblem:
    artifact: str | None
    what: str

    def as_dict(self) -> dict[str, Any]:
        return {"artifact": self.artifact, "problem": self.what}


@dataclass
class GcReport:
    artifacts: list[str] = field(default_factory=list)
    blobs: list[str] = field(default_factory=list)
    temp_files: list[str] = field(default_factory=list)
    bytes_freed: int = 0
    dry_run: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {
            "dry_run": self.dry_run,
            "artifacts": self.artifacts,
            "blobs": len(self.blobs),
            "temp_files": len(self.temp_files),
            "bytes_freed": self.bytes_freed,
        }


class Store:
    """The artifact store rooted at `root` (created on first write)."""

    def __init__(self, root: str | os.PathLike[str]):
        self.root = Path(root)

    # ----------------------------------------------------------------------------- layout
    @property
    def _objects(self) -> Path:
        return self.root / "objects"

    @property
    def _manifests(self) -> Path:
        return self.root / "manifests"

    @property
    def _refs(self) -> Path:
        return self.root / "refs"

    @property
    def _tmp(self) -> Path:
        return self.root / "tmp"

    def _blob_path(self, digest: str) -> Path:
        return self._objects / digest[:2] / digest

    def _manifest_path(self, art_id: str) -> Path:
        return self._manifests / art_id[:2] / f"{art_id}.json"

    def _ref_path(self, alias: str) -> Path:
        return self._refs / f"{alias}.ref"

    def _ensure_layout(self) -> None:
        for path in (self._objects, self._manifests, self._refs, self._tmp):
            path.mkdir(parents=True, exist_ok=True)

    @contextlib.contextmanager
    def _lock(self, exclusive: bool) -> Iterator[None]:
        self._ensure_layout()
        fd = os.open(self.root / "lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            yield
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    def _temp_file(self, suffix: str = "") -> tuple[IO[bytes], Path]:
        fd, name = tempfile.mkstemp(dir=self._tmp, prefix=f"{os.getpid()}-", suffix=suffix)
        return os.fdopen(fd, "wb"), Path(name)

    def _install(self, tmp: Path, final: Path) -> None:
        """Move a complete, fsynced temp file into place read-only; keep an existing copy."""
        final.parent.mkdir(parents=True, exist_ok=True)
        os.chmod(tmp, 0o444)
        try:
            os.link(tmp, final)  # fails if present: content-addressed, so the present copy is equal
        except FileExistsError:
            pass
        else:
            _fsync_dir(final.parent)
        finally:
            tmp.unlink(missing_ok=True)

    # ----------------------------------------------------------------------------- writing
    def create(
        self,
        kind: str,
        *,
        inputs: Iterable[str] = (),
        config: Any = None,
        seed: int | None = None,
        labels: dict[str, Any] | None = None,
        command: list[str] | None = None,
    ) -> "ArtifactWriter":
        """Start writing an artifact; use as a context manager and add files inside it."""
        input_ids = [self.resolve(ref) for ref in inputs]
        return ArtifactWriter(self, kind, input_ids, config, seed, labels or {}, command)

    def put(
        self,
        kind: str,
        files: dict[str, str | os.PathLike[str] | bytes],
        **kwargs: Any,
    ) -> Artifact:
        """Store an artifact from files on disk or bytes in one call."""
        with self.create(kind, **kwargs) as writer:
            for name, src in files.items():
                if isinstance(src, bytes):
                    writer.add_bytes(name, src)
                else:
                    writer.add_file(name, src)
        return writer.artifact

    def _commit(self, manifest: dict[str, Any], blobs: dict[str, Path]) -> Artifact:
        for digest, tmp in blobs.items():
            self._install(tmp, self._blob_path(digest))
        art_id = artifact_id(manifest)
        stored = dict(manifest, id=art_id)
        fh, tmp = self._temp_file(".json")
        with fh:
            fh.write(canonical_json(stored))
            fh.flush()
            os.fsync(fh.fileno())
        self._install(tmp, self._manifest_path(art_id))
        return self.get(art_id)

    # ----------------------------------------------------------------------------- reading
    def _all_ids(self) -> list[str]:
        if not self._manifests.is_dir():
            return []
        return sorted(p.stem for p in self._manifests.glob("??/*.json"))

    def refs(self) -> dict[str, str]:
        """All aliases and the ids they point to."""
        if not self._refs.is_dir():
            return {}
        out = {}
        for path in sorted(self._refs.rglob("*.ref")):
            alias = path.relative_to(self._refs).as_posix()[: -len(".ref")]
            out[alias] = path.read_text(encoding="ascii").strip()
        return dict(sorted(out.items()))

    def resolve(self, ref: str) -> str:
        """An alias, a full id or a unique id prefix -> the full artifact id."""
        ref = ref.strip()
        if ALIAS.match(ref):
            path = self._ref_path(ref)
            if path.is_file():
                return path.read_text(encoding="ascii").strip()
        if HEX.match(ref) and len(ref) >= MIN_PREFIX:
            if len(ref) == 64 and self._manifest_path(ref).is_file():
                return ref
            matches = [i for i in self._all_ids() if i.startswith(ref)]
            if len(matches) == 1:
                return matches[0]
            if len(matches) > 1:
                shown = ", ".join(m[:12] for m in matches[:5])
                raise NotFoundError(f"id prefix {ref!r} is ambiguous: it matches {len(matches)} artifacts ({shown})")
        known = list(self.refs()) + [i[:12] for i in self._all_ids()]
        close = difflib.get_close_matches(ref, known, n=3, cutoff=0.5)
        hint = f"; closest known: {', '.join(close)}" if close else ""
        raise NotFoundError(f"no artifact or alias {ref!r} in store {self.root}{hint}")

    def get(self, ref: str) -> Artifact:
        art_id = self.resolve(ref)
        path = self._manifest_path(art_id)
        try:
            manifest = json.loads(path.read_bytes())
        except FileNotFoundError:
            raise NotFoundError(f"alias or id {ref!r} points to {art_id}, which is not in the store") from None
        except json.JSONDecodeError as exc:
            raise IntegrityError(f"artifact {art_id}: manifest is not valid JSON ({exc.msg})") from None
        return Artifact(art_id, manifest)

    def path(self, ref: str, name: str) -> Path:
        """Read-only path of one file of an artifact (for np.load, torch.load, ...)."""
        art = self.get(ref)
        if name not in art.files:
            raise NotFoundError(f"artifact {art.id[:12]} ({art.kind}) has no file {name!r}; files: {sorted(art.files)}")
        path = self._blob_path(art.files[name]["sha256"])
        if not path.is_file():
            raise IntegrityError(f"artifact {art.id}: blob of {name!r} is missing")
        return path

    def read_bytes(self, ref: str, name: str, verify: bool = True) -> bytes:
        art = self.get(ref)
        data = self.path(art.id, name).read_bytes()
        if verify and hashlib.sha256(data).hexdigest() != art.files[name]["sha256"]:
            raise IntegrityError(f"artifact {art.id}: file {name!r} does not match its hash")
        return data

    def read_json(self, ref: str, name: str) -> Any:
        return json.loads(self.read_bytes(ref, name))

    def export(self, ref: str, directory: str | os.PathLike[str]) -> list[Path]:
        """Copy an artifact's files, under their own names, into `directory` (e.g. to open a log)."""
        art = self.get(ref)
        out = []
        for name in sorted(art.files):
            dst = Path(directory) / name
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(self.path(art.id, name), dst)
            out.append(dst)
        return out

    def list(self, kind: str | None = None) -> list[Artifact]:
        """Artifacts (optionally of one kind), oldest first."""
        arts = [self.get(i) for i in self._all_ids()]
        if kind is not None:
            arts = [a for a in arts if a.kind == kind]
        return sorted(arts, key=lambda a: (a.created, a.id))

    def find(self, kind: str, **fields: Any) -> list[Artifact]:
        """Artifacts of `kind` whose manifest fields (inputs, config, seed, labels...) equal these."""
        found = []
        for art in self.list(kind):
            # compare as stored JSON (tuples become lists, keys become strings)
            if all(art.manifest.get(k) == json.loads(canonical_json(v)) for k, v in fields.items()):
                found.append(art)
        return found

    def aliases_of(self, art_id: str) -> list[str]:
        return [alias for alias, target in self.refs().items() if target == art_id]

    def lineage(self, ref: str) -> dict[str, Any]:
        """The artifact and its inputs, recursively: {id, kind, aliases, inputs: [...]}."""
        refs = self.refs()
        seen: dict[str, dict[str, Any]] = {}

        def node(art_id: str) -> dict[str, Any]:
            if art_id in seen:  # a DAG can share inputs; show each once in full
                return {"id": art_id, "kind": seen[art_id]["kind"], "shared": True}
            art = self.get(art_id)
            entry = {
                "id": art.id,
                "kind": art.kind,
                "aliases": [a for a, t in refs.items() if t == art.id],
                "labels": art.labels,
            }
            seen[art_id] = entry
            entry["inputs"] = [node(i) for i in art.inputs]
            return entry

        return node(self.resolve(ref))

    # ----------------------------------------------------------------------------- refs
    def tag(self, ref: str, alias: str) -> str:
        """Point `alias` at the artifact `ref` resolves to (atomically replacing an old target)."""
        if not ALIAS.match(alias) or (HEX.match(alias) and len(alias) >= MIN_PREFIX):
            raise UsageError(
                f"invalid alias {alias!r}: use letters, digits, '._+-' in '/'-separated parts, "
                "and not a hex string (it would read as an id)"
            )
        art_id = self.get(ref).id
        with self._lock(exclusive=False):
            # refs live in '<alias>.ref' files, so 'a/b' and 'a/b/c' can coexist
            path = self._ref_path(alias)
            path.parent.mkdir(parents=True, exist_ok=True)
            fh, tmp = self._temp_file(".ref")
            with fh:
                fh.write(art_id.encode("ascii") + b"\n")
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
            _fsync_dir(path.parent)
        return art_id

    def untag(self, alias: str) -> None:
        path = self._ref_path(alias)
        if not path.is_file():
            raise NotFoundError(f"no alias {alias!r} in store {self.root}")
        path.unlink()

    # ----------------------------------------------------------------------------- upkeep
    def verify(self, refs: Iterable[str] | None = None) -> list[VerifyProblem]:
        """Re-hash manifests and blobs; report every corrupted or incomplete artifact."""
        ids = [self.resolve(r) for r in refs] if refs is not None else self._all_ids()
        problems: list[VerifyProblem] = []
        checked_blobs: dict[str, str | None] = {}
        for art_id in ids:
            path = self._manifest_path(art_id)
            try:
                manifest = json.loads(path.read_bytes())
                if manifest.get("id") != art_id or artifact_id(manifest) != art_id:
                    problems.append(VerifyProblem(art_id, "manifest does not match its id (modified)"))
                    continue
            except (OSError, ValueError, KeyError, TypeError) as exc:
                problems.append(VerifyProblem(art_id, f"manifest unreadable: {exc}"))
                continue
            for name, info in sorted(manifest["files"].items()):
                digest = info["sha256"]
                if digest not in checked_blobs:
                    blob = self._blob_path(digest)
                    if not blob.is_file():
                        checked_blobs[digest] = "missing"
                    else:
                        actual, size = sha256_file(blob)
                        checked_blobs[digest] = None if actual == digest and size == info["size"] else "corrupted"
                if checked_blobs[digest]:
                    problems.append(VerifyProblem(art_id, f"file {name!r}: blob {digest[:12]} {checked_blobs[digest]}"))
            for input_id in manifest["inputs"]:
                if not self._manifest_path(input_id).is_file():
                    problems.append(VerifyProblem(art_id, f"input {input_id[:12]} is missing"))
        if refs is None:
            for alias, target in self.refs().items():
                if not self._manifest_path(target).is_file():
                    problems.append(VerifyProblem(None, f"alias {alias!r} points to missing artifact {target[:12]}"))
        return problems

    def gc(self, dry_run: bool = False) -> GcReport:
        """Remove artifacts and blobs that no alias reaches (directly or as an input), and temp files."""
        report = GcReport(dry_run=dry_run)
        if not self.root.is_dir():
            return report
        with self._lock(exclusive=True):
            live: set[str] = set()
            stack = [t for t in self.refs().values() if self._manifest_path(t).is_file()]
            while stack:
                art_id = stack.pop()
                if art_id in live:
                    continue
                live.add(art_id)
                stack.extend(i for i in self.get(art_id).inputs if self._manifest_path(i).is_file())
            live_blobs = {f["sha256"] for i in live for f in self.get(i).files.values()}
            for art_id in self._all_ids():
                if art_id not in live:
                    report.artifacts.append(art_id)
            for blob in sorted(self._objects.glob("??/*")):
                if blob.name not in live_blobs:
                    report.blobs.append(blob.name)
                    report.bytes_freed += blob.stat().st_size
            # with the exclusive lock held no writer is alive, so every temp file is an orphan
            temps = sorted(self._tmp.iterdir())
            report.temp_files = [t.name for t in temps]
            report.bytes_freed += sum(t.stat().st_size for t in temps)
            if not dry_run:
                for art_id in report.artifacts:
                    self._manifest_path(art_id).unlink()
                for digest in report.blobs:
                    self._blob_path(digest).unlink()
                for tmp in temps:
                    if tmp.is_dir():
                        shutil.rmtree(tmp)
                    else:
                        tmp.unlink()
        return report


class ArtifactWriter:
    """Collects an artifact's files in temp storage; commits them atomically on success.

    Use `store.create(...)` as a context manager. An exception inside the block discards
    everything written; the artifact appears only when the block exits cleanly.
    """

    def __init__(self, store: Store, kind: str, inputs: list[str], config: Any, seed: int | None,
                 labels: dict[str, Any], command: list[str] | None):
        if not re.match(r"^[a-z][a-z0-9_-]*$", kind):
            raise UsageError(f"invalid artifact kind {kind!r}")
        self.store = store
        self.kind = kind
        self.inputs = inputs
        self.config = config
        self.seed = seed
        self.labels = labels
        self.command = command
        self._files: dict[str, dict[str, Any]] = {}
        self._blobs: dict[str, Path] = {}
        self._lock_cm: contextlib.AbstractContextManager | None = None
        self.artifact: Artifact | None = None

    def __enter__(self) -> "ArtifactWriter":
        self._lock_cm = self.store._lock(exclusive=False)
        self._lock_cm.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                manifest = {
                    "format": MANIFEST_FORMAT,
                    "kind": self.kind,
                    "files": self._files,
                    "inputs": self.inputs,
                    "config": self.config,
                    "seed": self.seed,
                    "labels": self.labels,
                    "provenance": provenance(self.command),
                }
                canonical_json(manifest)  # fail early on values JSON cannot hold (NaN, objects)
                self.artifact = self.store._commit(manifest, self._blobs)
        finally:
            for tmp in self._blobs.values():
                tmp.unlink(missing_ok=True)
            assert self._lock_cm is not None
            self._lock_cm.__exit__(None, None, None)

    def _check_name(self, name: str) -> None:
        if not FILE_NAME.match(name) or ".." in name.split("/"):
            raise UsageError(f"invalid file name {name!r} in artifact")
        if name in self._files:
            raise UsageError(f"file {name!r} added twice to the artifact")

    @contextlib.contextmanager
    def open(self, name: str) -> Iterator[IO[bytes]]:
        """A binary file to write `name` into, hashed as it is written."""
        if self._lock_cm is None:
            raise UsageError("use the writer as a context manager: with store.create(...) as w")
        self._check_name(name)
        fh, tmp = self.store._temp_file()
        writer = _HashingWriter(fh)
        try:
            yield writer  # type: ignore[misc]
            fh.flush()
            os.fsync(fh.fileno())
        except BaseException:
            fh.close()
            tmp.unlink(missing_ok=True)
            raise
        fh.close()
        digest = writer.hexdigest()
        if digest in self._blobs:
            tmp.unlink()
        else:
            self._blobs[digest] = tmp
        self._files[name] = {"sha256": digest, "size": writer.size}

    def add_bytes(self, name: str, data: bytes) -> None:
        with self.open(name) as fh:
            fh.write(data)

    def add_json(self, name: str, obj: Any) -> None:
        self.add_bytes(name, canonical_json(obj))

    def add_file(self, name: str, src: str | os.PathLike[str]) -> None:
        with self.open(name) as fh, open(src, "rb") as source:
            while chunk := source.read(CHUNK):
                fh.write(chunk)
