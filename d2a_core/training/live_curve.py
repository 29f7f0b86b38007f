"""A run's training curve, written while it trains.

The rows are kept in memory and stored with the run's artifact when it ends (`curve.jsonl`, what
`d2a report` reads). While the run trains they also go, row by row, to
`STORE/logs/<run name>/`: `curve.jsonl` (rewritten from the saved rows when a run resumes) and
TensorBoard event files with the same names as tags and the env step as step, so
`tensorboard --logdir STORE/logs` follows every run of a store live. The folder outlives the run
and is not an artifact: `d2a artifacts gc` leaves it, deleting it loses nothing stored.
"""

from __future__ import annotations

import json
from typing import Any

from d2a_core.artifacts import Store
from d2a_core.artifacts.fsutil import os_reason
from d2a_core.errors import StoreError
from d2a_core.training.tensorboard_events import ScalarEventWriter


class LiveCurve:
    """The curve's rows (`rows`), each also written to the run's live folder when appended."""

    def __init__(self, store: Store, name: str, rows: list[dict[str, Any]] | None = None) -> None:
        self.rows: list[dict[str, Any]] = list(rows or [])
        self.folder = store.live_log_dir(name)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with open(self.folder / "curve.jsonl", "w") as fh:  # a resumed run's rows, not the lost ones
                fh.writelines(_line(r) for r in self.rows)
            self._jsonl = open(self.folder / "curve.jsonl", "a")
            self._events = ScalarEventWriter(self.folder)
        except OSError as exc:
            raise StoreError(f"cannot write the live curve in {self.folder}: {os_reason(exc)}") from None

    def append(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        try:
            self._jsonl.write(_line(row))
            self._jsonl.flush()
            self._events.add_scalars(int(row["env_step"]), {k: v for k, v in row.items() if k != "env_step"})
        except OSError as exc:
            raise StoreError(f"cannot write the live curve in {self.folder}: {os_reason(exc)}") from None

    def jsonl_bytes(self) -> bytes:
        """The rows as the artifact stores them."""
        return "".join(_line(r) for r in self.rows).encode()

    def close(self) -> None:
        self._jsonl.close()
        self._events.close()


def _line(row: dict[str, Any]) -> str:
    return json.dumps(row, sort_keys=True) + "\n"
