"""The physics core, config, recording and tools layers never import rclpy (they run without ROS)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / 'gimbal_friction'


def test_no_rclpy_import_statement_under_core():
    pattern = re.compile(r'^\s*(import\s+rclpy|from\s+rclpy|.*__import__\([\'"]rclpy)', re.MULTILINE)
    offenders = [str(p) for d in ('core', 'recording', 'tools') for p in (PKG / d).rglob('*.py')
                 if pattern.search(p.read_text(encoding='utf-8'))]
    assert offenders == []


def test_importing_core_and_tools_does_not_load_rclpy():
    code = ('import sys, gimbal_friction.core, gimbal_friction.core.table, gimbal_friction.config, '
            'gimbal_friction.tools.cli, gimbal_friction.plots\n'
            'import gimbal_friction.tools.cli as c; c.build_parser()\n'
            'bad = [m for m in sys.modules if m.startswith("rclpy")]\n'
            'assert not bad, bad\nprint("pure")')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout
