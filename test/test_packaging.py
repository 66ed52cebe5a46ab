"""The ament_python package builds with colcon and installs what ``ros2 run`` looks up."""

from __future__ import annotations

import ast
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXECUTABLES = ('friction_feedforward', 'friction_estimator', 'residual_logger', 'chamber_replay')


def test_package_xml_is_format3_ament_python_with_real_deps():
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'gimbal_friction'
    assert root.find('export/build_type').text == 'ament_python'
    deps = {e.text for e in root.findall('exec_depend')}
    assert {'rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'python3-numpy', 'python3-scipy'} <= deps


def test_setup_declares_every_contract_executable():
    text = (ROOT / 'setup.py').read_text()
    for exe in EXECUTABLES + ('gimbal-friction',):
        assert re.search(rf"'{exe} = gimbal_friction\.", text), exe
    cfg = (ROOT / 'setup.cfg').read_text()
    assert 'script_dir=$base/lib/gimbal_friction' in cfg and 'install_scripts=$base/lib/gimbal_friction' in cfg
    assert (ROOT / 'resource' / 'gimbal_friction').exists()


def test_launch_file_parses_and_names_the_nodes():
    tree = ast.parse((ROOT / 'launch' / 'gimbal_friction.launch.py').read_text())
    names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert 'generate_launch_description' in names
    text = (ROOT / 'launch' / 'gimbal_friction.launch.py').read_text()
    for exe in ('friction_feedforward', 'friction_estimator', 'residual_logger'):
        assert exe in text


def test_launch_file_imports_where_launch_ros_exists():
    pytest.importorskip('launch_ros', reason='launch_ros is not on PyPI; this check runs on a full ROS 2 install')
    import importlib.util
    spec = importlib.util.spec_from_file_location('gf_launch', ROOT / 'launch' / 'gimbal_friction.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.generate_launch_description() is not None


def test_colcon_build_installs_ros2_run_layout(tmp_path):
    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent)) or shutil.which('colcon')
    assert colcon, 'colcon is installed by requirements-test.txt'
    src = tmp_path / 'ws' / 'src' / 'gimbal_friction'
    src.mkdir(parents=True)
    for name in ('package.xml', 'setup.py', 'setup.cfg', 'README.md'):
        if (ROOT / name).exists():
            shutil.copy(ROOT / name, src / name)
    for name in ('resource', 'gimbal_friction', 'config', 'launch'):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns('__pycache__', '*.egg-info'))
    ws = tmp_path / 'ws'
    env = dict(os.environ, COLCON_HOME=str(tmp_path / 'colcon_home'))
    out = subprocess.run([colcon, 'build', '--base-paths', 'src', '--event-handlers', 'console_direct-'],
                         cwd=ws, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    install = ws / 'install' / 'gimbal_friction'
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'gimbal_friction').exists()
    assert (install / 'share' / 'gimbal_friction' / 'package.xml').exists()
    assert (install / 'share' / 'gimbal_friction' / 'config' / 'gimbal_friction.yaml').exists()
    assert (install / 'share' / 'gimbal_friction' / 'launch' / 'gimbal_friction.launch.py').exists()
    # what `ros2 run gimbal_friction <exe>` does: ament index prefix, then an executable file under lib/<pkg>
    for exe in EXECUTABLES:
        path = install / 'lib' / 'gimbal_friction' / exe
        assert path.is_file() and os.access(path, os.X_OK), exe
    # the installed package carries the packaged defaults (importlib.resources path)
    site = list(install.glob('lib/python3*/site-packages/gimbal_friction/data/gimbal_friction.yaml'))
    assert site and 'ros__parameters' in site[0].read_text()
