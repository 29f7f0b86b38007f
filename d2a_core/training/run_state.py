"""Files of a resumable training run, shared by every kind of run (populations, assistants)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Optional

import torch

from d2a_core.artifacts import Store


def save_atomic(obj: Any, path: Path) -> None:
    """torch.save `obj` to `path` so that a kill at any moment leaves the old file or the new one."""
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    with open(tmp, "wb") as fh:
        torch.save(obj, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def cached_result(store: Store, kind: str, run_key: str, result_file: str, id_key: str = "id",
                  notes: tuple[str, ...] = ()) -> Optional[dict[str, Any]]:
    """The stored result of a finished run with this key (the latest, if several), or None.

    The result says it was reused and which code made it (`cached_from`), so a number trained by
    other code is never returned silently. The artifact's id goes under `id_key`; `notes` names provenance notes (timings, kept out of
    the hashed files) to copy back into it."""
    done = [a for a in store.list(kind) if a.labels.get("run_key") == run_key]
    if not done:
        return None
    result = store.read_json(done[-1].id, result_file)
    provenance = done[-1].manifest.get("provenance", {})
    result.update({k: v for k, v in provenance.get("notes", {}).items() if k in notes})
    made_by = {"training_code_version": result.get("training_code_version"),
               "created": provenance.get("created"), **provenance.get("code", {})}
    return dict(result, **{id_key: done[-1].id}, resumed_from_env_step=None, cached=True, cached_from=made_by)

