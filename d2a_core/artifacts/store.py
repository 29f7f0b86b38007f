"""A content-addressed artifact store on a local filesystem.

Layout under the store root::

    objects/ab/abcdef...        immutable blobs named by their sha256 (read-only files)
    manifests/ab/<id>.json      one canonical manifest per artifact (read-only)
    refs/<alias>.ref            aliases such as track/hairpin -> an artifact id
    leases/<pid>-<token>.json   artifacts a live process is using (flock-ed by that process)
    runs/<key>/holds.json       artifacts a (possibly killed) training run's state points at
    quarantine/<when>/...       unreadable files moved aside by `verify --repair`
    tmp/                        files being written (same filesystem, so renames are atomic)
    lock                        flock: writers share it, gc takes it exclusively

Safety: every file is written to tmp/, fsynced, then renamed into place, so a reader never sees
half a file. An artifact becomes visible only when its manifest lands, after all its blobs; a
ref is written only to an existing manifest. A process killed mid-write leaves only orphan
temp files, which `gc` removes. Writers hold a shared lock while they write and `gc` an
exclusive one, so gc never deletes a blob that a live writer is about to reference.

What gc keeps (its roots): every alias, every live lease (`Store.lease()`: a process that is
building something from several artifacts registers each one it creates or resolves, so nothing
it still needs disappears between two steps), and every run hold (`Store.hold_run()`: a run's
saved state names artifacts it resumes from, after its process is gone). If gc cannot read one
of its roots it deletes nothing: it cannot tell what that root protects.

Reads check hashes: a manifest is re-hashed against its id when it is loaded, and a blob when
`path()`, `read_bytes()` or `export()` hands it out.

Leases and run holds live in `leases.py`, verify and gc in `upkeep.py`, filesystem helpers in
`fsutil.py`; `docs/reliability.md` states the promises.
"""

from __future__ import annotations

import contextlib
import difflib
import fcntl
import hashlib
import json
import os
import re
import secrets
import shutil
import tempfile
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

from d2a_core.artifacts.manifest import (
    IDENTITY_FIELDS,
    MANIFEST_FORMAT,
    Artifact,
    artifact_id,
    canonical_json,
    provenance,
)
from d2a_core.artifacts import upkeep
from d2a_core.artifacts.fsutil import CHUNK, BadFile, fsync_dir, os_reason, sha256_file, storage_errors
from d2a_core.artifacts.leases import FULL_ID, HOLDS_FILE, HOLDS_FORMAT, Lease, read_run_holds
from d2a_core.artifacts.upkeep import SCRATCH_LOCK, SCRATCH_PREFIX, GcReport, VerifyProblem
from d2a_core.errors import AmbiguousRefError, IntegrityError, NotFoundError, StoreError, UsageError

HEX = re.compile(r"^[0-9a-f]+$")
REF_CONTENT = re.compile(r"^([0-9a-f]{64})\n?$")  # exactly what tag() writes: any flipped byte fails
ALIAS = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*(/[A-Za-z0-9][A-Za-z0-9_.+-]*)*$")
FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*(/[A-Za-z0-9][A-Za-z0-9_.+-]*)*$")


def valid_file_name(name: object) -> bool:
    """A file name an artifact may hold: relative, '/'-separated, never climbing out."""
    return isinstance(name, str) and bool(FILE_NAME.match(name)) and ".." not in name.split("/")


MIN_PREFIX = 4


def alias_problem(alias: str) -> str | None:
    """Why `alias` cannot be an alias, or None. Used up front by commands that will tag."""
    if not ALIAS.match(alias) or any(part in (".", "..") for part in alias.split("/")):
        return "use letters, digits, '._+-' in '/'-separated parts, each starting with a letter or digit"
    if HEX.match(alias) and len(alias) >= MIN_PREFIX:
        return "a hex string would read as an artifact id"
    return None


class _HashingWriter:
    """A binary file object that hashes what it writes (so a blob is hashed in one pass)."""

    def __init__(self, fh: IO[bytes], path: Path):
        self._fh = fh
        self._path = path
        self._digest = hashlib.sha256()
        self.size = 0

    def write(self, data: bytes) -> int:
        self._digest.update(data)
        self.size += len(data)
        with storage_errors("cannot write to the store", self._path):
            return self._fh.write(data)

    def flush(self) -> None:
        with storage_errors("cannot write to the store", self._path):
            self._fh.flush()

    def hexdigest(self) -> str:
        return self._digest.hexdigest()

    # torch.save and numpy.save only need write/flush; seekable() = False makes torch stream.
    def seekable(self) -> bool:
        return False

    def writable(self) -> bool:
        return True


def _fsync_file(path: Path) -> None:
    with storage_errors("cannot write to the store", path), open(path, "rb") as fh:
        os.fsync(fh.fileno())


class Store:
    """The artifact store rooted at `root` (created on first write)."""

    def __init__(self, root: str | os.PathLike[str]):
        self.root = Path(root)
        self._lock_depth = 0
        self._lock_fd: int | None = None
        self._lease: Lease | None = None
        self._verified: dict[str, tuple[int, int, int, int]] = {}  # blob -> stat it was hashed at

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

    @property
    def _leases(self) -> Path:
        return self.root / "leases"

    @property
    def _runs(self) -> Path:
        return self.root / "runs"

    def _blob_path(self, digest: str) -> Path:
        return self._objects / digest[:2] / digest

    def _manifest_path(self, art_id: str) -> Path:
        return self._manifests / art_id[:2] / f"{art_id}.json"

    def _ref_path(self, alias: str) -> Path:
        return self._refs / f"{alias}.ref"

    def run_dir(self, key: str) -> Path:
        """The directory a training run keeps its resumable state in."""
        if not re.match(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$", key):
            raise UsageError(f"invalid run key {key!r}")
        return self._runs / key

    def live_log_dir(self, name: str) -> Path:
        """`logs/<name>/`: what a run writes while it trains (live curves for TensorBoard). Not
        part of any artifact; `name` is a relative path of plain components."""
        parts = name.split("/")
        if not all(re.match(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$", part) for part in parts):
            raise UsageError(f"invalid live log name {name!r}")
        return self.root / "logs" / Path(*parts)

    def _check_root(self) -> None:
        """Reads of a store path that is a file must fail, not report an empty store."""
        if self.root.exists() and not self.root.is_dir():
            raise StoreError(f"store {self.root} is not a directory")

    def _ensure_layout(self) -> None:
        self._check_root()
        for path in (self._objects, self._manifests, self._refs, self._tmp, self._leases):
            with storage_errors(f"cannot create the store layout in {self.root}", path):
                path.mkdir(parents=True, exist_ok=True)

    @contextlib.contextmanager
    def _lock(self, exclusive: bool, write: bool = True) -> Iterator[None]:
        """The store lock (re-entrant within this Store object: shared inside shared is a no-op).

        `write=False` (gc --dry-run) also works on a read-only store: nothing can write there.
        """
        if self._lock_depth:
            # flock cannot upgrade in place, and gc or repair inside a write is a programming error
            assert not exclusive, "exclusive store lock requested while this Store holds it shared"
            self._lock_depth += 1
            try:
                yield
            finally:
                self._lock_depth -= 1
            return
        lock_path = self.root / "lock"
        if write:
            self._ensure_layout()
            with storage_errors("cannot open the store lock", lock_path):
                fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        else:
            self._check_root()
            try:
                fd = os.open(lock_path, os.O_RDONLY)
            except OSError:
                fd = -1  # no lock file (never written) or unreadable: no writer can be using it
        try:
            if fd >= 0:
                fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            self._lock_depth = 1
            yield
        finally:
            self._lock_depth = 0
            if fd >= 0:
                fcntl.flock(fd, fcntl.LOCK_UN)
                os.close(fd)

    @contextlib.contextmanager
    def scratch_dir(self, prefix: str) -> Iterator[Path]:
        """A private directory inside the store's tmp/ for files on their way into artifacts
        (episode logs). It is removed on exit; a killed command's is left for `gc`, which
        removes it once no process holds its lock."""
        self._ensure_layout()
        with storage_errors("cannot create a scratch directory", self._tmp):
            path = Path(tempfile.mkdtemp(dir=self._tmp, prefix=f"{SCRATCH_PREFIX}{prefix}-"))
            fd = os.open(path / SCRATCH_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield path
        finally:
            shutil.rmtree(path, ignore_errors=True)
            os.close(fd)

    def _temp_file(self, suffix: str = "") -> tuple[IO[bytes], Path]:
        with storage_errors("cannot write to the store", self._tmp):
            fd, name = tempfile.mkstemp(dir=self._tmp, prefix=f"{os.getpid()}-", suffix=suffix)
        return os.fdopen(fd, "wb"), Path(name)

    def _blob_ok(self, path: Path, digest: str) -> bool:
        try:
            return sha256_file(path)[0] == digest
        except OSError:
            return False

    def _manifest_ok(self, path: Path, art_id: str) -> bool:
        try:
            self._parse_manifest(path.read_bytes(), art_id)
            return True
        except (OSError, BadFile):
            return False

    def _install(self, tmp: Path, final: Path, valid) -> None:
        """Move a complete, fsynced temp file into place read-only.

        An existing copy is kept when `valid(final)` (content-addressed, so it is equal) and
        replaced when it is not: a rebuild repairs a corrupted blob or manifest.
        """
        with storage_errors("cannot write to the store", final):
            final.parent.mkdir(parents=True, exist_ok=True)
            os.chmod(tmp, 0o444)
            try:
                os.link(tmp, final)  # fails if present
            except FileExistsError:
                if not valid(final):
                    os.replace(tmp, final)
                    fsync_dir(final.parent)
            else:
                fsync_dir(final.parent)
            finally:
                tmp.unlink(missing_ok=True)

    # ----------------------------------------------------------------------------- leases
    @contextlib.contextmanager
    def lease(self) -> Iterator[Lease]:
        """Hold every artifact this Store creates, resolves or tags inside the block against gc.

        Re-entrant. The lease ends with the block, or with the process: a killed process's
        lock is released by the kernel and gc then removes its lease file.
        """
        if self._lease is not None:
            self._lease.depth += 1
            try:
                yield self._lease
            finally:
                self._lease.depth -= 1
            return
        with self._lock(exclusive=False):
            # created and locked under the store lock, so gc never sees it unlocked
            path = self._leases / f"{os.getpid()}-{secrets.token_hex(6)}.json"
            with storage_errors("cannot write to the store", path):
                fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
                fcntl.flock(fd, fcntl.LOCK_EX)
                lease = Lease(path, fd)
                lease.write()
        self._lease = lease
        try:
            yield lease
        finally:
            self._lease = None
            with contextlib.suppress(OSError):
                path.unlink()
            os.close(fd)

    def _register(self, art_id: str) -> None:
        """Add an id to the active lease; call with the store lock held."""
        lease = self._lease
        if lease is None or art_id in lease.ids:
            return
        lease.ids.append(art_id)
        with storage_errors("cannot write to the store", lease.path):
            lease.write()

    def _hold(self, art_id: str, ref: str) -> None:
        """Register a resolved id in the active lease, then make sure gc had not removed it already."""
        if self._lease is None or art_id in self._lease.ids:
            return
        with self._lock(exclusive=False):
            self._register(art_id)
            if not self._manifest_path(art_id).is_file():
                raise NotFoundError(f"{ref!r}: artifact {art_id} was removed from store {self.root} meanwhile")

    # ----------------------------------------------------------------------------- run holds
    def hold_run(self, key: str, ids: Iterable[str]) -> None:
        """Record that run `key`'s saved state points at `ids`: gc keeps them until release_run.

        Writes `runs/<key>/holds.json` = {"format": 1, "artifacts": [ids]} atomically. Call it
        *before* saving a state that names a new artifact, so the holds always cover the state.
        """
        ids = list(dict.fromkeys(ids))
        path = self.run_dir(key) / HOLDS_FILE
        with self._lock(exclusive=False):
            missing = [i for i in ids if not FULL_ID.match(i) or not self._manifest_path(i).is_file()]
            if missing:
                raise NotFoundError(f"run {key[:12]}: cannot hold {', '.join(m[:12] for m in missing)}: "
                                    f"not in store {self.root}")
            for art_id in ids:
                self._register(art_id)
            with storage_errors("cannot write the run state", path):
                path.parent.mkdir(parents=True, exist_ok=True)
                fh, tmp = self._temp_file(".holds")
                with fh:
                    fh.write(canonical_json({"format": HOLDS_FORMAT, "artifacts": ids}))
                    fh.flush()
                    os.fsync(fh.fileno())
                os.replace(tmp, path)
                fsync_dir(path.parent)

    def release_run(self, key: str) -> None:
        """Drop run `key`'s holds (its artifacts stay while an alias or another root reaches them)."""
        path = self.run_dir(key) / HOLDS_FILE
        with self._lock(exclusive=False), storage_errors("cannot write the run state", path):
            path.unlink(missing_ok=True)

    def run_holds(self) -> tuple[dict[str, list[str]], list[VerifyProblem]]:
        """Each run key -> the ids its holds.json names, and the holds files that cannot be read."""
        holds, bad = read_run_holds(self._runs)
        return holds, [VerifyProblem(None, f"run holds file unreadable ({why})", path=str(path)) for path, why in bad]

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
        """Land blobs, then the manifest. Called with the shared store lock held."""
        # an input resolved before the lock may have been collected since: refuse a dangling lineage
        gone = [i for i in manifest["inputs"] if not self._manifest_path(i).is_file()]
        if gone:
            raise NotFoundError(f"input artifact(s) {', '.join(g[:12] for g in gone)} left store {self.root} "
                                "while this artifact was being written")
        for digest, tmp in blobs.items():
            self._install(tmp, self._blob_path(digest), lambda p, d=digest: self._blob_ok(p, d))
        art_id = artifact_id(manifest)
        stored = dict(manifest, id=art_id)
        # the id covers only the identity; this covers every byte, provenance included
        stored["sha256"] = hashlib.sha256(canonical_json(stored)).hexdigest()
        fh, tmp = self._temp_file(".json")
        with fh, storage_errors("cannot write to the store", tmp):
            fh.write(canonical_json(stored))
            fh.flush()
            os.fsync(fh.fileno())
        self._install(tmp, self._manifest_path(art_id), lambda p: self._manifest_ok(p, art_id))
        self._register(art_id)
        return self.get(art_id)

    # ----------------------------------------------------------------------------- reading
    def _all_ids(self) -> list[str]:
        self._check_root()
        if not self._manifests.is_dir():
            return []
        return sorted(p.stem for p in self._manifests.glob("??/*.json") if FULL_ID.match(p.stem))

    def count(self) -> int:
        """How many manifests the store holds (readable or not)."""
        return len(self._all_ids())

    def _read_ref_file(self, path: Path) -> str:
        try:
            text = path.read_bytes().decode("ascii")
        except IsADirectoryError:
            raise BadFile("is a directory, not an alias file") from None
        except OSError as exc:
            raise BadFile(f"cannot be read ({os_reason(exc)})") from None
        except UnicodeDecodeError:
            raise BadFile("does not hold an artifact id (binary data)") from None
        match = REF_CONTENT.match(text)
        if not match:
            raise BadFile(f"does not hold an artifact id ({text.strip()[:20]!r})")
        return match.group(1)

    def _scan_refs(self) -> tuple[dict[str, str], list[VerifyProblem]]:
        """Readable aliases -> ids, and a problem for each alias file that cannot be read."""
        self._check_root()
        good: dict[str, str] = {}
        bad: list[VerifyProblem] = []
        if not self._refs.is_dir():
            return good, bad
        for path in sorted(self._refs.rglob("*.ref")):
            alias = path.relative_to(self._refs).as_posix()[: -len(".ref")]
            try:
                good[alias] = self._read_ref_file(path)
            except BadFile as exc:
                bad.append(VerifyProblem(None, f"alias {alias!r}: {path} {exc}", alias=alias, path=str(path)))
        return dict(sorted(good.items())), bad

    def refs(self) -> dict[str, str]:
        """All readable aliases and the ids they point to (`verify` reports the unreadable ones)."""
        return self._scan_refs()[0]

    def resolve(self, ref: str) -> str:
        """An alias, a full id or a unique id prefix -> the full artifact id."""
        ref = ref.strip()
        self._check_root()
        if ALIAS.match(ref):
            path = self._ref_path(ref)
            if path.exists() or path.is_symlink():
                try:
                    art_id = self._read_ref_file(path)
                except BadFile as exc:
                    raise IntegrityError(
                        f"alias {ref!r}: {path} {exc}; re-tag it (d2a artifacts tag ID {ref}) or run "
                        "d2a artifacts verify --repair") from None
                if not self._manifest_path(art_id).is_file():
                    raise IntegrityError(
                        f"alias {ref!r} points to artifact {art_id[:12]}, which is not in store {self.root} "
                        "(collected or quarantined); rebuild it or remove the alias with verify --repair")
                self._hold(art_id, ref)
                return art_id
        if HEX.match(ref) and len(ref) >= MIN_PREFIX:
            if len(ref) == 64 and self._manifest_path(ref).is_file():
                self._hold(ref, ref)
                return ref
            matches = [i for i in self._all_ids() if i.startswith(ref)]
            if len(matches) == 1:
                self._hold(matches[0], ref)
                return matches[0]
            if len(matches) > 1:
                shown = ", ".join(m[:12] for m in matches[:5])
                raise AmbiguousRefError(f"id prefix {ref!r} is ambiguous: it matches {len(matches)} artifacts "
                                        f"({shown}); give more characters")
        known = list(self.refs()) + [i[:12] for i in self._all_ids()]
        close = difflib.get_close_matches(ref, known, n=3, cutoff=0.5)
        if HEX.match(ref) and len(ref) < MIN_PREFIX:
            close = [i for i in known if i.startswith(ref)][:3] or close
            hint = f"; an id prefix needs at least {MIN_PREFIX} characters"
            hint += f" (ids starting with it: {', '.join(close)})" if close else ""
        else:
            hint = f"; closest known: {', '.join(close)}" if close else ""
        raise NotFoundError(f"no artifact or alias {ref!r} in store {self.root}{hint}")

    def _parse_manifest(self, data: bytes, art_id: str) -> dict[str, Any]:
        try:
            manifest = json.loads(data)
        except (ValueError, UnicodeDecodeError) as exc:
            raise BadFile(f"manifest is not valid JSON ({exc})") from None
        if not isinstance(manifest, dict) or any(k not in manifest for k in (*IDENTITY_FIELDS, "id", "provenance")):
            raise BadFile("manifest is incomplete")
        # a flipped bit in the key "sha256" would otherwise pass for an older manifest without a
        # checksum and skip the check below: any key beyond the known ones is damage
        unknown = set(manifest) - {*IDENTITY_FIELDS, "id", "provenance", "sha256"}
        if unknown:
            raise BadFile(f"manifest has unknown fields {', '.join(sorted(unknown))} (modified)")
        try:
            actual = artifact_id(manifest)
        except (TypeError, ValueError) as exc:
            raise BadFile(f"manifest is not canonical ({exc})") from None
        if manifest["id"] != art_id or actual != art_id:
            raise BadFile("manifest does not match its id (modified)")
        if not isinstance(manifest["files"], dict) or not isinstance(manifest["inputs"], list):
            raise BadFile("manifest is malformed")
        # names become paths on export: one that is absolute or climbs out (a forged manifest)
        # must never be read as a file name
        bad = [name for name in manifest["files"] if not valid_file_name(name)]
        if bad:
            raise BadFile(f"manifest names files outside the artifact ({', '.join(repr(b) for b in bad[:3])})")
        for info in manifest["files"].values():
            if not (isinstance(info, dict) and isinstance(info.get("sha256"), str) and FULL_ID.match(info["sha256"])
                    and isinstance(info.get("size"), int)):
                raise BadFile("manifest has a malformed file entry")
        if not all(isinstance(i, str) and FULL_ID.match(i) for i in manifest["inputs"]):
            raise BadFile("manifest has a malformed input id")
        # written canonically with a checksum of the whole file, so a flipped byte anywhere (the
        # unhashed provenance too) is caught; manifests from before the checksum only get the id check
        if "sha256" in manifest:
            body = {k: v for k, v in manifest.items() if k != "sha256"}
            if data != canonical_json(manifest) or hashlib.sha256(canonical_json(body)).hexdigest() != manifest["sha256"]:
                raise BadFile("manifest does not match its checksum (modified)")
        prov = manifest["provenance"]
        if not isinstance(prov, dict) or not isinstance(prov.get("created"), str):
            raise BadFile("manifest provenance is damaged")
        return manifest

    def parse_manifest(self, data: bytes, art_id: str) -> dict[str, Any]:
        """A manifest from elsewhere (a bundle), checked as strictly as the store's own: BadFile
        names what is wrong with it."""
        return self._parse_manifest(data, art_id)

    def manifest_bytes(self, ref: str) -> bytes:
        """The stored manifest of an artifact, byte for byte (after checking it)."""
        art_id = self.get(ref).id
        with storage_errors("cannot read the manifest", self._manifest_path(art_id)):
            return self._manifest_path(art_id).read_bytes()

    def has(self, art_id: str) -> bool:
        """Whether the store holds a readable manifest with this full id."""
        try:
            self._load_manifest(art_id)
            return True
        except (NotFoundError, IntegrityError, StoreError):
            return False

    def adopt(self, ids: list[str], manifests: dict[str, dict[str, Any]], manifest_dir: Path, blob_dir: Path) -> None:
        """Land artifacts checked elsewhere (`bundle.unpack`): their blobs from `blob_dir/<sha256>`,
        then their manifests from `manifest_dir/<id>.json`, each after its inputs, the way the
        store lands its own (a killed import leaves only orphan temp files). The files are moved."""
        order: list[str] = []
        seen: set[str] = set()

        def visit(art_id: str) -> None:
            if art_id in seen or art_id not in manifests:
                return
            seen.add(art_id)
            for parent in manifests[art_id]["inputs"]:
                visit(parent)
            order.append(art_id)

        for art_id in ids:
            visit(art_id)
        with self.lease(), self._lock(exclusive=False):
            for art_id in order:
                for info in manifests[art_id]["files"].values():
                    blob = blob_dir / info["sha256"]
                    if blob.exists():
                        _fsync_file(blob)
                        self._install(blob, self._blob_path(info["sha256"]),
                                      lambda p, d=info["sha256"]: self._blob_ok(p, d))
            for art_id in order:
                gone = [i for i in manifests[art_id]["inputs"] if not self._manifest_path(i).is_file()]
                if gone:
                    raise NotFoundError(f"input artifact {gone[0][:12]} of {art_id[:12]} left store {self.root} "
                                        "during the import")
                path = manifest_dir / f"{art_id}.json"
                _fsync_file(path)
                self._install(path, self._manifest_path(art_id), lambda p, a=art_id: self._manifest_ok(p, a))
                self._register(art_id)

    def _load_manifest(self, art_id: str, ref: str | None = None) -> dict[str, Any]:
        path = self._manifest_path(art_id)
        named = f"{ref!r} ({art_id[:12]})" if ref and ref != art_id else art_id
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise NotFoundError(f"artifact {named} is not in store {self.root}") from None
        except OSError as exc:
            raise StoreError(f"cannot read artifact {named}: {path}: {os_reason(exc)}") from None
        try:
            return self._parse_manifest(data, art_id)
        except BadFile as exc:
            raise IntegrityError(f"artifact {named}: {exc}; run d2a artifacts verify --repair") from None

    def get(self, ref: str) -> Artifact:
        art_id = self.resolve(ref)
        return Artifact(art_id, self._load_manifest(art_id, ref))

    def _checked_blob(self, art: Artifact, name: str, ref: str) -> Path:
        """The blob of one file, re-hashed unless it was hashed unchanged before in this process."""
        info = art.files[name]
        path = self._blob_path(info["sha256"])
        named = f"artifact {art.id[:12]}" + (f" ({ref})" if ref != art.id else "")
        try:
            st = path.stat()
        except FileNotFoundError:
            raise IntegrityError(f"{named}: the blob of file {name!r} is missing; rebuild the artifact") from None
        except OSError as exc:
            raise StoreError(f"cannot read {named}: {path}: {os_reason(exc)}") from None
        stamp = (st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        if self._verified.get(info["sha256"]) == stamp:
            return path
        if st.st_size != info["size"] or not self._blob_ok(path, info["sha256"]):
            raise IntegrityError(f"{named}: file {name!r} does not match its hash (corrupted blob "
                                 f"{info['sha256'][:12]}); run d2a artifacts verify --repair, then rebuild it")
        self._verified[info["sha256"]] = stamp
        return path

    def path(self, ref: str, name: str) -> Path:
        """Read-only path of one file of an artifact (for np.load, torch.load, ...), hash-checked."""
        art = self.get(ref)
        if name not in art.files:
            raise NotFoundError(f"artifact {art.id[:12]} ({art.kind}) has no file {name!r}; files: {sorted(art.files)}")
        return self._checked_blob(art, name, ref)

    def is_whole(self, ref: str) -> bool:
        """Whether the artifact and everything in its lineage still have every manifest and blob
        (of the recorded size) in the store. `verify --repair` moves damaged files to quarantine;
        a command that finds its result not whole builds it again instead of reusing it."""
        seen: set[str] = set()
        stack = [self.resolve(ref)]
        while stack:
            art_id = stack.pop()
            if art_id in seen:
                continue
            seen.add(art_id)
            try:
                art = Artifact(art_id, self._load_manifest(art_id))
            except (NotFoundError, IntegrityError):
                return False
            for info in art.files.values():
                try:
                    if self._blob_path(info["sha256"]).stat().st_size != info["size"]:
                        return False
                except OSError:
                    return False
            stack.extend(art.inputs)
        return True

    def read_bytes(self, ref: str, name: str, verify: bool = True) -> bytes:
        art = self.get(ref)
        if name not in art.files:
            raise NotFoundError(f"artifact {art.id[:12]} ({art.kind}) has no file {name!r}; files: {sorted(art.files)}")
        path = self._blob_path(art.files[name]["sha256"])
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise IntegrityError(f"artifact {art.id}: the blob of file {name!r} is missing; rebuild it") from None
        except OSError as exc:
            raise StoreError(f"cannot read artifact {art.id[:12]}: {path}: {os_reason(exc)}") from None
        if verify and hashlib.sha256(data).hexdigest() != art.files[name]["sha256"]:
            raise IntegrityError(f"artifact {art.id}: file {name!r} does not match its hash")
        return data

    def read_json(self, ref: str, name: str) -> Any:
        return json.loads(self.read_bytes(ref, name))

    def export(self, ref: str, directory: str | os.PathLike[str]) -> list[Path]:
        """Copy an artifact's files, under their own names, into `directory` (e.g. to open a log).

        Each copy is hashed as it is written and removed again if it does not match.
        """
        art = self.get(ref)
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise UsageError(f"export destination {directory} exists and is not a directory")
        out = []
        target = directory.resolve()
        for name in sorted(art.files):
            src = self._blob_path(art.files[name]["sha256"])
            dst = directory / name
            # a link already in the destination must not carry a copy outside it either
            if not dst.resolve().is_relative_to(target):
                raise UsageError(f"export destination {dst} leads outside {directory} (a link?); nothing more "
                                 "was exported")
            if dst.is_dir():
                raise UsageError(f"export destination {dst} is a directory")
            with storage_errors(f"cannot export {name!r}", dst):
                dst.parent.mkdir(parents=True, exist_ok=True)
                digest = hashlib.sha256()
                try:
                    source = open(src, "rb")
                except FileNotFoundError:
                    raise IntegrityError(f"artifact {art.id}: the blob of file {name!r} is missing") from None
                with source, open(dst, "wb") as sink:
                    while chunk := source.read(CHUNK):
                        digest.update(chunk)
                        sink.write(chunk)
            if digest.hexdigest() != art.files[name]["sha256"]:
                dst.unlink(missing_ok=True)
                raise IntegrityError(f"artifact {art.id[:12]}: file {name!r} does not match its hash (corrupted "
                                     "blob); nothing was exported for it. Run d2a artifacts verify --repair")
            out.append(dst)
        return out

    def list(self, kind: str | None = None, unreadable: list[str] | None = None) -> list[Artifact]:
        """Artifacts (optionally of one kind), oldest first. Unreadable manifests are skipped
        (their ids go to `unreadable` when given); `verify` reports them."""
        arts = []
        for art_id in self._all_ids():
            try:
                arts.append(Artifact(art_id, self._load_manifest(art_id)))
            except (IntegrityError, NotFoundError, StoreError):
                if unreadable is not None:
                    unreadable.append(art_id)
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

    def finished(self, kind: str, run_key: str) -> Artifact | None:
        """The latest whole artifact of `kind` that a run with this key stored (its `run_key`
        label), or None: how a command finds its own earlier result instead of redoing it."""
        done = [a for a in self.list(kind) if a.labels.get("run_key") == run_key and self.is_whole(a.id)]
        return done[-1] if done else None

    def aliases_of(self, art_id: str) -> list[str]:
        return [alias for alias, target in self.refs().items() if target == art_id]

    def lineage(self, ref: str) -> dict[str, Any]:
        """The artifact and its inputs, recursively: {id, kind, aliases, inputs: [...]}."""
        refs = self.refs()
        seen: dict[str, dict[str, Any]] = {}

        def node(art_id: str) -> dict[str, Any]:
            if art_id in seen:  # a DAG can share inputs; show each once in full
                return {"id": art_id, "kind": seen[art_id]["kind"], "shared": True}
            try:
                art = Artifact(art_id, self._load_manifest(art_id))
            except (IntegrityError, NotFoundError) as exc:  # show the damage, keep the rest of the tree
                return {"id": art_id, "kind": "?", "aliases": [], "labels": {}, "inputs": [], "problem": str(exc)}
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
    def point_aliases(self, targets: dict[str, str]) -> list[dict[str, str]]:
        """Point each alias at its artifact (tagging only those that point elsewhere) and return
        the ones that named another artifact before, as `{"alias", "previous", "now"}`."""
        moved = []
        for alias, art_id in targets.items():
            try:
                previous = self.resolve(alias)
            except NotFoundError:
                previous = None
            if previous != art_id:
                self.tag(art_id, alias)
                if previous is not None:
                    moved.append({"alias": alias, "previous": previous, "now": art_id})
        return moved

    def tag(self, ref: str, alias: str) -> str:
        """Point `alias` at the artifact `ref` resolves to (atomically replacing an old target)."""
        problem = alias_problem(alias)
        if problem:
            raise UsageError(f"invalid alias {alias!r}: {problem}")
        art_id = self.get(ref).id
        with self._lock(exclusive=False):
            # checked under the lock: gc cannot collect it between this check and the ref landing
            if not self._manifest_path(art_id).is_file():
                raise NotFoundError(f"artifact {art_id[:12]} ({ref}) was removed from store {self.root} meanwhile")
            self._register(art_id)
            # refs live in '<alias>.ref' files, so 'a/b' and 'a/b/c' can coexist
            path = self._ref_path(alias)
            if path.is_dir():
                raise IntegrityError(f"alias {alias!r}: {path} is a directory; run d2a artifacts verify --repair")
            with storage_errors(f"cannot write alias {alias!r}", path):
                path.parent.mkdir(parents=True, exist_ok=True)
                fh, tmp = self._temp_file(".ref")
                with fh:
                    fh.write(art_id.encode("ascii") + b"\n")
                    fh.flush()
                    os.fsync(fh.fileno())
                os.replace(tmp, path)
                fsync_dir(path.parent)
        return art_id

    def untag(self, alias: str) -> None:
        path = self._ref_path(alias)
        if not path.is_file():
            raise NotFoundError(f"no alias {alias!r} in store {self.root}")
        with self._lock(exclusive=False), storage_errors(f"cannot remove alias {alias!r}", path):
            path.unlink()

    # ----------------------------------------------------------------------------- upkeep
    def verify(self, refs: Iterable[str] | None = None, repair: bool = False) -> list[VerifyProblem]:
        """Re-hash manifests and blobs; report every corrupted or incomplete artifact, alias and
        run hold. `repair=True` moves what cannot be used into `quarantine/` (see upkeep.verify)."""
        return upkeep.verify(self, refs, repair)

    def gc(self, dry_run: bool = False) -> GcReport:
        """Remove what no alias, live lease or run hold reaches, and temp files (see upkeep.gc)."""
        return upkeep.gc(self, dry_run)


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
        self._notes: dict[str, Any] = {}
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
                    "provenance": {**provenance(self.command), **({"notes": self._notes} if self._notes else {})},
                }
                try:
                    canonical_json(manifest)  # fail early on values JSON cannot hold (NaN, objects)
                except ValueError as error:
                    raise UsageError(f"artifact of kind {self.kind!r} cannot be stored: {error} "
                                     "(a config value or label is NaN or infinite)") from None
                self.artifact = self.store._commit(manifest, self._blobs)
        finally:
            for tmp in self._blobs.values():
                tmp.unlink(missing_ok=True)
            assert self._lock_cm is not None
            self._lock_cm.__exit__(None, None, None)

    def note(self, key: str, value: Any) -> None:
        """Record `value` (JSON) under `provenance.notes.<key>`: facts about how the artifact was
        made that must not change its id, such as wall-clock timings."""
        self._notes[key] = value

    def _check_name(self, name: str) -> None:
        if not valid_file_name(name):
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
        writer = _HashingWriter(fh, tmp)
        try:
            yield writer  # type: ignore[misc]
            with storage_errors("cannot write to the store", tmp):
                fh.flush()
                os.fsync(fh.fileno())
        except BaseException:
            with contextlib.suppress(OSError):
                fh.close()
            tmp.unlink(missing_ok=True)
            raise
        with storage_errors("cannot write to the store", tmp):
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
