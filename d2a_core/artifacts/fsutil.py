"""Filesystem helpers shared by the store modules: hashing, directory fsync, and turning an
OSError into a StoreError that names the path and the OS reason (exit 1, no traceback)."""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path
from typing import Iterator

from d2a_core.errors import StoreError

CHUNK = 1 << 20


class BadFile(Exception):
    """A store file that exists but cannot be used (carries the reason for reports)."""


def fsync_dir(path: Path) -> None:
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


def os_reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


@contextlib.contextmanager
def storage_errors(what: str, path: Path | None = None) -> Iterator[None]:
    """Turn an OSError from the filesystem into a StoreError naming the path and the OS reason."""
    try:
        yield
    except OSError as exc:
        where = exc.filename or path
        raise StoreError(f"{what}: {where}: {os_reason(exc)}") from None
