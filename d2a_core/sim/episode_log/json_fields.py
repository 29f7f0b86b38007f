"""JSON side of episode logs: encoding per-step state, deriving its JSON schema, and turning a
channel's decoded messages back into arrays."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def to_plain_json(value: Any) -> Any:
    """`json` hook for numpy scalars and arrays (np.float64 is a float already and never gets here).

    Sets are refused: their order changes between runs and would break reproducible files.
    """
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"a value of type {type(value).__name__} cannot be logged as JSON")


def _finite_or_none(value: Any) -> Any:
    """Copy of `value` with NaN and infinities replaced by None (JSON has no non-finite numbers)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: _finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(item) for item in value]
    if isinstance(value, np.ndarray):
        return _finite_or_none(value.tolist())
    if isinstance(value, np.floating):
        return _finite_or_none(float(value))
    return value


_ENCODER = json.JSONEncoder(allow_nan=False, default=to_plain_json, separators=(",", ":"))


def encode_message(message: Mapping[str, Any]) -> bytes:
    """Compact UTF-8 JSON for one state message; floats keep full float64 precision.

    Non-finite numbers become `null` so that Foxglove (strict JSON) can parse every message.
    """
    try:
        text = _ENCODER.encode(message)
    except ValueError:  # a NaN or infinity somewhere: the rare slow path
        text = _ENCODER.encode(_finite_or_none(message))
    return text.encode("utf-8")


def json_schema_for(value: Any) -> dict[str, Any]:
    """JSON schema describing a decoded JSON value (used on the first message of a channel).

    `null` gets the empty schema (anything), because a field such as intent may be unknown at
    first and a string later.
    """
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, (int, float)):
        return {"type": "number"}
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, list):
        return {"type": "array", "items": json_schema_for(value[0]) if value else {}}
    if isinstance(value, dict):
        return {
            "type": "object",
            "properties": {key: json_schema_for(item) for key, item in value.items()},
        }
    return {}


def flatten(message: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested objects become dotted keys: {"reward": {"pass": 1}} -> {"reward.pass": 1}."""
    flat: dict[str, Any] = {}
    for key, value in message.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _object_array(values: list[Any]) -> np.ndarray:
    array = np.empty(len(values), dtype=object)
    array[:] = values
    return array


def _list_column(values: list[Any]) -> np.ndarray:
    """(T, k) array for fixed-length lists: float64 (missing rows NaN) or bool; else objects."""
    lengths = {len(value) for value in values if value is not None}
    if len(lengths) != 1:
        return _object_array(values)
    width = lengths.pop()
    items = [item for value in values if value is not None for item in value]
    if all(isinstance(item, bool) for item in items) and None not in values and items:
        return np.array(values, dtype=bool).reshape(len(values), width)
    if all(item is None or _is_number(item) for item in items):
        rows = [[math.nan] * width if value is None else value for value in values]
        return np.array(rows, dtype=np.float64).reshape(len(values), width)
    return _object_array(values)


def column(values: list[Any]) -> np.ndarray:
    """One field's values over time as an array.

    Numbers -> float64 (null -> NaN), or int64 when every value is an integer; booleans -> bool;
    equal-length number lists -> (T, k) float64; anything else (strings, mixed) -> object array.
    """
    kinds = {type(value) for value in values}
    if kinds == {bool}:
        return np.array(values, dtype=bool)
    if kinds == {int} and all(-(2**63) <= value < 2**63 for value in values):
        return np.array(values, dtype=np.int64)
    if kinds and kinds <= {int, float, type(None)} and kinds != {type(None)}:
        return np.array([math.nan if value is None else value for value in values], dtype=np.float64)
    if kinds and kinds <= {list, type(None)} and kinds != {type(None)}:
        return _list_column(values)
    return _object_array(values)


def columns(messages: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Arrays per dotted field name for a channel's messages; a field missing in a message is null."""
    flat_messages = [flatten(message) for message in messages]
    names: dict[str, None] = {}
    for flat in flat_messages:
        names.update(dict.fromkeys(flat))
    return {name: column([flat.get(name) for flat in flat_messages]) for name in names}
