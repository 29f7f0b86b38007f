"""TensorBoard event files without TensorBoard: scalars only, in the TFRecord format it reads.

TensorBoard (and TensorFlow, torch's `SummaryWriter`) is a heavy dependency for what d2a writes:
a few scalars per curve row. An event file is a sequence of TFRecords, each a length, its masked
CRC-32C, an `Event` protobuf and that's masked CRC-32C; the two protobuf messages d2a needs
(`Event` with `wall_time`, `step`, `file_version` or `summary`; `Summary.Value` with `tag` and
`simple_value`) are encoded here by hand. `tests/test_live_curves.py` reads the files with the
real `tensorboard` package.
"""

from __future__ import annotations

import math
import os
import socket
import struct
import time
from pathlib import Path
from typing import Mapping

_CRC32C_POLY = 0x82F63B78  # Castagnoli, reflected


def _crc32c_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ _CRC32C_POLY if crc & 1 else crc >> 1
        table.append(crc)
    return table


_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for byte in data:
        crc = _TABLE[(crc ^ byte) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def _masked_crc(data: bytes) -> int:
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def _varint(value: int) -> bytes:
    out = bytearray()
    value &= (1 << 64) - 1  # int64 as protobuf encodes it
    while True:
        bits = value & 0x7F
        value >>= 7
        if value:
            out.append(bits | 0x80)
        else:
            out.append(bits)
            return bytes(out)


def _length_delimited(field: int, payload: bytes) -> bytes:
    return _varint(field << 3 | 2) + _varint(len(payload)) + payload


def _event(wall_time: float, step: int, file_version: str | None = None,
           scalars: Mapping[str, float] | None = None) -> bytes:
    body = _varint(1 << 3 | 1) + struct.pack("<d", wall_time) + _varint(2 << 3 | 0) + _varint(step)
    if file_version is not None:
        body += _length_delimited(3, file_version.encode())
    if scalars:
        values = b"".join(
            _length_delimited(1, _length_delimited(1, tag.encode()) + _varint(2 << 3 | 5) + struct.pack("<f", value))
            for tag, value in scalars.items())
        body += _length_delimited(5, values)
    return body


def _record(data: bytes) -> bytes:
    header = struct.pack("<Q", len(data))
    return header + struct.pack("<I", _masked_crc(header)) + data + struct.pack("<I", _masked_crc(data))


class ScalarEventWriter:
    """Appends scalar rows to a new event file in `folder`; every row is flushed to disk at once,
    so `tensorboard --logdir` shows a run while it trains."""

    def __init__(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        now = time.time()
        self.path = folder / f"events.out.tfevents.{int(now)}.{socket.gethostname()}.{os.getpid()}.0"
        self._fh = open(self.path, "ab")
        self._write(_event(now, 0, file_version="brain.Event:2"))

    def add_scalars(self, step: int, scalars: Mapping[str, object]) -> None:
        """One event holding every finite number in `scalars` (other values are left out)."""
        numbers = {tag: float(v) for tag, v in scalars.items()
                   if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))}
        if numbers:
            self._write(_event(time.time(), int(step), scalars=numbers))

    def _write(self, event: bytes) -> None:
        self._fh.write(_record(event))
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
