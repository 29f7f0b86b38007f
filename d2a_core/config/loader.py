"""Resolve a run's configuration: preset, then a user file, then `--set` overrides, validated.

Every leaf value remembers where it came from (the preset file, the user's file or the `--set`
argument), so a validation error can name the key, the offending value and its source.

A preset or file may hold a `pairs:` section: per intent pair (`left-right`), a partial config
merged over that layer's own values when a run is for that pair (an assistant's training), so one
preset can carry a setting measured to serve one pair and not the other. Its key names the pair's
two intents in either order. Every pair's values are validated whatever the run's pair.
"""

from __future__ import annotations

import copy
import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import yaml
from pydantic import BaseModel, ValidationError

from d2a_core.config.section import record
from d2a_core.errors import ConfigError

PRESET_DIR = Path(__file__).parent / "presets"


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as `1e-4` (PyYAML reads them as strings)
    and refuses aliases: a config has no use for them, and they are how a few hundred bytes
    expand into gigabytes ("billion laughs") or into a structure that contains itself."""

    def compose_node(self, parent, index):  # noqa: ANN001 - PyYAML's signature
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, f"alias *{event.anchor} found: a config file may not "
                                              "use YAML anchors and aliases", event.start_mark)
        return super().compose_node(parent, index)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def parse_yaml(text: str, source: str) -> Any:
    """Parse YAML text; a syntax error becomes a ConfigError naming the source and line."""
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{shorten(source)}:{mark.line + 1}:{mark.column + 1}" if mark else shorten(source)
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{where}: invalid YAML: {problem}") from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of more digits than Python converts
        raise ConfigError(f"{shorten(source)}: invalid YAML value: {shorten(str(exc))}") from None


def shorten(text: str, limit: int = 200) -> str:
    """`text`, cut to `limit` characters for a message (a value can be megabytes long)."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


@dataclass
class ResolvedConfig:
    """A validated config plus the provenance of each value that did not come from a default."""

    config: BaseModel
    preset: str
    config_file: str | None
    overrides: list[str]
    sources: dict[str, str] = field(default_factory=dict)
    pair: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """Every key with its value (for display)."""
        return self.config.model_dump(mode="json")

    def record(self) -> dict[str, Any]:
        """The config as recorded in run keys and manifests (`config.section.record`)."""
        return record(self.config)

    def source(self) -> dict[str, Any]:
        """Where the config came from (preset, file, `--set` overrides): recorded beside a run's
        result, outside its id, so a reader knows the preset without comparing configs."""
        out = {"preset": self.preset, "config_file": self.config_file, "overrides": list(self.overrides)}
        if self.pair is not None:
            out["pair"] = self.pair
        return out

    def section(self, *names: str) -> dict[str, Any]:
        """The named top-level sections of the record only: what an artifact actually depends on."""
        full = self.record()
        return {name: full[name] for name in names}


def _flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            out.update(_flatten(value, path + "."))
        else:
            out[path] = value
    return out


def _merge(base: dict, layer: dict, sources: dict[str, str], source: str, prefix: str = "") -> None:
    """Deep-merge `layer` into `base` in place, recording the source of each leaf written."""
    for key, value in layer.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value, sources, source, path + ".")
        else:
            base[key] = copy.deepcopy(value)
            if isinstance(value, dict) and value:
                for leaf in _flatten(value, path + "."):
                    sources[leaf] = source
            else:
                sources[path] = source


def _load_mapping(path: Path, label: str) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a directory") from None
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{label}: not a UTF-8 text file (byte {exc.start}: {exc.reason}); "
                          "--config takes a YAML file") from None
    data = parse_yaml(text, label)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: the top level must be a mapping of sections, got {type(data).__name__}")
    return data


def parse_override(text: str) -> tuple[str, Any]:
    """`a.b.c=value` -> ("a.b.c", parsed value). The value is read as YAML (so 256 is an int)."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--set {text!r}: expected KEY.PATH=VALUE, e.g. --set dreamer.units=256")
    value = parse_yaml(raw, f"--set {text}") if raw.strip() else ""
    return key, value


def _nest(key: str, value: Any) -> dict[str, Any]:
    tree: dict[str, Any] = {}
    node = tree
    parts = key.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return tree


def _known_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    keys = []
    for name, info in model.model_fields.items():
        path = f"{prefix}{name}"
        keys.append(path)
        ann = info.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            keys.extend(_known_keys(ann, path + "."))
    return keys


def _describe_errors(exc: ValidationError, schema: type[BaseModel], sources: dict[str, str]) -> str:
    lines = []
    known = _known_keys(schema)
    for err in exc.errors():
        key = ".".join(str(p) for p in err["loc"])
        # list items report their index; the source is recorded for the whole list
        source_key = key
        while source_key and source_key not in sources and "." in source_key:
            source_key = source_key.rsplit(".", 1)[0]
        source = sources.get(source_key)
        if source is None:  # a whole-section check (e.g. pace_min <= pace_max): name what set its keys
            below = sorted({src for k, src in sources.items() if k.startswith(key + ".")})
            source = ", ".join(below) if below else "defaults"
        value = err.get("input")
        if err["type"] == "extra_forbidden":
            hint = difflib.get_close_matches(key, known, n=3, cutoff=0.6)
            did_you_mean = f" (did you mean {', '.join(hint)}?)" if hint else ""
            lines.append(f"unknown key '{key}' = {shorten(repr(value))} from {source}{did_you_mean}")
        else:
            lines.append(f"invalid value for '{key}': {shorten(repr(value))} from {shorten(source)}: {err['msg']}")
    return "invalid configuration:\n  " + "\n  ".join(lines)


def _reject_non_finite(tree: Any, sources: dict[str, str], prefix: str = "") -> None:
    """NaN and infinity are valid YAML floats but no valid setting: a NaN reward or an infinite
    learning rate only shows up later as a crash or a NaN loss, and JSON cannot record them."""
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else ()
    for key, value in items:
        path = f"{prefix}{key}"
        if isinstance(value, float) and not math.isfinite(value):
            source_key = path
            while source_key not in sources and "." in source_key:
                source_key = source_key.rsplit(".", 1)[0]
            raise ConfigError(f"invalid value for '{path}': {value} from {sources.get(source_key, 'defaults')}: "
                              "must be a finite number")
        _reject_non_finite(value, sources, path + ".")


PAIRS_KEY = "pairs"


def _pair_intents(name: Any, label: str, intents: Iterable[str] | None) -> frozenset[str]:
    """The two intents a `pairs:` key (or a run's pair) names; a ConfigError for any other key."""
    parts = name.split("-") if isinstance(name, str) else []
    known = list(intents) if intents is not None else None
    if len(parts) != 2 or parts[0] == parts[1] or not all(parts) or (
            known is not None and not all(p in known for p in parts)):
        allowed = f" (intents: {', '.join(known)})" if known else ""
        raise ConfigError(f"{label}: {name!r} is not an intent pair; write two distinct intents as "
                          f"'a-b', e.g. pairs.left-right{allowed}")
    return frozenset(parts)


def _split_pairs(layer: dict[str, Any], label: str, intents: Iterable[str] | None
                 ) -> tuple[dict[str, Any], list[tuple[frozenset[str], str, dict]]]:
    """(the layer without its `pairs:` section, [(a pair's intents, its source label, its partial
    config)])."""
    layer = dict(layer)
    section = layer.pop(PAIRS_KEY, None)
    if section is None:
        return layer, []
    if not isinstance(section, dict):
        raise ConfigError(f"{label}: '{PAIRS_KEY}' must map an intent pair to the values it changes, "
                          f"got {type(section).__name__}")
    out = []
    for name, values in section.items():
        where = f"{label}, {PAIRS_KEY}.{name}"
        pair = _pair_intents(name, f"{label}, {PAIRS_KEY}", intents)
        if not isinstance(values, dict):
            raise ConfigError(f"{where}: must be a mapping of sections, got {type(values).__name__}")
        if PAIRS_KEY in values:
            raise ConfigError(f"{where}: a pair's values cannot hold another '{PAIRS_KEY}' section")
        out.append((pair, where, values))
    return layer, out


def _validate(schema: type[BaseModel], merged: dict[str, Any], sources: dict[str, str]) -> BaseModel:
    _reject_non_finite(merged, sources)
    try:
        return schema.model_validate(merged)
    except ValidationError as exc:
        raise ConfigError(_describe_errors(exc, schema, sources)) from None


def resolve_config(
    schema: type[BaseModel],
    preset: str = "quick",
    config_file: str | Path | None = None,
    overrides: Iterable[str] = (),
    pair: str | None = None,
    intents: Iterable[str] | None = None,
) -> ResolvedConfig:
    """Merge preset < its `pairs.<pair>` < file < its `pairs.<pair>` < overrides and validate
    against `schema`. `pair` is the run's intent pair (None: a run for no pair, which takes no
    `pairs:` values); `intents`, when given, are the intent names a pair may use."""
    if preset not in available_presets():
        raise ConfigError(f"unknown preset {preset!r}; choose one of {', '.join(available_presets())}")
    intents = list(intents) if intents is not None else None
    wanted = _pair_intents(pair, "the run's pair", intents) if pair is not None else None
    preset_path = PRESET_DIR / f"{preset}.yaml"
    layers = [(f"preset '{preset}' ({preset_path})", _load_mapping(preset_path, f"preset '{preset}' ({preset_path})"))]
    if config_file is not None:
        path = Path(config_file)
        layers.append((str(path), _load_mapping(path, str(path))))
    sources: dict[str, str] = {}
    merged: dict[str, Any] = {}
    others: list[tuple[dict[str, Any], dict[str, str], str, dict]] = []
    for label, data in layers:
        base, by_pair = _split_pairs(data, label, intents)
        _merge(merged, base, sources, label)
        for pair_intents, where, values in by_pair:
            if pair_intents == wanted:
                _merge(merged, values, sources, where)
            else:  # checked over the layers before it, so a typo fails now, not on the other pair's run
                others.append((copy.deepcopy(merged), dict(sources), where, values))
    overrides = list(overrides)
    for text in overrides:
        key, value = parse_override(text)
        if key.split(".")[0] == PAIRS_KEY:
            raise ConfigError(f"--set {text!r}: a pair's values are set in a preset or --config file; "
                              "--set applies to the run's own pair (e.g. --set assistant.reward.w_interv=0.5)")
        _merge(merged, _nest(key, value), sources, f"--set {text}")
    for base, base_sources, where, values in others:
        _merge(base, values, base_sources, where)
        _validate(schema, base, base_sources)
    config = _validate(schema, merged, sources)
    return ResolvedConfig(
        config=config,
        preset=preset,
        config_file=str(config_file) if config_file is not None else None,
        overrides=overrides,
        sources=sources,
        pair=pair,
    )
