"""Reading episode logs (and opponent replays) back as numpy arrays. The format is described in
`d2a_core.sim.episode_log`."""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader

from d2a_core.errors import UsageError
from d2a_core.sim.episode_log.json_fields import columns

STATE_TOPIC_PREFIX = "/state/"
EPISODE_METADATA_NAME = "episode"
LOG_METADATA_NAME = "d2a.episode_log"
REPLAY_FIELDS: tuple[str, ...] = ("t", "x", "y", "yaw", "speed", "s", "e")
"""Fields a replay's `/state/<agent>` channel must carry (`z` is optional and defaults to 0)."""


@dataclass
class Episode:
    """One episode read from an MCAP log.

    `times` (T,) are the `t` values of the steps (s). `state[agent][field]` is (T,) or (T, k), with
    nested objects flattened to dotted names such as `reward.pass`. `poses[name]` is (T, 4) of
    x, y, z, yaw for every state channel that has x, y and yaw. `dt` and `track_name` are None for
    logs not written by `EpisodeRecorder`.
    """

    path: Path
    metadata: dict[str, Any]
    times: np.ndarray
    poses: dict[str, np.ndarray]
    state: dict[str, dict[str, np.ndarray]]
    dt: float | None = None
    track_name: str | None = None
    log_info: dict[str, str] = field(default_factory=dict)

    @property
    def agents(self) -> list[str]:
        """Names of the `/state/<agent>` channels, sorted."""
        return sorted(self.state)

    def __len__(self) -> int:
        return len(self.times)


def _decode_metadata_value(text: str) -> Any:
    """Values are JSON text; a plain string from a foreign writer is kept as it is."""
    try:
        return json.loads(text)
    except ValueError:
        return text


def _read_records(path: Path) -> tuple[dict[str, list[dict[str, Any]]], dict[str, dict[str, str]]]:
    """Decoded JSON messages per state agent (in log-time order) and metadata records by name."""
    if not path.is_file():
        raise UsageError(f"episode log {path} does not exist")
    messages: dict[str, list[dict[str, Any]]] = {}
    metadata: dict[str, dict[str, str]] = {}
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            for record in reader.iter_metadata():
                metadata[record.name] = dict(record.metadata)
            for _, channel, message in reader.iter_messages(log_time_order=True):
                if not channel.topic.startswith(STATE_TOPIC_PREFIX):
                    continue
                agent = channel.topic[len(STATE_TOPIC_PREFIX):]
                if channel.message_encoding != "json":
                    raise UsageError(
                        f"episode log {path}: channel {channel.topic} has message encoding "
                        f"{channel.message_encoding!r}, expected 'json'"
                    )
                try:
                    decoded = json.loads(message.data)
                except ValueError as error:
                    raise UsageError(
                        f"episode log {path}: message on {channel.topic} at log time "
                        f"{message.log_time} ns is not valid JSON ({error})"
                    ) from error
                if not isinstance(decoded, dict):
                    raise UsageError(
                        f"episode log {path}: message on {channel.topic} at log time "
                        f"{message.log_time} ns is not a JSON object"
                    )
                messages.setdefault(agent, []).append(decoded)
    except UsageError:
        raise
    except Exception as error:  # the mcap reader raises many types for damaged files
        raise UsageError(
            f"episode log {path} is not a readable MCAP file: {type(error).__name__}: {error}"
        ) from error
    return messages, metadata


def _times(path: Path, state: dict[str, dict[str, np.ndarray]]) -> np.ndarray:
    """The shared step times; every channel must have a numeric `t` with the same values."""
    times: np.ndarray | None = None
    reference = ""
    for agent in sorted(state):
        t = state[agent].get("t")
        if t is None or t.ndim != 1 or t.dtype.kind not in "fi" or not np.all(np.isfinite(t)):
            raise UsageError(
                f"episode log {path}: channel {STATE_TOPIC_PREFIX}{agent} lacks a numeric 't' "
                "field (seconds from episode start) in every message"
            )
        t = t.astype(np.float64)
        if times is None:
            times, reference = t, agent
        elif len(t) != len(times) or not np.array_equal(t, times):
            raise UsageError(
                f"episode log {path}: channels {STATE_TOPIC_PREFIX}{reference} and "
                f"{STATE_TOPIC_PREFIX}{agent} do not share the same steps ({len(times)} vs {len(t)})"
            )
    assert times is not None
    return times


def _poses(fields: dict[str, np.ndarray]) -> np.ndarray | None:
    """(T, 4) x, y, z, yaw when the channel carries a numeric pose (z defaults to 0)."""
    needed = [fields.get(name) for name in ("x", "y", "yaw")]
    if any(array is None or array.ndim != 1 or array.dtype.kind not in "fi" for array in needed):
        return None
    x, y, yaw = needed
    z = fields.get("z")
    if z is None or z.ndim != 1 or z.dtype.kind not in "fi":
        z = np.zeros(len(x))
    return np.column_stack([x, y, z, yaw]).astype(np.float64)


def read_episode(path: str | Path) -> Episode:
    """Read an episode log written by `EpisodeRecorder`, or a replay in the minimal format.

    Raises `UsageError` naming the file when it is missing, not valid MCAP, has no
    `/state/<agent>` channel, or its channels lack a numeric `t` or disagree on the steps.
    """
    path = Path(path)
    messages, metadata_records = _read_records(path)
    if not messages:
        raise UsageError(
            f"episode log {path} has no {STATE_TOPIC_PREFIX}<agent> JSON channel with messages"
        )
    state = {agent: columns(messages[agent]) for agent in sorted(messages)}
    times = _times(path, state)
    poses = {agent: pose for agent in state if (pose := _poses(state[agent])) is not None}
    log_info = metadata_records.get(LOG_METADATA_NAME, {})
    dt_text = log_info.get("dt")
    return Episode(
        path=path,
        metadata={
            key: _decode_metadata_value(value)
            for key, value in metadata_records.get(EPISODE_METADATA_NAME, {}).items()
        },
        times=times,
        poses=poses,
        state=state,
        dt=float(dt_text) if dt_text is not None else None,
        track_name=log_info.get("track"),
        log_info=log_info,
    )


def missing_fields(episode: Episode, agent: str, fields: Iterable[str] = REPLAY_FIELDS) -> list[str]:
    """Fields of `fields` that `agent` lacks or does not hold as a numeric (T,) array."""
    columns_of_agent = episode.state.get(agent, {})
    return [
        name
        for name in fields
        if name not in columns_of_agent
        or columns_of_agent[name].ndim != 1
        or columns_of_agent[name].dtype.kind not in "fi"
    ]


def read_replay(path: str | Path, agent: str | None = None) -> Episode:
    """Read a log to race against: like `read_episode`, and check `agent`'s channel carries the
    replay fields (t, x, y, yaw, speed, s, e; z optional).

    `agent` may be left out when the file has exactly one state channel.
    """
    episode = read_episode(path)
    if agent is None:
        if len(episode.state) != 1:
            raise UsageError(
                f"replay {episode.path} has several agents ({', '.join(episode.agents)}); "
                "choose which one to replay"
            )
        agent = episode.agents[0]
    if agent not in episode.state:
        raise UsageError(
            f"replay {episode.path} has no channel {STATE_TOPIC_PREFIX}{agent} "
            f"(agents: {', '.join(episode.agents)})"
        )
    lacking = missing_fields(episode, agent)
    if lacking:
        raise UsageError(
            f"replay {episode.path}: channel {STATE_TOPIC_PREFIX}{agent} lacks numeric fields "
            f"{', '.join(lacking)} (a replay needs {', '.join(REPLAY_FIELDS)}; z is optional)"
        )
    return episode
