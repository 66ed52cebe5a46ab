"""gimbal_friction.sim is pure: importing it loads neither rclpy nor the recording (file I/O) layer."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.slow
def test_importing_sim_loads_no_rclpy_and_no_recording():
    code = ('import sys, gimbal_friction.sim, gimbal_friction.sim.study\n'
            'bad = [m for m in sys.modules if m.startswith(("rclpy", "gimbal_friction.recording", "yaml"))]\n'
            'assert not bad, bad\nprint("pure")')
    out = subprocess.run([sys.executable, '-c', code], check=False, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout
