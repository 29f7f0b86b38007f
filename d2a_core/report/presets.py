"""Which config preset an artifact was made with, read from its recorded config.

Artifacts record their resolved config sections, not the preset's name. A preset file lists only
the values it sets over the schema defaults, so a record "is" preset P when every value P's file
sets (in the sections the record holds) equals the record's; values changed with `--set` show up
as differences. The preset files are read as YAML: the config schema is not imported (it pulls in
the simulator, which the report never loads).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping
from typing import Any

import yaml

from d2a_core.config.loader import PRESET_DIR, available_presets

MAX_LISTED = 3


@functools.lru_cache(maxsize=None)
def _preset_values(name: str) -> dict[str, Any]:
    with (PRESET_DIR / f"{name}.yaml").open(encoding="utf-8") as fh:
        return yaml.safe_load(fh) or {}


def _leaves(values: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for key, value in values.items():
        if isinstance(value, Mapping):
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def _lookup(record: Mapping[str, Any], dotted: str) -> tuple[bool, Any]:
    node: Any = record
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def differences(record: Mapping[str, Any], preset: str) -> tuple[int, list[str]]:
    """(values of the preset checked, 'key=recorded value' for each that differs)."""
    checked, differ = 0, []
    for key, value in _leaves(_preset_values(preset)):
        if key.split(".")[0] not in record:
            continue
        found, recorded = _lookup(record, key)
        checked += 1
        if not found or recorded != value:
            differ.append(f"{key}={recorded if found else '(absent)'}")
    return checked, differ


def describe(record: Mapping[str, Any] | None) -> str:
    """'smoke', 'smoke, except humans.checkpoints=4', or 'custom (...)'."""
    if not record:
        return "unknown (no config recorded)"
    scored = []
    for order, name in enumerate(available_presets()):
        checked, differ = differences(record, name)
        if checked:
            scored.append((len(differ), -checked, order, name, differ))
    if not scored:
        return "unknown (no preset sets these sections)"
    count, _, _, name, differ = min(scored)
    if count == 0:
        return name
    if count <= MAX_LISTED:
        return f"{name}, except {', '.join(differ)}"
    return f"custom (closest preset {name}: {count} of its values differ)"
