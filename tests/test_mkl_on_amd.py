"""MKL's vendor check answered by d2a on AMD CPUs (d2a_core/mkl_on_amd.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from d2a_core import mkl_on_amd

_PROBE = """
import json, sys
from d2a_core import mkl_on_amd
if sys.argv[1] == "torch-first":
    import torch
print(json.dumps({"status": mkl_on_amd.enable()}))
import torch
a = torch.ones(64, 96)
print(json.dumps({"product": float((a @ a.T).sum()), "mkl": torch.backends.mkl.is_available()}))
"""


def _probe(tmp_path, order: str = "d2a-first", **env) -> tuple[dict, str]:
    """Runs the probe in a fresh interpreter; returns its output and where the dynamic linker
    bound libtorch's reference to MKL's vendor check ('' if it never did)."""
    log = tmp_path / f"ld-{order}-{len(list(tmp_path.glob('ld-*')))}"
    result = subprocess.run([sys.executable, "-c", _PROBE, order], capture_output=True, text=True, timeout=300,
                            check=True, env={**os.environ, "D2A_KERNEL_CACHE": str(tmp_path / "cache"),
                                             "LD_DEBUG": "bindings", "LD_DEBUG_OUTPUT": str(log), **env})
    lines = result.stdout.strip().splitlines()
    binding = ""
    for path in tmp_path.glob(f"{log.name}.*"):  # the linker's log (~25 MB), one file per process
        with open(path, errors="replace") as linker_log:
            for line in linker_log:
                if f"`{mkl_on_amd.SYMBOL}'" in line and "libtorch_cpu" in line.split(" to ")[0]:
                    binding = line.split(" to ")[1]
        path.unlink()
    return {**json.loads(lines[-2]), **json.loads(lines[-1])}, binding


def test_it_applies_only_to_amd_x86_64_linux_before_torch():
    applies = dict(vendor="AuthenticAMD", system="Linux", machine="x86_64", torch_loaded=False, setting="1")
    assert mkl_on_amd.not_applicable(**applies) is None
    assert "Intel" in mkl_on_amd.not_applicable(**{**applies, "vendor": "GenuineIntel"})
    assert "arm64" in mkl_on_amd.not_applicable(**{**applies, "system": "Darwin", "machine": "arm64"})
    assert "D2A_MKL_AMD=0" in mkl_on_amd.not_applicable(**{**applies, "setting": "0"})
    assert "torch was imported" in mkl_on_amd.not_applicable(**{**applies, "torch_loaded": True})
    assert mkl_on_amd.cpu_vendor("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\n") == "AuthenticAMD"
    assert mkl_on_amd.cpu_vendor("processor : 0\n") is None


@pytest.mark.skipif(mkl_on_amd.cpu_vendor() != "AuthenticAMD" or sys.platform != "linux",
                    reason="the vendor check is answered on AMD CPUs under Linux only")
def test_on_amd_libtorch_binds_mkls_vendor_check_to_d2as_library(tmp_path):
    applied, binding = _probe(tmp_path)
    if not applied["mkl"]:
        pytest.skip("this torch build has no MKL")
    built = list((tmp_path / "cache").glob("mkl_vendor-*.so"))
    assert applied["status"].startswith("MKL vendor check answered") and len(built) == 1
    assert str(built[0]) in binding
    assert not [p for p in (tmp_path / "cache").iterdir() if p not in built]  # no partial files left
    # torch loaded first: MKL keeps its own answer, and the status says why
    late, late_binding = _probe(tmp_path, "torch-first")
    assert "torch was imported" in late["status"] and "libtorch_cpu" in late_binding
    disabled, disabled_binding = _probe(tmp_path, D2A_MKL_AMD="0")
    assert "D2A_MKL_AMD=0" in disabled["status"] and "libtorch_cpu" in disabled_binding
    # another kernel, the same product (exact in float32 for these integers)
    assert applied["product"] == late["product"] == disabled["product"] == 64 * 64 * 96


def test_without_a_compiler_nothing_is_loaded(tmp_path):
    result, binding = _probe(tmp_path, CC="/nonexistent/cc")
    if mkl_on_amd.cpu_vendor() == "AuthenticAMD" and sys.platform == "linux":
        assert "needs a C compiler" in result["status"]
    assert "mkl_vendor" not in binding and not list((tmp_path / "cache").glob("*"))


def test_the_command_line_answers_it_before_any_command_runs(tmp_path):
    code = ("import sys; from d2a_cli.main import main; from d2a_core import mkl_on_amd\n"
            "try:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print(mkl_on_amd.status())")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True,
                            env={**os.environ, "D2A_KERNEL_CACHE": str(tmp_path / "cache")})
    status = result.stdout.strip().splitlines()[-1]
    assert status != "not tried"
    if mkl_on_amd.cpu_vendor() == "AuthenticAMD" and sys.platform == "linux":
        assert status.startswith("MKL vendor check answered")
