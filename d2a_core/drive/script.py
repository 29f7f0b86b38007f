"""Timed key presses for a scripted drive (demos, tests, a study's practice lap).

A script is a YAML (or JSON) list of events, each `{t: seconds from the start, down: [keys]}` or
`{t: ..., up: [keys]}`; keys are those of `controls` (left/a, right/d, up/w, down/s, escape/q).
The window posts them as real key events when the race clock reaches `t`, so a scripted drive
goes through the same code as a person's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from d2a_core.drive.controls import DRIVING_KEYS, QUIT
from d2a_core.errors import UsageError

KNOWN_KEYS = DRIVING_KEYS | QUIT


@dataclass(frozen=True)
class KeyEvent:
    t: float
    key: str
    down: bool


def read_yaml_file(path: Path, what: str) -> object:
    """The YAML document at `path`; an unreadable file or bad YAML names `what` and the file."""
    from d2a_core.config import parse_yaml

    try:
        text = Path(path).read_text()
    except OSError as error:
        raise UsageError(f"{what} {path}: cannot read it ({error.strerror or error})") from None
    return parse_yaml(text, f"{what} {path}")


def load_script(path: Path) -> list[KeyEvent]:
    """The script's events in time order; a bad entry names the file, the entry and the field."""
    data = read_yaml_file(path, "key script")
    if not isinstance(data, list):
        raise UsageError(f"key script {path}: expected a list of {{t, down|up}} events, got {type(data).__name__}")
    events: list[KeyEvent] = []
    for i, entry in enumerate(data):
        where = f"key script {path}, event {i}"
        if not isinstance(entry, dict) or "t" not in entry:
            raise UsageError(f"{where}: expected a mapping with 't' and 'down' or 'up'")
        extra = set(entry) - {"t", "down", "up"}
        if extra:
            raise UsageError(f"{where}: unknown field(s) {sorted(extra)}; allowed: t, down, up")
        t = entry["t"]
        if not isinstance(t, (int, float)) or isinstance(t, bool) or t < 0:
            raise UsageError(f"{where}: field 't' must be seconds >= 0, got {t!r}")
        for field, down in (("down", True), ("up", False)):
            keys = entry.get(field, [])
            keys = [keys] if isinstance(keys, str) else keys
            if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
                raise UsageError(f"{where}: field {field!r} must be a key name or a list of them")
            for key in keys:
                if key not in KNOWN_KEYS:
                    raise UsageError(f"{where}: field {field!r}: unknown key {key!r}; known: {sorted(KNOWN_KEYS)}")
                events.append(KeyEvent(float(t), key, down))
    return sorted(events, key=lambda e: e.t)
