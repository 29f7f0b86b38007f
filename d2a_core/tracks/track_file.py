"""Track artifact file: one `.npz` (a zip of `.npy` arrays) with JSON metadata inside.

Layout (format `d2a.track`, version 1):
    s, x, y, z, heading, curvature, w_left, w_right, grade   float64 (n,) per-sample arrays
    barrier_<k>_s        float64 (m,)   centreline s of each barrier base point
    barrier_<k>_points   float64 (m, 3) x, y, z of the wall's road-facing base
    barrier_<k>_e        float64 (m,)   signed lateral offset of those points
    metadata             uint8 (bytes)  UTF-8 JSON: format, version, name, finish_s, start_grid,
                                        barriers (side, type, height, offset), source, summary numbers

The zip entries carry a fixed timestamp and a fixed order, so the same track always produces the
same bytes (artifacts are content-addressed). Arrays are stored uncompressed and load bit-exactly.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.errors import SpecError
from d2a_core.tracks.config import FrenetSearchConfig
from d2a_core.tracks.track import SAMPLE_FIELDS, Barrier, GridSlot, StartGrid, Track

TRACK_FORMAT = "d2a.track"
TRACK_FORMAT_VERSION = 1
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def _write_array(archive: zipfile.ZipFile, name: str, array: np.ndarray) -> None:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(array), allow_pickle=False)
    info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
    info.compress_type = zipfile.ZIP_STORED
    info.external_attr = 0o644 << 16
    archive.writestr(info, buffer.getvalue())


def save_track(track: Track, path: str | Path) -> None:
    """Write `track` to `path` (conventionally ending in `.npz`)."""
    metadata = {"format": TRACK_FORMAT, "version": TRACK_FORMAT_VERSION, **track.metadata()}
    encoded = json.dumps(metadata, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as archive:
        for name in SAMPLE_FIELDS:
            _write_array(archive, name, getattr(track, name))
        for k, barrier in enumerate(track.barriers):
            _write_array(archive, f"barrier_{k}_s", barrier.s)
            _write_array(archive, f"barrier_{k}_points", barrier.points)
            _write_array(archive, f"barrier_{k}_e", barrier.e)
        _write_array(archive, "metadata", np.frombuffer(encoded, dtype=np.uint8))


def _slot(data: dict[str, Any]) -> GridSlot:
    return GridSlot(s=float(data["s"]), e=float(data["e"]))


def load_track(path: str | Path, frenet_config: FrenetSearchConfig | None = None) -> Track:
    """Read a track file written by `save_track`.

    Raises:
        SpecError: the file is missing, not a track file, of another format version, or inconsistent.
    """
    source = str(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile) as error:
        raise SpecError(f"{source}: cannot read the track file ({error})") from error
    try:
        metadata = json.loads(arrays["metadata"].tobytes().decode("utf-8"))
    except (KeyError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise SpecError(f"{source}: not a d2a track file (no readable metadata)") from error
    if metadata.get("format") != TRACK_FORMAT:
        raise SpecError(f"{source}: not a d2a track file (format {metadata.get('format')!r})")
    if metadata.get("version") != TRACK_FORMAT_VERSION:
        raise SpecError(
            f"{source}: track file version {metadata.get('version')} is not supported (expected {TRACK_FORMAT_VERSION})"
        )
    try:
        barriers = [
            Barrier(
                side=info["side"],
                kind=info["type"],
                height=float(info["height"]),
                offset=float(info["offset"]),
                s=arrays[f"barrier_{k}_s"],
                points=arrays[f"barrier_{k}_points"],
                e=arrays[f"barrier_{k}_e"],
            )
            for k, info in enumerate(metadata["barriers"])
        ]
        grid = metadata["start_grid"]
        return Track(
            metadata["name"],
            **{name: arrays[name] for name in SAMPLE_FIELDS},
            barriers=barriers,
            finish_s=float(metadata["finish_s"]),
            start_grid=StartGrid(ego=_slot(grid["ego"]), opponent=_slot(grid["opponent"])),
            source=metadata.get("source", {}),
            frenet_config=frenet_config,
        )
    except (KeyError, TypeError, ValueError) as error:
        raise SpecError(f"{source}: corrupt track file ({error!r})") from error
