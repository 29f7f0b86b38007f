"""The built wheel carries everything a user needs outside a checkout (the shipped track specs,
the presets, the kernel source): install it elsewhere and build a shipped track."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile

from d2a_test_helpers import REPO


def test_the_wheel_ships_the_tracks_and_make_track_works_outside_the_checkout(tmp_path):
    wheels = tmp_path / "wheels"
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                            "-w", str(wheels), str(REPO)], capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stderr
    wheel = next(wheels.glob("d2a-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"d2a_tracks/straightaway.yaml", "d2a_tracks/hairpin.yaml", "d2a_core/config/presets/quick.yaml",
            "d2a_core/agents/dreamer/cpu_kernels.c"} <= names

    site = tmp_path / "site"
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site),
                              str(wheel)], capture_output=True, text=True, timeout=300)
    assert install.returncode == 0, install.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # the wheel's packages first on the path; the dependencies come from this environment
    env = dict(os.environ, PYTHONPATH=str(site))
    where = subprocess.run([sys.executable, "-c", "import d2a_core, d2a_tracks; print(d2a_core.__file__); "
                            "print(d2a_tracks.__file__)"], capture_output=True, text=True, env=env, cwd=elsewhere)
    assert where.returncode == 0 and all(line.startswith(str(site)) for line in where.stdout.split()), where.stdout
    res = subprocess.run([sys.executable, "-m", "d2a_cli", "make-track", "hairpin", "--preset", "smoke", "--json",
                          "--store", str(tmp_path / "store")], capture_output=True, text=True, env=env,
                         cwd=elsewhere, timeout=300)
    assert res.returncode == 0, res.stderr
    assert '"hairpin"' in res.stdout
