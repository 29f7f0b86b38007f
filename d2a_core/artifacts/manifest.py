"""Artifact manifests: canonical JSON, the identity that gives an artifact its id, provenance.

A manifest has two parts. The *identity* (kind, files with their hashes, input ids, resolved
config, seed, labels) determines the artifact id: same inputs and config and same bytes give the
same id, whoever produced them. The *provenance* (when, the command line, the code version and
package versions) is recorded beside it but is not hashed, so re-running an unchanged step on a
later commit deduplicates instead of forking the lineage; if new code changes the results, the
file hashes change and so does the id.
"""

from __future__ import annotations

import functools
import hashlib
import json
import platform
import subprocess
import sys
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any

IDENTITY_FIELDS = ("format", "kind", "files", "inputs", "config", "seed", "labels")
MANIFEST_FORMAT = 1
RECORDED_PACKAGES = ("d2a", "torch", "numpy", "gymnasium", "pybullet", "mcap", "foxglove-sdk", "pydantic", "typer")


def canonical_json(obj: Any) -> bytes:
    """Deterministic JSON bytes: sorted keys, no whitespace, UTF-8, no NaN."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode()


def content_key(identity: Any) -> str:
    """The sha256 of `identity`'s canonical JSON: the key of a run, an evaluation or a grid cell
    (what it was made from), by which a finished one is found again."""
    return hashlib.sha256(canonical_json(identity)).hexdigest()


def identity_of(manifest: dict[str, Any]) -> dict[str, Any]:
    return {key: manifest[key] for key in IDENTITY_FIELDS}


def artifact_id(manifest: dict[str, Any]) -> str:
    """The sha256 of the canonical identity part of a manifest."""
    return content_key(identity_of(manifest))


@functools.lru_cache(maxsize=1)
def code_version() -> dict[str, Any]:
    """The installed d2a version and, when running from a git checkout, its commit and dirty flag."""
    from d2a_core import __version__

    info: dict[str, Any] = {"version": __version__, "git_commit": None, "dirty": None}
    source_dir = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(
            ["git", "-C", str(source_dir), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
        status = subprocess.run(
            ["git", "-C", str(source_dir), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return info  # installed without a checkout: the version is all we know
    info["git_commit"] = commit
    info["dirty"] = bool(status.strip())
    return info


@functools.lru_cache(maxsize=1)
def package_versions() -> dict[str, str | None]:
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in RECORDED_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def provenance(command: list[str] | None = None) -> dict[str, Any]:
    return {
        "created": datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
        "command": list(sys.argv if command is None else command),
        "code": code_version(),
        "packages": package_versions(),
        "host": {"platform": platform.platform(), "machine": platform.machine()},
    }


@dataclass(frozen=True)
class Artifact:
    """A stored artifact, as read back from its manifest."""

    id: str
    manifest: dict[str, Any]

    @property
    def kind(self) -> str:
        return self.manifest["kind"]

    @property
    def files(self) -> dict[str, dict[str, Any]]:
        return self.manifest["files"]

    @property
    def inputs(self) -> list[str]:
        return self.manifest["inputs"]

    @property
    def config(self) -> Any:
        return self.manifest["config"]

    @property
    def labels(self) -> dict[str, Any]:
        return self.manifest["labels"]

    @property
    def seed(self) -> int | None:
        return self.manifest["seed"]

    @property
    def created(self) -> str:
        return self.manifest["provenance"]["created"]

    @property
    def size(self) -> int:
        return sum(f["size"] for f in self.files.values())
