"""pybullet's build banner reaches neither stdout nor stderr (it would corrupt --json output)."""

import subprocess
import sys


def test_importing_pybullet_prints_nothing():
    code = "from d2a_core.sim.quiet_pybullet import pb; print('imported', pb.isConnected(0))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == "imported 0\n" and proc.stderr == ""
