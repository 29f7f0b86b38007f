"""Files of a resumable training run, shared by every kind of run (populations, assistants).

A run lives in `STORE/runs/<run key>/` while it trains: its lock, its state (weights, optimisers,
replay, what it has stored so far) and scratch files such as weight snapshots. The state files
carry their own checksum and are read back with the restricted unpickler (`torch_files`), so a
damaged state is named (exit 3) and a planted one runs nothing.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import io
import os
from pathlib import Path
from typing import Any, Iterator, Optional

import torch

from d2a_core.artifacts import Store
from d2a_core.artifacts.fsutil import fsync_dir, os_reason
from d2a_core.errors import D2AError, IntegrityError, StoreError
from d2a_core.training.torch_files import load_torch

# A checked state file: this line, the sha256 of the rest, a newline, then the torch bytes.
# Files written before the checksum (a bare torch file) still load, through the same unpickler.
_MAGIC = b"D2A-RUN-STATE-1 "


class RunBusyError(D2AError):
    """Another process is training the same run (same key) right now."""

    exit_code = 1


def save_atomic(obj: Any, path: Path) -> None:
    """Save `obj` as a checked torch file at `path`: a kill at any moment leaves the old file or
    the new one, and a full disk names the path and leaves no temp file behind."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    body = buffer.getvalue()
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(_MAGIC + hashlib.sha256(body).hexdigest().encode() + b"\n")
            fh.write(body)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        hint = " (free some space and run the command again: it resumes from the last saved state)" \
            if exc.errno in (errno.ENOSPC, errno.EDQUOT) else ""
        raise StoreError(f"cannot save the run state {path}: {os_reason(exc)}{hint}") from None


def load_checked(path: Path, device: str, what: str, hint: str) -> Any:
    """Read a file written by `save_atomic`: its checksum, then its contents through the
    restricted unpickler. Damage of either kind raises IntegrityError naming `what` and `hint`."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StoreError(f"cannot read {what} {path}: {os_reason(exc)}") from None
    if data.startswith(_MAGIC):
        header, _, body = data.partition(b"\n")
        if hashlib.sha256(body).hexdigest().encode() != header[len(_MAGIC):]:
            raise IntegrityError(f"{what} {path} is damaged (it does not match its checksum); {hint}")
        data = body
    return load_torch(data, f"{what} {path}", device, hint)


class RunDir:
    """`runs/<key>/` of one resumable run."""

    def __init__(self, store: Store, key: str) -> None:
        self.path = store.run_dir(key)
        self.key = key
        self.state_path = self.path / "state.pt"

    @property
    def restart_hint(self) -> str:
        return f"delete {self.path} to train this run from the start"

    @contextlib.contextmanager
    def exclusive(self) -> Iterator["RunDir"]:
        """Hold the run's lock while it trains. A second process asking for the same run (same
        inputs, config, seed and code) exits naming the first instead of resuming from its live
        state; once the first is done, running the command again reuses its stored result."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path / "lock", os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise StoreError(f"cannot create the run directory {self.path}: {os_reason(exc)}") from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "another process"
                raise RunBusyError(
                    f"this run is already being trained by {holder} (run directory {self.path}); wait for it "
                    "to finish, then run the command again to reuse its result") from None
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"process {os.getpid()} on {os.uname().nodename}".encode(), 0)
            yield self
        finally:
            os.close(fd)  # releases the lock

    def load_state(self, device: str) -> Optional[dict[str, Any]]:
        """The saved state, or None when the run has none (a new run)."""
        if not self.state_path.is_file():
            return None
        state = load_checked(self.state_path, device, "the saved state of run", self.restart_hint)
        if not isinstance(state, dict):
            raise IntegrityError(f"the saved state of run {self.state_path} is not a run state; {self.restart_hint}")
        return state

    def save_state(self, state: dict[str, Any]) -> None:
        save_atomic(state, self.state_path)

    def clear_state(self) -> None:
        self.state_path.unlink(missing_ok=True)


def cached_result(store: Store, kind: str, run_key: str, result_file: str, id_key: str = "id",
                  notes: tuple[str, ...] = ()) -> Optional[dict[str, Any]]:
    """The stored result of a finished run with this key (the latest whole one, if several), or None.

    A result whose files, or whose inputs' files, are no longer all in the store (a blob that
    `verify --repair` quarantined) does not count: the run trains again and rebuilds them. The
    result says it was reused and which code made it (`cached_from`), so a number trained by
    other code is never returned silently. The artifact's id goes under `id_key`; `notes` names
    provenance notes (timings, kept out of the hashed files) to copy back into it."""
    done = [a for a in store.list(kind) if a.labels.get("run_key") == run_key and store.is_whole(a.id)]
    if not done:
        return None
    result = store.read_json(done[-1].id, result_file)
    provenance = done[-1].manifest.get("provenance", {})
    result.update({k: v for k, v in provenance.get("notes", {}).items() if k in notes})
    made_by = {"training_code_version": result.get("training_code_version"),
               "created": provenance.get("created"), **provenance.get("code", {})}
    return dict(result, **{id_key: done[-1].id}, resumed_from_env_step=result.get("resumed_from_env_step"),
                cached=True, cached_from=made_by)


def result_record(result: dict[str, Any], leave_out: tuple[str, ...] = ()) -> dict[str, Any]:
    """The result as stored: `resumed_from_env_step` only where the run did resume, so an
    uninterrupted run keeps the id it always had and a resumed one says that it resumed."""
    return {k: v for k, v in result.items()
            if k not in leave_out and not (k == "resumed_from_env_step" and v is None)}
