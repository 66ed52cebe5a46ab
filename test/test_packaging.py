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

ROOT = Path(__file__).resolve().parents[1]
EXECUTABLES = ('friction_feedforward', 'friction_estimator', 'residual_logger', 'chamber_replay', 'gimbal_sim')


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


def test_launch_file_describes_the_suite(monkeypatch):
    """Runs generate_launch_description() against recording stand-ins of launch / launch_ros (not on PyPI): every
    node it starts is an executable of setup.py, gets the packaged parameter file first, and gimbal_sim only on
    sim:=true. (On a full ROS 2 install `ros2 launch gimbal_friction gimbal_friction.launch.py` runs the same.)"""
    import importlib.util
    import types

    made: list[dict] = []

    class Recorder:
        def __init__(self, *args, **kwargs):
            self.args, self.kwargs = args, kwargs

    class Node(Recorder):
        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            made.append(kwargs)

    modules = {
        'launch': types.ModuleType('launch'), 'launch.actions': types.ModuleType('launch.actions'),
        'launch.conditions': types.ModuleType('launch.conditions'),
        'launch.substitutions': types.ModuleType('launch.substitutions'),
        'launch_ros': types.ModuleType('launch_ros'), 'launch_ros.actions': types.ModuleType('launch_ros.actions'),
        'ament_index_python': types.ModuleType('ament_index_python'),
        'ament_index_python.packages': types.ModuleType('ament_index_python.packages'),
    }
    modules['launch'].LaunchDescription = Recorder
    modules['launch.actions'].DeclareLaunchArgument = Recorder
    modules['launch.conditions'].IfCondition = Recorder
    modules['launch.substitutions'].LaunchConfiguration = lambda name: ('config', name)
    modules['launch_ros.actions'].Node = Node
    modules['ament_index_python.packages'].get_package_share_directory = lambda pkg: f'/share/{pkg}'
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('gf_launch', ROOT / 'launch' / 'gimbal_friction.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    arguments = {a.args[0] for a in description.args[0] if isinstance(a, Recorder) and a not in made and a.args}
    assert {'params_file', 'log_dir', 'sim', 'sim_params_file'} <= arguments
    setup = (ROOT / 'setup.py').read_text()
    started = {n['executable']: n for n in made}
    assert set(started) == {'friction_feedforward', 'friction_estimator', 'residual_logger', 'gimbal_sim'}
    for exe, node in started.items():
        assert node['package'] == 'gimbal_friction' and re.search(rf"'{exe} = gimbal_friction\.", setup), exe
        assert node['parameters'][0] == '/share/gimbal_friction/config/gimbal_friction.yaml', exe
        assert ('condition' in node) == (exe == 'gimbal_sim'), exe
    assert {'output_dir': ('config', 'log_dir')} in started['residual_logger']['parameters']


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
