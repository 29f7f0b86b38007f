"""Replay of fixed-length sequences from per-environment numpy ring buffers: uniform, with
optional shares of windows from the newest steps or on stored terminal steps.

Each parallel environment writes its own stream of steps; episodes follow one another in a
stream and each starts with `is_first = True`, so a sampled window may span an episode
boundary and the world model resets its state there. Windows never wrap across the write
position (where the newest step meets the oldest). Sampling is deterministic given the seed.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.errors import TrainingError, UsageError


class SequenceReplay:
    """Ring buffer of steps of `num_streams` environments, sampled as (batch, length) windows.

    Fields are created from the first `add`: every value has a leading axis of size
    num_streams (one entry per environment); later adds must carry the same fields and shapes.
    """

    def __init__(self, capacity: int, seed: int) -> None:
        self.capacity = capacity
        self.rng = np.random.default_rng(seed)
        self.data: dict[str, np.ndarray] = {}
        self.num_streams = 0
        self.stream_capacity = 0
        self.position = 0  # next write index in every stream
        self.filled = 0  # valid steps per stream

    def __len__(self) -> int:
        """Steps stored over all streams."""
        return self.filled * self.num_streams

    def _allocate(self, step: Mapping[str, np.ndarray]) -> None:
        self.num_streams = int(next(iter(step.values())).shape[0])
        self.stream_capacity = max(1, self.capacity // self.num_streams)
        for key, value in step.items():
            value = np.asarray(value)
            self.data[key] = np.zeros((self.num_streams, self.stream_capacity, *value.shape[1:]), value.dtype)

    def add(self, step: Mapping[str, np.ndarray]) -> None:
        """Append one step of every stream: each value has shape (num_streams, ...)."""
        if not self.data:
            self._allocate(step)
        if set(step) != set(self.data):
            raise UsageError(f"replay: step fields {sorted(step)} differ from the stored fields {sorted(self.data)}")
        for key, value in step.items():
            value = np.asarray(value)
            if value.shape[0] != self.num_streams or value.shape[1:] != self.data[key].shape[2:]:
                raise UsageError(
                    f"replay: field {key!r} has shape {value.shape}, expected "
                    f"({self.num_streams}, {', '.join(map(str, self.data[key].shape[2:]))})"
                )
            self.data[key][:, self.position] = value
        self.position = (self.position + 1) % self.stream_capacity
        self.filled = min(self.filled + 1, self.stream_capacity)

    def can_sample(self, length: int) -> bool:
        """Whether a window of `length` steps exists."""
        return self.num_streams > 0 and self.filled >= length

    def sample(self, batch_size: int, length: int) -> dict[str, np.ndarray]:
        """`batch_size` windows of `length` consecutive steps, uniformly over streams and starts
        (DreamerV3's replay). `is_first` is set at each window's first step: the model starts
        every window afresh."""
        if not self.can_sample(length):
            raise TrainingError(
                f"replay holds {self.filled} steps per stream, fewer than the batch length {length}"
            )
        streams = self.rng.integers(0, self.num_streams, batch_size)
        starts = self.rng.integers(0, self.filled - length + 1, batch_size)
        oldest = self.position if self.filled == self.stream_capacity else 0
        index = (oldest + starts[:, None] + np.arange(length)[None]) % self.stream_capacity
        batch = {key: value[streams[:, None], index] for key, value in self.data.items()}
        if "is_first" in batch:
            batch["is_first"][:, 0] = True
        return batch

    # --- persistence

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue exactly: contents, positions and the RNG state."""
        return {
            "capacity": self.capacity,
            "num_streams": self.num_streams,
            "stream_capacity": self.stream_capacity,
            "position": self.position,
            "filled": self.filled,
            "rng": self.rng.bit_generator.state,
            "data": {key: value.copy() for key, value in self.data.items()},
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore a `state_dict`."""
        self.capacity = int(state["capacity"])
        self.num_streams = int(state["num_streams"])
        self.stream_capacity = int(state["stream_capacity"])
        self.position = int(state["position"])
        self.filled = int(state["filled"])
        self.rng.bit_generator.state = state["rng"]
        self.data = {key: np.array(value) for key, value in state["data"].items()}

    def save(self, path: str | Path) -> None:
        """Write the state to an .npz file (arrays uncompressed, metadata as JSON)."""
        state = self.state_dict()
        meta = {k: v for k, v in state.items() if k != "data"}
        arrays = {f"data/{k}": v for k, v in state["data"].items()}
        with open(path, "wb") as handle:
            np.savez(handle, meta=np.array(json.dumps(meta)), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> SequenceReplay:
        """Read a replay written by `save`."""
        with np.load(path, allow_pickle=False) as archive:
            meta = json.loads(str(archive["meta"]))
            data = {k.removeprefix("data/"): archive[k] for k in archive.files if k.startswith("data/")}
        replay = cls(int(meta["capacity"]), seed=0)
        replay.load_state_dict({**meta, "data": data})
        return replay
