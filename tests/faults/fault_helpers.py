"""Shared pieces of the fault-injection suite: seeded randomness, CLI processes, store invariants.

`D2A_FAULT_SEED` (default 18) seeds every random choice, so a failure reproduces; set another
seed to explore other kill points and flips.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path

from d2a_core.artifacts import Store
from d2a_core.run_inputs import opponents_of

REPO = Path(__file__).resolve().parents[2]
SEED = int(os.environ.get("D2A_FAULT_SEED", "18"))


def rng(salt: str) -> random.Random:
    return random.Random(f"{SEED}-{salt}")


def d2a(*args: str, store: Path) -> list[str]:
    return [sys.executable, "-m", "d2a_cli", *args, "--store", str(store)]


def run(*args: str, store: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    proc = subprocess.run(d2a(*args, store=store), cwd=REPO, capture_output=True, text=True, timeout=timeout)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def assert_consistent(store_dir: Path) -> None:
    """What a reader may rely on after any fault: every visible artifact is whole, every alias
    resolves, and an aliased track comes with a complete set of replays."""
    store = Store(store_dir)
    problems = store.verify()
    assert problems == [], [p.as_dict() for p in problems]
    for alias, target in store.refs().items():
        assert store.get(alias).id == target
        if alias.startswith("track/") and alias.count("/") == 1:
            replays = opponents_of(store, alias)
            count = store.get(replays[0]).config["opponents"]["count"]
            assert len(replays) == count
