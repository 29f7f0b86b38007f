"""The training processes' malloc tuning: freed tensor memory stays mapped between updates."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

_SCRIPT = textwrap.dedent(
    """
    import resource, sys
    import torch
    from d2a_core.training.allocator import keep_freed_memory
    tuned = keep_freed_memory() if sys.argv[1] == "tuned" else False
    def update():  # an update's pattern: large tensors kept for backward, temporaries between
        kept = []
        for _ in range(16):
            kept.append(torch.ones(1024, 1024))
            temporary = torch.ones(4096, 255)
            kept.append(torch.ones(1024, 128))
            del temporary
        del kept
    for _ in range(3):
        update()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(10):
        update()
    print(tuned, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    """
)


def _faults(mode: str) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", _SCRIPT, mode], capture_output=True, text=True, check=True)
    tuned, faults = out.stdout.split()
    return tuned, int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning")
def test_keep_freed_memory_stops_page_faults_of_repeated_large_allocations():
    tuned, tuned_faults = _faults("tuned")
    assert tuned == "True"
    _, default_faults = _faults("default")
    # 10 updates keep ~72 MiB each (184,320 pages): untuned, most are faulted in again.
    assert default_faults > 50_000
    assert tuned_faults < 1_000
