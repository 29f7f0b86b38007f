"""Concurrent writers (store API processes and `make-track`) while another process runs `gc` in a
loop that also verifies and reads every aliased artifact after each gc: every writer finishes,
nothing it made or used is collected under it, and no reader ever sees a damaged artifact."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

from fault_helpers import REPO, assert_consistent, d2a, run

from d2a_core.artifacts import Store

# Each step: an unaliased input, an artifact built on it, then the alias. Between the steps only
# the writer's lease keeps them from the gc loop.
WRITER = textwrap.dedent(
    """
    import sys
    from d2a_core.artifacts import Store
    store, who, n = Store(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    with store.lease():
        for i in range(n):
            base = store.put("blob", {"data": b"shared-%d" % i * 500})
            own = store.put("ckpt", {"data": (who + str(i)).encode() * 2000}, inputs=[base.id])
            store.tag(own.id, f"{who}/{i}")
            assert store.read_bytes(f"{who}/{i}", "data") == (who + str(i)).encode() * 2000
    print("done", flush=True)
    """
)

GC_LOOP = textwrap.dedent(
    """
    import os, sys, time
    from d2a_core.artifacts import Store
    store, stop = Store(sys.argv[1]), sys.argv[2]
    runs = removed = 0
    while not os.path.exists(stop):
        removed += len(store.gc().artifacts)
        runs += 1
        # what readers see meanwhile: every artifact whole, every alias resolving
        if runs % 4 == 1:
            problems = store.verify()
            assert not problems, [p.as_dict() for p in problems]
        for alias in store.refs():
            art = store.get(alias)
            for name in art.files:
                store.path(alias, name)
        time.sleep(0.02)
    print(runs, removed, flush=True)
    """
)


def test_writers_and_make_track_beside_a_gc_loop(tmp_path):
    store = tmp_path / "store"
    Store(store).put("seed", {"x": b"so that gc has a store to lock"})
    stop = tmp_path / "stop"
    gc = subprocess.Popen([sys.executable, "-c", GC_LOOP, str(store), str(stop)], stdout=subprocess.PIPE, text=True)
    writers = [subprocess.Popen([sys.executable, "-c", WRITER, str(store), who, "40"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True) for who in ("a", "b")]
    tracks = [subprocess.Popen(d2a("make-track", "straightaway", "--preset", "smoke", "--seed", str(seed),
                                   "--name", f"straight{seed}", "--json", store=store),
                               cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
              for seed in (1, 2)]
    try:
        outs = [p.communicate(timeout=300) for p in writers + tracks]
    finally:
        stop.write_text("stop")
        gc_out, _ = gc.communicate(timeout=60)
    for proc, (out, err) in zip(writers + tracks, outs):
        assert proc.returncode == 0, err
    assert gc.returncode == 0, "a reader saw a damaged artifact or a dangling alias"
    gc_runs, gc_removed = map(int, gc_out.split())
    assert gc_runs >= 3  # gc waits for writers between their puts, so it runs less often than it loops
    store_view = Store(store)
    for who in ("a", "b"):
        for i in range(40):
            assert store_view.resolve(f"{who}/{i}")
    for seed, (out, _) in zip((1, 2), outs[2:]):
        result = json.loads(out)
        assert store_view.resolve(f"track/straight{seed}") == result["id"]
    assert_consistent(store)
    print(f"gc loop: {gc_runs} runs, {gc_removed} artifacts removed (the 'seed' one only)")
    assert gc_removed <= 1
    # and a final gc with nobody writing keeps every aliased artifact
    report = json.loads(run("artifacts", "gc", "--json", store=store).stdout)
    assert report["artifacts"] == []
