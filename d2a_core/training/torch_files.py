"""Torch files that d2a reads back (checkpoints, run states): tensors and plain data only.

A torch file is a pickle, and unpickling can call any importable function: a checkpoint put into
a shared store, or a run state dropped into `runs/`, would run its author's code in the reader.
Hashes do not help, since whoever writes a store also writes its manifests. So every torch file
is read with torch's restricted unpickler (`weights_only=True`), which builds only tensors,
containers, numbers and strings, plus the numpy arrays and scalars our states hold (replay
contents, normaliser statistics). Anything else is refused as damage (exit 3) without running.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import torch

from d2a_core.errors import IntegrityError

# What numpy pickles an array or scalar into (numpy 1 and 2 name the module differently). None
# of these calls anything beyond numpy's own array constructors.
_NUMPY_GLOBALS: list[Any] = [np.ndarray, np.dtype]
for _module in ("numpy._core.multiarray", "numpy.core.multiarray"):
    try:
        _mod = __import__(_module, fromlist=["_reconstruct", "scalar"])
    except ImportError:
        continue
    _NUMPY_GLOBALS += [_mod._reconstruct, _mod.scalar]
    break
_NUMPY_GLOBALS += [type(np.dtype(name)) for name in
                   ("bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
                    "float16", "float32", "float64")]


def load_torch(source: Path | BinaryIO | bytes, what: str, device: str = "cpu", hint: str = "") -> Any:
    """The contents of a torch file, built from tensors and plain data only.

    `what` names the file for the error (e.g. "artifact 1a2b3c4d5e6f file 'agent.pt'"), `hint`
    says what to do about it. A file that asks for any other object, or that is not a torch file
    at all, raises IntegrityError: nothing in it is executed."""
    if isinstance(source, bytes):
        source = io.BytesIO(source)
    try:
        with torch.serialization.safe_globals(_NUMPY_GLOBALS):
            return torch.load(source, map_location=device, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError,
            KeyError, IndexError, UnicodeDecodeError, OverflowError) as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise IntegrityError(f"{what} is not a plain torch file of tensors and data, so it was not loaded "
                             f"(nothing in it was executed): {reason[:300]}"
                             + (f"; {hint}" if hint else "")) from None


def check_shared_file(name: str, path: Path, what: str) -> None:
    """Refuse (IntegrityError) a file from another store that d2a would read as a torch file
    (`*.pt`) unless it holds only tensors and plain data; nothing in it runs. Other files d2a
    reads as JSON, NPZ without pickles, MCAP or text."""
    if name.endswith(".pt"):
        load_torch(path, what, "cpu", "it cannot come into this store")
