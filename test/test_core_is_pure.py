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
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout


#: what the core must not import: the recording layer and every I/O library (files, bags, ROS)
CORE_FORBIDDEN = ('gimbal_friction.recording', 'gimbal_friction.nodes', 'gimbal_friction.tools', 'rclpy',
                  'rosbags', 'mcap', 'mcap_ros2', 'sqlite3', 'yaml', 'zstandard', 'lz4')


def test_no_core_module_imports_recording_or_io():
    pattern = re.compile(r'^\s*(?:from\s+([\w.]+)\s+import|import\s+([\w.]+))', re.MULTILINE)
    offenders = []
    for path in (PKG / 'core').rglob('*.py'):
        for match in pattern.finditer(path.read_text(encoding='utf-8')):
            name = match.group(1) or match.group(2)
            if any(name == bad or name.startswith(bad + '.') for bad in CORE_FORBIDDEN):
                offenders.append(f'{path.relative_to(PKG)}: {name}')
    assert offenders == []


def test_importing_every_core_module_loads_no_recording_or_io_module():
    modules = sorted('gimbal_friction.core.' + p.stem for p in (PKG / 'core').glob('*.py') if p.stem != '__init__')
    code = (f'import importlib, sys\nfor m in {modules!r}: importlib.import_module(m)\nforbidden = {CORE_FORBIDDEN!r}\n'
            'bad = sorted(m for m in sys.modules if any(m == b or m.startswith(b + ".") for b in forbidden))\n'
            'assert not bad, bad\nprint("pure")')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout
