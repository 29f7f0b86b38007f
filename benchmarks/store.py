"""Artifact store throughput for a ~50 MB checkpoint-like file; prints JSON.

    python benchmarks/store.py [--mb 50] [--repeats 3]

put: hash + copy into the store with fsync and atomic rename (a fresh store each repeat, so
nothing is deduplicated). get: read back the blob; get_verified: read and re-hash it. The
reference is a plain copy with fsync in the same process, so `put_vs_plain_copy` is a ratio
that is stable on a noisy machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from d2a_core.artifacts import Store


def _best(fn, repeats: int) -> float:
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        fn(i)
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--mb", type=float, default=50.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src = tmp / "checkpoint.pt"
        rng = np.random.default_rng(0)
        # float32 weights compress poorly and hash like real checkpoints
        src.write_bytes(rng.standard_normal(int(args.mb * (1 << 20) / 4), dtype=np.float32).tobytes())
        size_mb = src.stat().st_size / (1 << 20)

        def plain_copy(i: int) -> None:
            dst = tmp / f"copy{i}"
            shutil.copyfile(src, dst)
            with open(dst, "rb+") as fh:
                os.fsync(fh.fileno())

        ids = []

        def put(i: int) -> None:
            ids.append((Store(tmp / f"store{i}").put("ckpt", {"model.pt": src}).id, i))

        t_copy = _best(plain_copy, args.repeats)
        t_put = _best(put, args.repeats)
        art_id, i = ids[-1]
        store = Store(tmp / f"store{i}")
        t_get = _best(lambda _: store.read_bytes(art_id, "model.pt", verify=False), args.repeats)
        t_get_verified = _best(lambda _: store.read_bytes(art_id, "model.pt", verify=True), args.repeats)

    print(json.dumps({
        "benchmark": "store",
        "file_mb": round(size_mb, 1),
        "put_mb_s": round(size_mb / t_put, 1),
        "get_mb_s": round(size_mb / t_get, 1),
        "get_verified_mb_s": round(size_mb / t_get_verified, 1),
        "plain_copy_fsync_mb_s": round(size_mb / t_copy, 1),
        "put_vs_plain_copy": round(t_copy / t_put, 2),
    }))


if __name__ == "__main__":
    main()
