"""The bytes of a stored agent checkpoint (`agent.pt`), the same for the same weights and config.

Checkpoints are content-addressed, so two runs with the same seed and config must write the same
bytes. torch.save pickles, and pickle writes a string it has met before as a back-reference to
the first one only when it is the *same object*: whether `config.device` is the interned literal
"cpu" (the option's default) or a fresh string parsed from `--device cpu` changed a checkpoint's
bytes, and so its id, without changing anything it holds. Interning every string first makes the
bytes depend on the values alone.
"""

from __future__ import annotations

import io
import sys
from typing import Any

import torch


def _interned(obj: Any) -> Any:
    """`obj` with every str in its dicts (of any dict type), lists and tuples interned; tensors
    and other leaves are shared, not copied."""
    if isinstance(obj, str):
        return sys.intern(str(obj))
    if isinstance(obj, dict):
        items = [(_interned(k), _interned(v)) for k, v in obj.items()]
        return dict(items) if type(obj) is dict else type(obj)(items)
    if type(obj) is list:
        return [_interned(v) for v in obj]
    if type(obj) is tuple:
        return tuple(_interned(v) for v in obj)
    return obj


def agent_bytes(agent: Any) -> bytes:
    """The checkpoint file of a Dreamer-family agent: torch.save of its state without the replay,
    strings interned (see the module docstring)."""
    buffer = io.BytesIO()
    torch.save(_interned(agent.state_dict(include_replay=False)), buffer)
    return buffer.getvalue()
