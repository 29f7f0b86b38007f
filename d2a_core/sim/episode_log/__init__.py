"""MCAP episode logs that Foxglove opens, and a reader that returns numpy arrays.

- `recorder`: `EpisodeRecorder` writes one episode (the format is in its docstring);
- `reader`: `read_episode`, `read_replay` (the minimal replay format) and the names they share;
- `scene`: the static 3-D scene of a track and the cars drawn on it;
- `json_fields`: per-step state as JSON channels (schemas, NaN handling, flattened columns);
- `config`: `EpisodeLogConfig`, the `episode_log` config section (colours, sizes, compression).

The names below are importable from the package; each submodule loads on first use, so a reader
of logs (the report) does not import the writer's dependencies.
"""

from __future__ import annotations

import importlib
from typing import Any

_HOME = {
    "EpisodeRecorder": "recorder", "LOG_FORMAT": "recorder",
    "read_episode": "reader", "read_replay": "reader", "Episode": "reader", "missing_fields": "reader",
    "EPISODE_METADATA_NAME": "reader", "LOG_METADATA_NAME": "reader", "REPLAY_FIELDS": "reader",
    "STATE_TOPIC_PREFIX": "reader",
    "CarPose": "scene", "CarDrawer": "scene", "StaticScene": "scene", "static_scene_update": "scene",
    "EpisodeLogConfig": "config", "Colour": "config",
}

__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
