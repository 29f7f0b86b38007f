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

from d2a_core.artifacts import Store, content_key
from d2a_core.artifacts.fsutil import fsync_dir, os_reason
from d2a_core.errors import D2AError, IntegrityError, NotFoundError, StoreError, TrainingError
from d2a_core.run_inputs import TrackBundle
from d2a_core.training.code_version import TRAINING_CODE_VERSION
from d2a_core.training.torch_files import load_torch

RUN_FORMAT = 1
"""Format of a training run's key and of its saved state."""

# A checked state file: this line, the sha256 of the rest, a newline, then the torch bytes.
# Files written before the checksum (a bare torch file) still load, through the same unpickler.
_MAGIC = b"D2A-RUN-STATE-1 "


def training_run_key(kind: str, bundle: TrackBundle, config: dict[str, Any], seed: int, **inputs: Any) -> str:
    """The key of a training run (`kind` "humans" or "assistant"): everything its result depends
    on (the track and its replays, the config record, the seed, the training-code version and the
    run's own `inputs`, e.g. its intent or its populations), hashed. A finished run is found again
    by it, and an unfinished one resumes from `STORE/runs/<key>/`."""
    identity = {"format": RUN_FORMAT, "kind": kind, "code": TRAINING_CODE_VERSION, "track": bundle.track_id,
                "replays": bundle.replay_ids, "config": config, "seed": seed, **inputs}
    return content_key(identity)


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
    done = store.finished(kind, run_key)
    if done is None:
        return None
    result = store.read_json(done.id, result_file)
    provenance = done.manifest.get("provenance", {})
    result.update({k: v for k, v in provenance.get("notes", {}).items() if k in notes})
    made_by = {"training_code_version": result.get("training_code_version"),
               "created": provenance.get("created"), **provenance.get("code", {})}
    return dict(result, **{id_key: done.id}, resumed_from_env_step=result.get("resumed_from_env_step"),
                cached=True, cached_from=made_by)


def result_record(result: dict[str, Any], leave_out: tuple[str, ...] = ()) -> dict[str, Any]:
    """The result as stored: `resumed_from_env_step` only where the run did resume, so an
    uninterrupted run keeps the id it always had and a resumed one says that it resumed."""
    return {k: v for k, v in result.items()
            if k not in leave_out and not (k == "resumed_from_env_step" and v is None)}


class RunProgress:
    """Where a resumable training run stands, and what it does around its own loop: resume from
    the saved state, hold what that state names, checkpoint, and finish. Populations and
    assistants share it; each keeps its own loop and its own artifacts.

    `inputs` are the artifacts the run reads: they and every checkpoint stored so far are held
    against gc while the run lives and after it dies (run holds), so a saved state never names an
    artifact that is gone. The checkpoint schedule is `count` evenly spaced env-step counts up to
    `total`."""

    def __init__(self, store: Store, run: RunDir, inputs: list[str], total: int, count: int) -> None:
        self.store, self.run, self.inputs = store, run, list(inputs)
        self.schedule = [round(total * (k + 1) / count) for k in range(count)]
        self.env_steps = 0
        self.checkpoints: list[dict[str, Any]] = []
        self.curve_rows: list[dict[str, Any]] = []
        self.resumed_from: Optional[int] = None

    def resume(self, agent: Any, device: str, what: str) -> dict[str, Any]:
        """Restore the saved state (if the run has one) into `agent` and this progress; returns
        the whole saved state, or {} for a new run."""
        saved = self.run.load_state(device)
        if saved is None:
            return {}
        agent.load_state_dict(saved["agent"])
        self.env_steps, self.checkpoints, self.curve_rows = saved["env_steps"], saved["checkpoints"], saved["curve"]
        try:  # the state's checkpoints must still exist (run holds keep them from gc)
            self.hold()
        except NotFoundError as exc:
            raise TrainingError(f"cannot resume {what} from {self.run.state_path}: {exc}; {self.run.restart_hint}") \
                from None
        self.resumed_from = self.env_steps
        return saved

    def hold(self) -> None:
        """Hold the inputs and every checkpoint so far against gc."""
        self.store.hold_run(self.run.key, [*self.inputs, *(c["id"] for c in self.checkpoints)])

    def pending(self) -> list[int]:
        """The checkpoints' env steps still ahead."""
        return [s for s in self.schedule if s > self.env_steps]

    def checkpointed(self, checkpoint: dict[str, Any], state: dict[str, Any]) -> None:
        """A checkpoint was stored: hold it before the saved state names it, then save `state`
        (the run's own fields) with the progress."""
        self.checkpoints.append(checkpoint)
        self.hold()
        self.run.save_state({**state, "env_steps": self.env_steps, "checkpoints": self.checkpoints,
                             "curve": self.curve_rows})

    def stopped(self, exc: Exception, what: str) -> TrainingError:
        """The error to raise when training fails: where it stopped and the last good checkpoint."""
        last = (f"; the last good checkpoint is {self.checkpoints[-1]['id'][:12]} at "
                f"{self.checkpoints[-1]['env_step']} env steps") if self.checkpoints else ""
        return TrainingError(f"{what} training stopped at env step {self.env_steps}: {exc}{last}")

    def finish(self, aliases: dict[str, str]) -> list[dict[str, str]]:
        """The run's result is stored: point its aliases (which now keep everything), drop the
        resumable state and the holds. Returns the aliases that moved."""
        moved = self.store.point_aliases(aliases)
        self.run.clear_state()
        self.store.release_run(self.run.key)
        return moved
