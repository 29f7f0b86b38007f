"""Store upkeep: `verify` (re-hash everything, report every problem, optionally quarantine what
cannot be used) and `gc` (remove what none of the store's roots reaches).

gc's roots are aliases, live leases and run holds (see `d2a_core.artifacts.leases`). When it
cannot read a root, or an artifact a root reaches, it removes nothing: it cannot know what that
root protects. `verify --repair` moves such files to `quarantine/` so that gc works again.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable

from d2a_core.artifacts.fsutil import BadFile, os_reason, sha256_file, storage_errors
from d2a_core.artifacts.leases import HOLDS_FILE, scan_leases
from d2a_core.errors import IntegrityError

if TYPE_CHECKING:
    from d2a_core.artifacts.store import Store

# `Store.scratch_dir`: a directory in tmp/ that a live command holds by a lock inside it
SCRATCH_PREFIX = "scratch-"
SCRATCH_LOCK = ".lock"


@dataclass
class VerifyProblem:
    artifact: str | None
    what: str
    alias: str | None = None
    path: str | None = None
    repaired: str | None = None  # what `verify --repair` did about it

    def as_dict(self) -> dict[str, Any]:
        return {"artifact": self.artifact, "alias": self.alias, "problem": self.what, "path": self.path,
                "repaired": self.repaired}


@dataclass
class GcReport:
    artifacts: list[str] = field(default_factory=list)
    blobs: list[str] = field(default_factory=list)
    temp_files: list[str] = field(default_factory=list)
    stale_leases: list[str] = field(default_factory=list)
    held: dict[str, list[str]] = field(default_factory=dict)  # root -> artifacts it keeps (leases, runs)
    bytes_freed: int = 0
    dry_run: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {
            "dry_run": self.dry_run,
            "artifacts": self.artifacts,
            "blobs": len(self.blobs),
            "temp_files": len(self.temp_files),
            "stale_leases": len(self.stale_leases),
            "held": self.held,
            "bytes_freed": self.bytes_freed,
        }


def _quarantine(store: "Store", path: Path, stamp: str) -> str:
    """Move an unusable file out of the store's namespaces, keeping it for inspection."""
    dest = store.root / "quarantine" / stamp / path.relative_to(store.root)
    with storage_errors("cannot quarantine", path):
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(path, dest)
    return str(dest)

def verify(store: "Store", refs: Iterable[str] | None = None, repair: bool = False) -> list[VerifyProblem]:
    """Re-hash manifests and blobs; report every corrupted or incomplete artifact, alias and
    run hold. `repair=True` moves what cannot be used (unreadable manifests and alias files,
    corrupted blobs, aliases to missing artifacts) into `quarantine/`, so every command works
    again and a rebuild writes fresh copies."""
    problems: list[VerifyProblem] = []
    if refs is not None:
        ids = []
        for ref in refs:
            try:
                ids.append(store.resolve(ref))
            except IntegrityError as exc:
                problems.append(VerifyProblem(None, str(exc), alias=ref))
    else:
        ids = store._all_ids()
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime()) + f"-{os.getpid()}"
    # shared without --repair: a concurrent gc cannot remove a manifest between listing and reading
    with store._lock(exclusive=repair, write=repair):
        checked_blobs: dict[str, str | None] = {}
        for art_id in ids:
            path = store._manifest_path(art_id)
            try:
                manifest = store._parse_manifest(path.read_bytes(), art_id)
            except (OSError, BadFile) as exc:
                what = f"manifest unreadable ({os_reason(exc)})" if isinstance(exc, OSError) else str(exc)
                problem = VerifyProblem(art_id, what, path=str(path))
                if repair and path.exists():
                    problem.repaired = f"moved to {_quarantine(store, path, stamp)}"
                problems.append(problem)
                continue
            for name, info in sorted(manifest["files"].items()):
                digest = info["sha256"]
                blob = store._blob_path(digest)
                if digest not in checked_blobs:
                    if not blob.is_file():
                        checked_blobs[digest] = "missing"
                    else:
                        try:
                            actual, size = sha256_file(blob)
                            ok = actual == digest and size == info["size"]
                        except OSError:
                            ok = False
                        checked_blobs[digest] = None if ok else "corrupted"
                        if not ok and repair:
                            _quarantine(store, blob, stamp)
                if checked_blobs[digest]:
                    problem = VerifyProblem(art_id, f"file {name!r}: blob {digest[:12]} {checked_blobs[digest]}",
                                            path=str(blob))
                    if repair and checked_blobs[digest] == "corrupted":
                        problem.repaired = "blob quarantined; rebuild the artifact to restore it"
                    problems.append(problem)
            for input_id in manifest["inputs"]:
                if not store._manifest_path(input_id).is_file():
                    problems.append(VerifyProblem(art_id, f"input {input_id[:12]} is missing; rebuild it"))
        if refs is None:
            good, bad = store._scan_refs()
            for alias, target in good.items():
                if not store._manifest_path(target).is_file():
                    bad.append(VerifyProblem(None, f"alias {alias!r} points to missing artifact {target[:12]}",
                                             alias=alias, path=str(store._ref_path(alias))))
            holds, bad_holds = store.run_holds()
            for key, held in holds.items():
                for art_id in held:
                    if not store._manifest_path(art_id).is_file():
                        problems.append(VerifyProblem(art_id, f"run {key[:12]} holds missing artifact {art_id[:12]}",
                                                      path=str(store._runs / key / HOLDS_FILE)))
            for problem in bad + bad_holds:
                if repair:
                    problem.repaired = f"moved to {_quarantine(store, Path(problem.path), stamp)}"
                problems.append(problem)
    return problems

def gc(store: "Store", dry_run: bool = False) -> GcReport:
    """Remove artifacts and blobs that no root reaches (directly or as an input), and temp files.

    Roots: aliases, live leases, run holds. If an alias file, a run holds file or a reachable
    manifest cannot be read, gc removes nothing and names it (IntegrityError): it cannot know
    what that root protects. `verify --repair` quarantines such files.
    """
    report = GcReport(dry_run=dry_run)
    store._check_root()
    if not store.root.is_dir():
        return report
    with store._lock(exclusive=True, write=not dry_run):
        refs, bad_refs = store._scan_refs()
        holds, bad_holds = store.run_holds()
        leases, stale = scan_leases(store._leases, store._lease, remove_stale=not dry_run)
        report.stale_leases = stale
        blockers = [p.what if p.alias else f"{p.path}: {p.what}" for p in bad_refs + bad_holds]
        # an alias to a missing artifact is damage too (gc never collects an aliased artifact):
        # a flipped id in it may be hiding the artifact it was meant to protect
        blockers += [f"alias {a!r} points to missing artifact {t[:12]}" for a, t in refs.items()
                     if not store._manifest_path(t).is_file()]
        roots = list(refs.values())
        for name, ids in leases.items():
            report.held[f"lease {name}"] = ids
            roots.extend(ids)
        for key, ids in holds.items():
            report.held[f"run {key}"] = ids
            roots.extend(ids)
        live: set[str] = set()
        manifests: dict[str, dict[str, Any]] = {}
        stack = [t for t in roots if store._manifest_path(t).is_file()]
        while stack:
            art_id = stack.pop()
            if art_id in live:
                continue
            live.add(art_id)
            try:
                manifests[art_id] = store._parse_manifest(store._manifest_path(art_id).read_bytes(), art_id)
            except (OSError, BadFile) as exc:
                blockers.append(f"artifact {art_id}: {exc}")
                continue
            stack.extend(i for i in manifests[art_id]["inputs"] if store._manifest_path(i).is_file())
        if blockers:
            raise IntegrityError(
                "gc removed nothing: it cannot tell what these protect:\n  " + "\n  ".join(blockers)
                + "\nrun d2a artifacts verify --repair to quarantine them, then gc again")
        live_blobs = {f["sha256"] for m in manifests.values() for f in m["files"].values()}
        for art_id in store._all_ids():
            if art_id not in live:
                report.artifacts.append(art_id)
        for blob in sorted(store._objects.glob("??/*")):
            if blob.name not in live_blobs:
                report.blobs.append(blob.name)
                report.bytes_freed += blob.stat().st_size
        # with the exclusive lock held no writer is alive, so every temp file is an orphan; a
        # store's own directories are never links (gc must not empty what a link points to)
        for layout in (store._tmp, store._objects, store._manifests, store._runs):
            if layout.is_symlink():
                raise IntegrityError(f"gc removed nothing: {layout} is a link out of the store, not a directory "
                                     "of it; replace it by a directory")
        temps = [t for t in sorted(store._tmp.iterdir()) if not _scratch_in_use(t)] if store._tmp.is_dir() else []
        temps += _orphan_run_temps(store._runs)
        report.temp_files = [t.relative_to(store.root).as_posix() if t.parent != store._tmp else t.name
                             for t in temps]
        report.bytes_freed += sum(t.lstat().st_size for t in temps)
        if not dry_run:
            with storage_errors("gc cannot remove files"):
                for art_id in report.artifacts:
                    store._manifest_path(art_id).unlink(missing_ok=True)
                for digest in report.blobs:
                    store._blob_path(digest).unlink(missing_ok=True)
                for tmp in temps:
                    if tmp.is_dir() and not tmp.is_symlink():
                        shutil.rmtree(tmp)
                    else:
                        tmp.unlink(missing_ok=True)
    return report


def _orphan_run_temps(runs: Path) -> list[Path]:
    """Temp files (`*.tmp<pid>`) that killed training runs left in their run directories. A run
    that is training holds its directory's lock; the temp files of the others are orphans."""
    found: list[Path] = []
    if not runs.is_dir():
        return found
    for run_dir in sorted(runs.iterdir()):
        if run_dir.is_symlink() or not run_dir.is_dir():
            continue
        temps = [Path(top) / name for top, _, names in os.walk(run_dir)  # never follows links
                 for name in names if ".tmp" in name]
        if not temps:
            continue
        if not _held(run_dir / "lock"):  # a run training now is saving its state into its temp file
            found += temps
    return found



def _held(lock_path: Path) -> bool:
    """Whether a live process holds the flock on `lock_path` (a missing file: no one)."""
    try:
        fd = os.open(lock_path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # also releases a lock taken just now
    return False


def _scratch_in_use(path: Path) -> bool:
    return path.name.startswith(SCRATCH_PREFIX) and not path.is_symlink() and path.is_dir() \
        and _held(path / SCRATCH_LOCK)
