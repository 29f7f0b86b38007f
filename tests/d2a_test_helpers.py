"""Run the real `d2a` CLI in a subprocess and parse its --json output (shared by the tests)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


@dataclass
class CliResult:
    code: int
    stdout: str
    stderr: str

    @property
    def json(self) -> Any:
        return json.loads(self.stdout)


def run_cli(*args: str, store: Path | None = None, timeout: float = 300, env: dict | None = None) -> CliResult:
    cmd = [sys.executable, "-m", "d2a_cli", *args]
    if store is not None:
        cmd += ["--store", str(store)]
    full_env = dict(os.environ, **(env or {}))
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=full_env, cwd=REPO)
    return CliResult(proc.returncode, proc.stdout, proc.stderr)




def copy_store(store: Path, parent: Path) -> Path:
    """A copy of a whole store under `parent` (tests that change a shared store change a copy)."""
    target = parent / "store"
    shutil.copytree(store, target)
    return target
