"""The store under concurrent writers and a writer killed with SIGKILL mid-write."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

from d2a_core.artifacts import Store

WRITER = textwrap.dedent(
    """
    import sys
    from d2a_core.artifacts import Store
    store, who, n = Store(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    for i in range(n):
        shared = store.put("blob", {"data": b"shared-%d" % i * 1000})        # both write this one
        own = store.put("ckpt", {"data": (who + str(i)).encode() * 5000}, inputs=[shared.id])
        store.tag(own.id, "latest")                                          # both move this alias
        store.tag(own.id, f"{who}/{i}")
    print("done")
    """
)

SLOW_WRITER = textwrap.dedent(
    """
    import sys, time
    from d2a_core.artifacts import Store
    store = Store(sys.argv[1])
    with store.create("ckpt", seed=0) as writer:
        with writer.open("model.pt") as fh:
            fh.write(b"x" * (8 << 20))
            fh.flush()
            print("writing", flush=True)
            time.sleep(60)   # killed here, half-way through the artifact
            fh.write(b"y")
    """
)


def test_two_concurrent_writer_processes(store_dir):
    n = 25
    procs = [
        subprocess.Popen([sys.executable, "-c", WRITER, str(store_dir), who, str(n)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for who in ("a", "b")
    ]
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert out.strip() == "done"
    store = Store(store_dir)
    assert store.verify() == []
    kinds = [a.kind for a in store.list()]
    assert kinds.count("blob") == n            # shared content stored once
    assert kinds.count("ckpt") == 2 * n
    refs = store.refs()
    assert refs["latest"] in {refs["a/%d" % (n - 1)], refs["b/%d" % (n - 1)]}
    assert not any((store_dir / "tmp").iterdir())


def test_writer_killed_mid_write_leaves_no_partial_artifact(store_dir):
    store = Store(store_dir)
    keep = store.put("track", {"t": b"existing"})
    store.tag(keep.id, "track/x")
    proc = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, str(store_dir)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert [a.id for a in store.list()] == [keep.id]      # no partial artifact is visible
    assert store.refs() == {"track/x": keep.id}            # no dangling ref
    assert store.verify() == []
    leftovers = list((store_dir / "tmp").iterdir())
    assert leftovers, "the killed writer's temp file should be there for gc to collect"
    start = time.monotonic()
    report = store.gc()                                     # the dead writer's lock is released
    assert time.monotonic() - start < 10
    assert len(report.temp_files) == len(leftovers) and report.artifacts == []
    assert not any((store_dir / "tmp").iterdir())
    assert store.read_bytes("track/x", "t") == b"existing"
