"""Which config preset an artifact was made with, read from its recorded config.

Artifacts record their resolved config sections, not the preset's name. A record "is" preset P
when every value it holds equals P's resolved value (the preset file over the schema defaults);
values changed with `--set` show up as differences, including values the preset file leaves at
their defaults (`assistant.intent_scale=2` on `quick`). An assistant's `dreamer` section is its
learner's: it holds the preset's `assistant.train_ratio` / `imag_starts` where those are set.
Keys a record leaves out at their neutral value (`Section.omit_at_default`) are compared at that
value; other keys a record lacks are not counted (older artifacts predate them). The keys a
method sets itself (its reward weights, intent head and relabelling, `training.methods`) are not
differences: the report names the method.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterator, Mapping
from typing import Any

from d2a_core.config.loader import available_presets
from d2a_core.config.section import Section
from d2a_core.training.methods import ASSISTANT_DREAMER_KEYS, METHOD_SET_KEYS, assistant_dreamer_overrides

MAX_LISTED = 8


@functools.lru_cache(maxsize=None)
def _preset_values(name: str, assistant: bool = False, pair: str | None = None) -> dict[str, Any]:
    """The preset's values (for `pair`'s runs, with its `pairs.<pair>` values); for an assistant's
    record (`assistant`), its `dreamer` section is the assistant's learner, so it holds the
    preset's `assistant.*` overrides of it."""
    # imported here: the schema pulls in the simulator's configs, which only this needs
    from d2a_core.config import load

    config = load(name, pair=pair).config
    if assistant:
        config = config.model_copy(update={"dreamer": config.dreamer.model_copy(
            update=assistant_dreamer_overrides(config.assistant))})
    # every key, also those a record omits at their default; through JSON, as manifests store it
    return json.loads(json.dumps(config.model_dump(mode="json")))


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


def _with_neutral_additions(values: Mapping[str, Any], section: type) -> dict[str, Any]:
    """`values` (a recorded section) with the keys a record leaves out at their neutral value
    (`Section.omit_at_default`) put back: such a key is absent because the run used that value,
    or predates the key and behaved as it does."""
    filled = dict(values)
    for name, neutral in section.omit_at_default.items():
        # a whole section missing from a record is one the artifact does not depend on (a record
        # holds only its run's sections), not one left out at its defaults
        if not isinstance(neutral, Mapping):
            filled.setdefault(name, neutral)
    for name, field in section.model_fields.items():
        kind = field.annotation
        if isinstance(filled.get(name), Mapping) and isinstance(kind, type) and issubclass(kind, Section):
            filled[name] = _with_neutral_additions(filled[name], kind)
    return filled


def differences(record: Mapping[str, Any], preset: str, pair: str | None = None) -> tuple[int, list[str]]:
    """(values of the record checked, 'key=recorded value' for each that differs from the preset,
    as the preset resolves for `pair`'s runs)."""
    from d2a_core.config.schema import Config

    checked, differ = 0, []
    resolved = _preset_values(preset, assistant="assistant" in record, pair=pair)
    record = _with_neutral_additions(record, Config)
    # a learner value the record's assistant section sets is named there, not twice; unset, the
    # learner's own value (its `dreamer` section) is the one compared
    assistant = record.get("assistant") or {}
    derived = {f"dreamer.{target}" for key, target in ASSISTANT_DREAMER_KEYS.items()
               if assistant.get(key) is not None}
    derived |= {f"assistant.{key}" for key in ASSISTANT_DREAMER_KEYS if assistant.get(key) is None}
    for key, recorded in _leaves(record):
        found, value = _lookup(resolved, key)
        if not found or key in METHOD_SET_KEYS or key in derived:
            continue
        checked += 1
        if recorded != value:
            differ.append(f"{key}={recorded if isinstance(recorded, str) else json.dumps(recorded)}")
    return checked, sorted(differ)


def describe(record: Mapping[str, Any] | None, pair: str | None = None) -> str:
    """'smoke', 'smoke, except humans.checkpoints=4', or 'custom (...)'; `pair`: the intent pair
    the artifact was made for (its preset's `pairs.<pair>` values are the preset's there)."""
    if not record:
        return "unknown (no config recorded)"
    scored = []
    for order, name in enumerate(available_presets()):
        checked, differ = differences(record, name, pair)
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
