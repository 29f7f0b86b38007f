"""gc roots besides aliases: leases of live processes and holds of saved run states.

A *lease* (`leases/<pid>-<token>.json`) lists the artifacts a live process uses. The process
holds an exclusive flock on the file for its whole life; gc tries to take that lock without
waiting: if it cannot, the process is alive and every id listed is a root; if it can, the
process is gone (the kernel drops a dead process's locks) and the lease is stale.

A *run hold* (`runs/<key>/holds.json` = `{"format": 1, "artifacts": [ids]}`) lists the
artifacts a run's saved state resumes from; it outlives the process and lasts until released.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
from pathlib import Path

from d2a_core.errors import IntegrityError

HOLDS_FORMAT = 1
HOLDS_FILE = "holds.json"
FULL_ID = re.compile(r"^[0-9a-f]{64}$")


class Lease:
    """Artifacts a live process uses, in `leases/<pid>-<token>.json`, flock-ed while it lives.

    gc treats the ids of a lease whose lock is held as roots; a lease whose lock it can take
    belongs to a dead process and is removed. The file is rewritten in place (never renamed):
    the lock belongs to its inode.
    """

    def __init__(self, path: Path, fd: int):
        self.path = path
        self.fd = fd
        self.ids: list[str] = []
        self.depth = 1

    def write(self) -> None:
        data = json.dumps({"pid": os.getpid(), "artifacts": self.ids}).encode()
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, data, 0)


def read_run_holds(runs: Path) -> tuple[dict[str, list[str]], list[tuple[Path, str]]]:
    """Each run key -> the ids its holds.json names, and (path, reason) of those that cannot be read."""
    holds: dict[str, list[str]] = {}
    bad: list[tuple[Path, str]] = []
    if not runs.is_dir():
        return holds, bad
    for path in sorted(runs.glob(f"*/{HOLDS_FILE}")):
        try:
            data = json.loads(path.read_bytes())
            ids = data["artifacts"]
            if data.get("format") != HOLDS_FORMAT or not all(isinstance(i, str) and FULL_ID.match(i) for i in ids):
                raise ValueError("not a list of artifact ids")
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            bad.append((path, str(exc)))
            continue
        holds[path.parent.name] = ids
    return holds, bad


def scan_leases(directory: Path, own: Lease | None, remove_stale: bool) -> tuple[dict[str, list[str]], list[str]]:
    """Ids held by live leases (by lease file), and the stale lease files (removed if asked)."""
    live: dict[str, list[str]] = {}
    stale: list[str] = []
    if not directory.is_dir():
        return live, stale
    for path in sorted(directory.glob("*.json")):
        if own is not None and path == own.path:  # our own: flock would refuse us too, but say why
            live[path.name] = list(own.ids)
            continue
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:  # its process is alive: everything it lists is a root
                data = json.loads(os.pread(fd, 1 << 24, 0) or b"{}")
                live[path.name] = [i for i in data.get("artifacts", []) if isinstance(i, str)]
            else:
                stale.append(path.name)
                if remove_stale:
                    path.unlink(missing_ok=True)
        except (ValueError, AttributeError):
            # a live lease mid-rewrite cannot be: rewrites happen under the store lock we hold
            raise IntegrityError(f"lease {path} of a live process is unreadable") from None
        finally:
            os.close(fd)
    return live, stale
