"""MCAP episode logs that Foxglove opens, and a reader that returns numpy arrays.

`EpisodeRecorder` writes one episode to an MCAP file:

- `/scene/track` (protobuf `foxglove.SceneUpdate`, once at log time 0): road surface, road edges,
  optional centreline, finish line and barrier walls, in frame `world`.
- `/scene/cars` (protobuf `foxglove.SceneUpdate`, every step): one cube entity `car/<name>` per car.
- `/tf` (protobuf `foxglove.FrameTransforms`, every step): `world -> <car>`, so a 3-D panel can
  follow a car.
- `/state/<agent>` (JSON, `jsonschema` schema derived from the first message, every step): `t`
  (s), the car pose `x, y, z, yaw, pitch, roll` when a car has the agent's name, then the caller's
  fields (scalars, number lists, strings, booleans, nested objects such as reward terms). Foxglove's
  Plot panel reads them by message path, e.g. `/state/ego.speed` or `/state/ego.reward.pass`.
  NaN and infinities are written as `null` and read back as NaN.
- Metadata record `episode`: the caller's metadata, each top-level value as JSON text.
  Metadata record `d2a.episode_log`: `format`, `dt` and `track`.

Log times are `round(t * 1e9)` ns from episode start, so identical episodes give byte-identical
files. The file appears at `path` only when the recorder closes without an exception.

Minimal replay format (for laps recorded elsewhere): an MCAP file with, per agent, a channel
`/state/<agent>` whose message encoding is `json` (any or no schema) and whose messages are JSON
objects, one per step in log-time order, each holding at least the numbers

    t (s from start), x, y (m, world frame), yaw (rad), speed (m/s), s (m along the centreline),
    e (m lateral offset from the centreline), and optionally z (m; 0 when absent).

Other fields, channels and metadata are optional and returned as found. Files written by
`EpisodeRecorder` satisfy this format for every car that has state. `read_replay` checks it.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import foxglove
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from d2a_core.errors import UsageError
from d2a_core.sim.episode_log.config import EpisodeLogConfig
from d2a_core.sim.episode_log.json_fields import encode_message, json_schema_for, to_plain_json
from d2a_core.sim.episode_log.reader import (
    EPISODE_METADATA_NAME,
    LOG_METADATA_NAME,
    REPLAY_FIELDS,
    STATE_TOPIC_PREFIX,
    Episode,
    missing_fields,
    read_episode,
    read_replay,
)
from d2a_core.sim.episode_log.scene import CarDrawer, CarPose, StaticScene, static_scene_update

__all__ = [
    "CarPose",
    "Episode",
    "EpisodeLogConfig",
    "EpisodeRecorder",
    "REPLAY_FIELDS",
    "StaticScene",
    "missing_fields",
    "read_episode",
    "read_replay",
]

LOG_FORMAT = "d2a-episode-log/1"
TRACK_TOPIC = "/scene/track"
CARS_TOPIC = "/scene/cars"
TRANSFORMS_TOPIC = "/tf"
_POSE_FIELDS = ("t", "x", "y", "z", "yaw", "pitch", "roll")

_COMPRESSION = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4, "none": None}


def _encode_metadata(metadata: Mapping[str, Any]) -> dict[str, str]:
    """Each top-level value as canonical JSON text (MCAP metadata maps strings to strings)."""
    encoded: dict[str, str] = {}
    for key, value in metadata.items():
        if not isinstance(key, str):
            raise TypeError(f"episode metadata keys must be strings, got {key!r}")
        try:
            encoded[key] = json.dumps(value, sort_keys=True, allow_nan=False, default=to_plain_json)
        except (TypeError, ValueError) as error:
            raise TypeError(f"episode metadata {key!r} is not JSON-serialisable: {error}") from error
    return encoded


class EpisodeRecorder:
    """Context manager writing one episode to an MCAP file (see the module docstring).

    Usage::

        with EpisodeRecorder(path, scene, {"track": "oval", "seed": 3}, dt=0.05) as recorder:
            for step in ...:
                recorder.log_step(t, {"ego": CarPose(...)}, {"ego": {"speed": v, ...}})

    The set of cars, agents and top-level state fields is fixed by the first step.
    """

    def __init__(
        self,
        path: str | Path,
        scene: StaticScene,
        metadata: Mapping[str, Any],
        dt: float,
        config: EpisodeLogConfig | None = None,
    ) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.path = Path(path)
        self.scene = scene
        self.dt = float(dt)
        self.config = config or EpisodeLogConfig()
        self._metadata = _encode_metadata(metadata)  # fail before any file is created
        self._temp_path: Path | None = None
        self._writer: foxglove.MCAPWriter | None = None
        self._context: foxglove.Context | None = None
        self._channels: list[Any] = []
        self._state_channels: dict[str, foxglove.Channel] = {}
        self._state_keys: dict[str, frozenset[str]] = {}
        self._car_names: frozenset[str] | None = None
        self._agents: list[str] = []
        self._cars: CarDrawer | None = None
        self._cars_channel: SceneUpdateChannel | None = None
        self._transforms_channel: FrameTransformsChannel | None = None
        self._last_time_ns = -1
        self._used = False
        self.steps = 0

    # -- lifecycle ---------------------------------------------------------------------------

    def __enter__(self) -> EpisodeRecorder:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def open(self) -> None:
        """Start writing to a temporary file beside `path` and draw the static scene."""
        if self._writer is not None or self._used:
            raise RuntimeError(f"an EpisodeRecorder records one episode ({self.path}); make a new one")
        self._used = True
        # Unique name in the same directory so os.replace is atomic; created by the writer with
        # the usual (umask) permissions, which mkstemp's 0600 would not give.
        self._temp_path = self.path.with_name(f".{self.path.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp")
        # A private context keeps these channels out of any other recorder or live server, and
        # makes channel ids start at 1 in every file.
        self._context = foxglove.Context()
        options = MCAPWriteOptions(
            compression=_COMPRESSION[self.config.compression],
            chunk_size=self.config.chunk_size_bytes,
            compression_threads=0,  # single-threaded zstd: reproducible and fair to shared CPUs
        )
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = foxglove.open_mcap(
                self._temp_path, allow_overwrite=False, context=self._context, writer_options=options
            )
        except Exception as error:
            self.abort()
            raise UsageError(f"cannot write episode log {self.path}: {error}") from error
        try:
            track = SceneUpdateChannel(TRACK_TOPIC, context=self._context)
            self._cars_channel = SceneUpdateChannel(CARS_TOPIC, context=self._context)
            self._transforms_channel = FrameTransformsChannel(TRANSFORMS_TOPIC, context=self._context)
            self._channels += [track, self._cars_channel, self._transforms_channel]
            track.log(static_scene_update(self.scene, self.config, 0), log_time=0)
        except BaseException:
            self.abort()
            raise

    def update_metadata(self, metadata: Mapping[str, Any]) -> None:
        """Add or replace episode metadata (e.g. an outcome known only at the end) before closing."""
        self._metadata.update(_encode_metadata(metadata))

    def close(self) -> None:
        """Finish the file and move it to `path` atomically."""
        if self._writer is None or self._temp_path is None:
            raise RuntimeError(f"episode recorder for {self.path} is not open")
        try:
            self._writer.write_metadata(EPISODE_METADATA_NAME, self._metadata)
            self._writer.write_metadata(
                LOG_METADATA_NAME,
                {"format": LOG_FORMAT, "dt": repr(self.dt), "track": self.scene.track_name},
            )
            self._writer.close()
            self._writer = None
            if self.config.fsync:
                descriptor = os.open(self._temp_path, os.O_RDONLY)
                try:
                    os.fsync(descriptor)
                finally:
                    os.close(descriptor)
            os.replace(self._temp_path, self.path)
            self._temp_path = None
        except BaseException:
            self.abort()
            raise
        finally:
            self._release_channels()

    def abort(self) -> None:
        """Stop writing and delete the temporary file; nothing appears at `path`."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # the file is being thrown away; its close error does not matter
                pass
            self._writer = None
        if self._temp_path is not None:
            if self._temp_path.exists():
                self._temp_path.unlink()
            self._temp_path = None
        self._release_channels()

    def _release_channels(self) -> None:
        for channel in self._channels:
            channel.close()
        self._channels = []
        self._state_channels = {}

    # -- per step ----------------------------------------------------------------------------

    def _start_channels(
        self, cars: Mapping[str, CarPose], state: Mapping[str, Mapping[str, Any]], t: float
    ) -> None:
        """Fix the cars and agents from the first step and advertise one JSON channel per agent."""
        assert self._context is not None
        for agent, fields in state.items():
            reserved = _POSE_FIELDS if agent in cars else ("t",)
            clash = sorted(set(reserved).intersection(fields))
            if clash:
                raise ValueError(
                    f"state of {agent!r} has fields {clash}, which the recorder fills itself "
                    "(t from the step time, the pose from the car of that name)"
                )
        self._car_names = frozenset(cars)
        self._cars = CarDrawer(sorted(cars), self.config)
        self._state_keys = {agent: frozenset(fields) for agent, fields in state.items()}
        self._agents = sorted(set(cars) | set(state))
        messages = self._messages(t, cars, state)
        for agent in self._agents:
            schema = json_schema_for(json.loads(encode_message(messages[agent])))
            schema["title"] = f"d2a.state.{agent}"
            channel = foxglove.Channel(
                f"{STATE_TOPIC_PREFIX}{agent}", schema=schema, context=self._context
            )
            self._channels.append(channel)
            self._state_channels[agent] = channel

    def _check_same_layout(
        self, t: float, cars: Mapping[str, CarPose], state: Mapping[str, Mapping[str, Any]]
    ) -> None:
        """Every step must have the cars, agents and top-level fields of the first step."""
        if cars.keys() != self._car_names or state.keys() != self._state_keys.keys():
            raise ValueError(
                f"step at {t} s has cars {sorted(cars)} and state for {sorted(state)}; the first "
                f"step had cars {sorted(self._car_names or ())} and state for "
                f"{sorted(self._state_keys)}"
            )
        for agent, fields in state.items():
            if fields.keys() != self._state_keys[agent]:
                raise ValueError(
                    f"state of {agent!r} at {t} s has fields {sorted(fields)}; the first step had "
                    f"{sorted(self._state_keys[agent])}"
                )

    @staticmethod
    def _messages(
        t: float, cars: Mapping[str, CarPose], state: Mapping[str, Mapping[str, Any]]
    ) -> dict[str, dict[str, Any]]:
        """One JSON object per agent: t, the pose of the car of that name, then the caller's state."""
        messages: dict[str, dict[str, Any]] = {}
        for name, pose in cars.items():
            # float() so numpy or integer poses log as the same JSON numbers
            messages[name] = {
                "t": t, "x": float(pose.x), "y": float(pose.y), "z": float(pose.z),
                "yaw": float(pose.yaw), "pitch": float(pose.pitch), "roll": float(pose.roll),
            }
        for agent, fields in state.items():
            message = messages.get(agent)
            if message is None:
                messages[agent] = {"t": t, **fields}
            else:
                message.update(fields)
        return messages

    def log_step(
        self,
        t: float,
        cars: Mapping[str, CarPose],
        state: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> None:
        """Record one control step at `t` seconds from episode start (strictly increasing).

        `cars` maps car names to poses; `state` maps agent names to JSON-able fields. An agent
        named like a car shares its channel with that car's pose.
        """
        if self._writer is None:
            raise RuntimeError(f"episode recorder for {self.path} is not open (use it in a with block)")
        t = float(t)
        time_ns = round(t * 1e9)
        if time_ns <= self._last_time_ns or time_ns < 0:
            raise ValueError(
                f"step time {t} s must be >= 0 and after the previous step "
                f"({self._last_time_ns / 1e9} s)"
            )
        state = state if state is not None else {}
        if self._cars is None:
            self._start_channels(cars, state, t)
        else:
            self._check_same_layout(t, cars, state)
        assert self._cars is not None
        assert self._cars_channel is not None and self._transforms_channel is not None
        scene, transforms = self._cars.messages(cars, time_ns)
        self._cars_channel.log(scene, log_time=time_ns)
        self._transforms_channel.log(transforms, log_time=time_ns)
        messages = self._messages(t, cars, state)
        for agent in self._agents:
            self._state_channels[agent].log(encode_message(messages[agent]), log_time=time_ns)
        self._last_time_ns = time_ns
        self.steps += 1
