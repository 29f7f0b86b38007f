"""Load a track spec from YAML with errors that name the file, the line and the field path."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from d2a_core.errors import SpecError
from d2a_core.tracks.interpolation import KnotProfile
from d2a_core.tracks.limits import MAX_COORD_M, MAX_SAMPLES
from d2a_core.tracks.spec import TrackSpec, Width

Loc = tuple[str | int, ...]

# Tolerance when comparing user-given positions with the summed segment length.
_LENGTH_TOLERANCE_M = 1e-6


def format_loc(loc: Loc) -> str:
    """`('segments', 3, 'arc', 'radius')` -> `segments[3].arc.radius`."""
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += ("." if text else "") + str(part)
    return text or "(top level)"


def _describe(error: dict[str, Any]) -> str:
    """A short human message for one pydantic error."""
    kind = error["type"]
    ctx = error.get("ctx") or {}
    bounds = {"greater_than": (">", "gt"), "greater_than_equal": (">=", "ge"),
              "less_than": ("<", "lt"), "less_than_equal": ("<=", "le")}
    if kind in bounds:
        op, key = bounds[kind]
        bound = ctx.get(key)
        message = f"must be {op} {bound:g}" if isinstance(bound, (int, float)) else f"must be {op} {bound}"
    elif kind == "missing":
        return "required field is missing"
    elif kind == "extra_forbidden":
        return "unknown field"
    elif kind == "literal_error":
        message = f"must be {ctx.get('expected')}"
    elif kind in ("float_parsing", "float_type", "int_parsing", "int_type"):
        message = "must be a number"
    elif kind in ("model_type", "dict_type"):
        message = "must be a mapping"
    elif kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    else:
        message = error["msg"]
    if "input" in error and not isinstance(error["input"], (dict, list)):
        message += f" (got {error['input']!r})"
    return message


class _YamlIndex:
    """Maps field paths to 1-based line numbers using the YAML node tree."""

    def __init__(self, root: yaml.Node | None) -> None:
        self._root = root

    def line_of(self, loc: Loc) -> int | None:
        node = self._root
        line = None if node is None else node.start_mark.line + 1
        for part in loc:
            child = None
            if isinstance(node, yaml.MappingNode) and isinstance(part, str):
                # A missing key leaves `child` None: the line of the enclosing mapping is reported.
                child = next((v for k, v in node.value if getattr(k, "value", None) == part), None)
            elif isinstance(node, yaml.SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
                child = node.value[part]
            if child is None:
                break
            node = child
            line = node.start_mark.line + 1
        return line


def _duplicate_keys(node: yaml.Node | None, loc: Loc = ()) -> list[tuple[Loc, int, str]]:
    """PyYAML silently keeps the last of duplicated keys; report them instead."""
    found: list[tuple[Loc, int, str]] = []
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key, value in node.value:
            name = str(getattr(key, "value", ""))
            if name in seen:
                found.append((loc + (name,), key.start_mark.line + 1, "duplicate key"))
            seen.add(name)
            found += _duplicate_keys(value, loc + (name,))
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            found += _duplicate_keys(item, loc + (index,))
    return found


def _line_message(source: str, line: int | None, loc: Loc, message: str) -> str:
    where = f"{source}:{line}" if line is not None else source
    return f"{where}: {format_loc(loc)}: {message}"


def _width_profile(value: float | Sequence[tuple[float, float]]) -> KnotProfile:
    return KnotProfile.constant(value) if isinstance(value, (int, float)) else KnotProfile(value)


def width_profiles(width: Width) -> tuple[KnotProfile, KnotProfile]:
    """(left, right) half-width profiles of a spec's width block."""
    return _width_profile(width.left), _width_profile(width.right)


def check_spec_consistency(spec: TrackSpec) -> list[tuple[Loc, str]]:
    """Checks that need the whole spec (positions against the summed segment length, the grid inside the road)."""
    problems: list[tuple[Loc, str]] = []
    total = spec.total_length
    samples = total / spec.sample_spacing_m
    if samples > MAX_SAMPLES:  # checked before sampling: it would not fit in memory
        problems.append((("sample_spacing_m",), f"{spec.sample_spacing_m} m over {total:.0f} m of track is "
                         f"{samples:.3g} samples, more than {MAX_SAMPLES}; use a coarser spacing"))
        return problems
    for axis in ("x", "y"):
        value = getattr(spec.start_pose, axis, 0.0)
        if abs(value) > MAX_COORD_M:
            problems.append((("start_pose", axis), f"must be within +-{MAX_COORD_M:g} m (got {value})"))
    limit = total + _LENGTH_TOLERANCE_M
    if spec.finish_s > limit:
        problems.append((("finish_s",), f"must be <= the track length {total:.3f} m (got {spec.finish_s})"))
    for index, barrier in enumerate(spec.barriers):
        if barrier.s_start >= total:
            problems.append(
                (("barriers", index, "s_start"), f"must be < the track length {total:.3f} m (got {barrier.s_start})")
            )
        if barrier.s_end > limit:
            problems.append(
                (("barriers", index, "s_end"), f"must be <= the track length {total:.3f} m (got {barrier.s_end})")
            )
    left, right = width_profiles(spec.width)
    for role in ("ego", "opponent"):
        slot = getattr(spec.start_grid, role)
        if slot.s >= min(spec.finish_s, total):
            problems.append(
                (("start_grid", role, "s"), f"must be before the finish line at {spec.finish_s} (got {slot.s})")
            )
        w_left, w_right = float(left.value(slot.s)), float(right.value(slot.s))
        if not -w_right < slot.e < w_left:
            problems.append(
                (
                    ("start_grid", role, "e"),
                    f"must be on the road, between {-w_right:.2f} and {w_left:.2f} at s={slot.s} (got {slot.e})",
                )
            )
    return problems


def validate_spec_data(data: Any, source: str, yaml_root: yaml.Node | None = None) -> TrackSpec:
    """Validate already-parsed spec data; errors name `source` (and lines when `yaml_root` is given)."""
    index = _YamlIndex(yaml_root)
    if not isinstance(data, dict):
        raise SpecError(f"{source}: the spec must be a YAML mapping (got {type(data).__name__})")
    messages = [_line_message(source, line, loc, msg) for loc, line, msg in _duplicate_keys(yaml_root)]
    spec = None
    try:
        spec = TrackSpec.model_validate(data)
    except ValidationError as error:
        for item in error.errors():
            loc = tuple(item["loc"])
            messages.append(_line_message(source, index.line_of(loc), loc, _describe(item)))
    if spec is not None:
        for loc, message in check_spec_consistency(spec):
            messages.append(_line_message(source, index.line_of(loc), loc, message))
    if messages:
        raise SpecError("\n".join(messages))
    assert spec is not None
    return spec


def load_spec(path: str | Path) -> TrackSpec:
    """Read and validate a track spec YAML file.

    Raises:
        SpecError: the file is unreadable, is not valid YAML (message: `file:line:column`), or fails
            validation (one line per problem: `file:line: field.path: message`).
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise SpecError(f"{source}: cannot read the spec ({error})") from error
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark is not None else source
        problem = getattr(error, "problem", None) or str(error)
        raise SpecError(f"{where}: YAML syntax error: {problem}") from error
    if data is None:
        raise SpecError(f"{source}: the spec is empty")
    _reject_non_finite(data, source, _YamlIndex(root))
    return validate_spec_data(data, source, root)


def _reject_non_finite(data: Any, source: str, index: _YamlIndex, loc: Loc = ()) -> None:
    """YAML accepts `.nan` and `.inf`; no spec field means them."""
    if isinstance(data, float) and not math.isfinite(data):
        raise SpecError(_line_message(source, index.line_of(loc), loc, f"must be a finite number (got {data})"))
    if isinstance(data, dict):
        for key, value in data.items():
            _reject_non_finite(value, source, index, loc + (str(key),))
    elif isinstance(data, list):
        for position, value in enumerate(data):
            _reject_non_finite(value, source, index, loc + (position,))
