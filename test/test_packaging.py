"""The ament_python package builds with colcon and installs what ``ros2 run`` looks up."""

from __future__ import annotations

import ast
import os
import re
import shutil
import subprocess
import sys
import types
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

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


def _run_launch_file(monkeypatch, configurations):
    """generate_launch_description() against recording stand-ins of launch / launch_ros (not on PyPI), then its
    OpaqueFunction with ``configurations`` as the launch arguments. Returns (declared argument names, nodes made
    (their keyword arguments), LogInfo texts)."""
    import importlib.util
    import types

    made: list[dict] = []
    logged: list[str] = []

    class Recorder:
        def __init__(self, *args, **kwargs):
            self.args, self.kwargs = args, kwargs

    class Node(Recorder):
        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            made.append(kwargs)

    class LogInfo(Recorder):
        def __init__(self, msg):
            super().__init__(msg=msg)
            logged.append(msg)

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
    modules['launch.actions'].OpaqueFunction = Recorder
    modules['launch.actions'].LogInfo = LogInfo
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
    declared = {a.args[0]: a.kwargs.get('default_value') for a in description.args[0] if a.args}
    opaque = [a for a in description.args[0] if 'function' in a.kwargs]
    assert len(opaque) == 1
    context = types.SimpleNamespace(launch_configurations={**declared, **configurations})
    opaque[0].kwargs['function'](context, *opaque[0].kwargs.get('args', []))
    return declared, {n['executable']: n for n in made}, logged


def test_launch_file_describes_the_suite(monkeypatch):
    """Every node the launch file starts is an executable of setup.py, gets the packaged parameter file once and
    first, and gimbal_sim only on sim:=true. (On a full ROS 2 install `ros2 launch gimbal_friction
    gimbal_friction.launch.py` runs the same.)"""
    declared, started, _ = _run_launch_file(monkeypatch, {})
    assert {'params_file', 'log_dir', 'sim', 'sim_params_file', 'autostart'} <= set(declared)
    setup = (ROOT / 'setup.py').read_text()
    assert set(started) == {'friction_feedforward', 'friction_estimator', 'residual_logger', 'gimbal_sim'}
    packaged = '/share/gimbal_friction/config/gimbal_friction.yaml'
    for exe, node in started.items():
        assert node['package'] == 'gimbal_friction' and re.search(rf"'{exe} = gimbal_friction\.", setup), exe
        assert node['parameters'][0] == packaged, exe
        assert node['parameters'].count(packaged) == 1, exe  # loaded once, not as defaults and again as the file
        assert ('condition' in node) == (exe == 'gimbal_sim'), exe


def test_launch_file_layers_a_user_file_once_and_resolves_the_log_folder(monkeypatch, tmp_path):
    """A relative log_dir is made absolute against the folder ros2 launch runs in, and printed; the default folder
    does not depend on that folder; a params_file naming the packaged file is not loaded twice."""
    packaged = '/share/gimbal_friction/config/gimbal_friction.yaml'
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv('ROS_HOME', str(tmp_path / 'ros_home'))
    _, started, logged = _run_launch_file(monkeypatch, {'log_dir': 'runs/today', 'params_file': 'extra.yaml'})
    folder = str(tmp_path / 'runs' / 'today')
    assert {'output_dir': folder} in started['residual_logger']['parameters']
    assert started['friction_estimator']['parameters'] == [packaged, 'extra.yaml', {'autostart': True}]
    assert len(logged) == 1 and folder in logged[0] and 'extra.yaml' in logged[0]
    _, started, logged = _run_launch_file(monkeypatch, {'params_file': packaged})
    default = str(tmp_path / 'ros_home' / 'gimbal_friction' / 'residuals')
    assert {'output_dir': default} in started['residual_logger']['parameters'] and default in logged[0]
    assert started['friction_feedforward']['parameters'] == [packaged, {'autostart': True}]


def test_launch_file_passes_autostart_to_the_managed_nodes_only(monkeypatch):
    """autostart (default true) reaches the three managed nodes as a bool, last (over the files); gimbal_sim, a
    plain node, does not get it; a value that is not true or false stops the launch naming the argument."""
    from gimbal_friction.config.loader import MANAGED_NODES

    for text, value in (('true', True), ('false', False), ('False', False), ('1', True)):
        declared, started, logged = _run_launch_file(monkeypatch, {'autostart': text})
        assert declared['autostart'] == 'true'
        for exe in MANAGED_NODES:
            assert started[exe]['parameters'][-1] == {'autostart': value}, (exe, text)
        assert not any('autostart' in p for p in started['gimbal_sim']['parameters'] if isinstance(p, dict))
        assert ('lifecycle manager' in logged[0]) == (not value), logged
    with pytest.raises(ValueError, match='autostart'):
        _run_launch_file(monkeypatch, {'autostart': 'maybe'})


class _StandInModule(types.ModuleType):
    """A stand-in for a module of launch / launch_ros (not on PyPI): every name is a class that records the
    arguments of each instance (in ``made``, by name)."""

    def __init__(self, name: str, made: dict[str, list[types.SimpleNamespace]]) -> None:
        super().__init__(name)
        self._made = made

    def __getattr__(self, attr: str):
        if attr.startswith('__'):
            raise AttributeError(attr)
        made = self._made

        class Recorder(types.SimpleNamespace):
            def __init__(self, *args, **kwargs):
                super().__init__(args=args, kwargs=kwargs)
                made.setdefault(attr, []).append(self)

        Recorder.__name__ = attr
        setattr(self, attr, Recorder)
        return Recorder


def _load_launch_file(monkeypatch, name: str, configurations: dict[str, str]):
    """The route by which the launch files are tested where launch / launch_ros are absent (PyPI wheels): the file
    is imported with every launch, launch_ros and ament_index_python module a recording stand-in, its
    generate_launch_description() called, then its OpaqueFunction with the declared defaults overlaid with
    ``configurations``. Returns (declared arguments and defaults, what the OpaqueFunction returned, the stand-ins
    made by name). ``ros2 launch`` on a ROS 2 install runs the same functions with the real classes."""
    import importlib.util

    made: dict[str, list[types.SimpleNamespace]] = {}
    for mod in ('launch', 'launch.actions', 'launch.conditions', 'launch.event_handlers', 'launch.events',
                'launch.substitutions', 'launch_ros', 'launch_ros.actions', 'ament_index_python',
                'ament_index_python.packages'):
        monkeypatch.setitem(sys.modules, mod, _StandInModule(mod, made))
    spec = importlib.util.spec_from_file_location(f'gf_launch_{name}', ROOT / 'launch' / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    (entities,) = module.generate_launch_description().args
    declared = {a.args[0]: a.kwargs['default_value'] for a in entities if type(a).__name__ == 'DeclareLaunchArgument'}
    (opaque,) = [a for a in entities if type(a).__name__ == 'OpaqueFunction']
    context = types.SimpleNamespace(launch_configurations={**declared, **configurations})
    actions = opaque.kwargs['function'](context, *opaque.kwargs.get('args', []))
    return declared, actions, made


def test_closed_loop_launch_file_starts_the_loop_as_loop_study_live(monkeypatch, tmp_path):
    """closed_loop.launch.py starts what loop-study --live starts (gimbal_friction.runs.loop_wiring, the one source
    of both; test/runs/test_loop_wiring.py holds the live study to it): the three nodes and gimbal_sim, under their
    names, each with the loop's parameter files and parameters, with loop-study --live's defaults; gimbal_sim's end
    shuts the launch down."""
    from gimbal_friction.runs.loop_study import load_study_inputs
    from gimbal_friction.runs.loop_wiring import SimRun, closed_loop, write_parameter_files

    work = tmp_path / 'loop'
    declared, actions, made = _load_launch_file(monkeypatch, 'closed_loop.launch.py', {'work_dir': str(work)})
    assert {'params_file', 'axis', 'work_dir', 'temperature_c', 'profile', 'duration_s', 'use_feedforward',
            'realtime_factor', 'publish_every_ticks', 'exit_when_done', 'autostart'} == set(declared)
    assert declared['autostart'] == 'true'
    nodes = [a.kwargs for a in actions if type(a).__name__ == 'Node']
    inputs = load_study_inputs([])
    files = write_parameter_files(inputs, tmp_path / 'expected')
    launched = [work / 'params' / f.name for f in files]
    for mine, expected in zip(launched, files, strict=True):
        assert mine.read_text() == expected.read_text(), mine.name
    run = SimRun(duration_s=inputs.sim.profile_duration_s('tracking'), record_path=str(work / 'run_feedforward.npz'))
    specs = closed_loop(launched, work / 'residuals', run)
    assert [(n['name'], n['executable'], n['package']) for n in nodes] == [
        (s.name, s.executable, 'gimbal_friction') for s in specs]
    assert [n['name'] for n in nodes] == ['friction_feedforward', 'friction_estimator', 'residual_logger',
                                          'gimbal_sim']
    for node, spec in zip(nodes, specs, strict=True):
        managed = [{'autostart': True}] if spec.name != 'gimbal_sim' else []   # the managed nodes get autostart
        assert node['parameters'] == [*map(str, launched), dict(spec.parameters), *managed], spec.name
        assert node['remappings'] == list(spec.remappings), spec.name
        # the loop's error reaches the feedforward's judge; no other node is remapped
        assert spec.remappings == ((('/gimbal/loop_error', '/gimbal_sim/los_error'),)
                                   if spec.name == 'friction_feedforward' else ()), spec.name
    assert nodes[2]['parameters'][-2] == {'output_dir': str(work / 'residuals')}
    sim = nodes[3]['parameters'][-1]
    assert sim == {'environment_temperature_c': -40.0, 'profile': 'tracking',
                   'duration_s': inputs.sim.profile_duration_s('tracking'), 'exit_when_done': True,
                   'use_feedforward': True, 'wait_for_subscribers': 3, 'wait_for_feedforward': True,
                   'realtime_factor': 1.0, 'record_path': str(work / 'run_feedforward.npz'), 'publish_every_ticks': 2}
    (handler,) = made['OnProcessExit']
    assert handler.kwargs['target_action'].kwargs['name'] == 'gimbal_sim'
    assert [type(a).__name__ for a in handler.kwargs['on_exit']] == ['LogInfo', 'EmitEvent']


def test_closed_loop_launch_arguments_reach_the_nodes(monkeypatch, tmp_path):
    """A user's parameter file is layered like loop-study --config; the run's arguments reach gimbal_sim."""
    extra = tmp_path / 'extra.yaml'
    extra.write_text('gimbal_sim:\n  ros__parameters:\n    scan_duration_s: 7.5\n')
    monkeypatch.chdir(tmp_path)
    _, actions, made = _load_launch_file(monkeypatch, 'closed_loop.launch.py', {
        'work_dir': 'rel', 'params_file': str(extra), 'profile': 'scan', 'use_feedforward': 'false',
        'temperature_c': '60', 'exit_when_done': 'false', 'publish_every_ticks': '4'})
    nodes = {a.kwargs['name']: a.kwargs for a in actions if type(a).__name__ == 'Node'}
    sim = nodes['gimbal_sim']['parameters'][-1]
    assert sim['duration_s'] == 7.5 and sim['profile'] == 'scan' and sim['environment_temperature_c'] == 60.0
    assert sim['use_feedforward'] is False and sim['wait_for_feedforward'] is False
    assert sim['exit_when_done'] is False and sim['publish_every_ticks'] == 4
    assert sim['record_path'] == str(tmp_path / 'rel' / 'run_none.npz')
    assert 'scan_duration_s: 7.5' in (tmp_path / 'rel' / 'params' / 'study.yaml').read_text()
    assert 'OnProcessExit' not in made   # without exit_when_done the launch keeps running
    _, actions, _ = _load_launch_file(monkeypatch, 'closed_loop.launch.py', {'work_dir': 'rel', 'autostart': 'false'})
    nodes = {a.kwargs['name']: a.kwargs for a in actions if type(a).__name__ == 'Node'}
    for name in ('friction_feedforward', 'friction_estimator', 'residual_logger'):
        assert nodes[name]['parameters'][-1] == {'autostart': False}, name
    assert 'autostart' not in nodes['gimbal_sim']['parameters'][-1]


@pytest.mark.slow
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
    for launch_file in ('gimbal_friction.launch.py', 'closed_loop.launch.py'):
        assert (install / 'share' / 'gimbal_friction' / 'launch' / launch_file).exists(), launch_file
    # what `ros2 run gimbal_friction <exe>` does: ament index prefix, then an executable file under lib/<pkg>
    for exe in EXECUTABLES:
        path = install / 'lib' / 'gimbal_friction' / exe
        assert path.is_file() and os.access(path, os.X_OK), exe
    # the installed package carries the packaged defaults (importlib.resources path)
    site = list(install.glob('lib/python3*/site-packages/gimbal_friction/data/gimbal_friction.yaml'))
    assert site and 'ros__parameters' in site[0].read_text()


@pytest.mark.slow
def test_the_test_command_runs_on_every_core_and_passes_arguments_through():
    """scripts/test.sh (what CI runs) spreads the tests over workers (pytest-xdist, pinned in
    requirements-test.txt), each test file whole on one worker, and a user's pytest arguments still pass through
    after its own (here a selection, and the worker count)."""
    assert re.search(r'^pytest-xdist==', (ROOT / 'requirements-test.txt').read_text(), re.MULTILINE)
    env = dict(os.environ, TEST_WORKERS='2')
    selection = ['test/test_packaging.py', '-k', 'package_xml', '-p', 'no:randomly']
    out = subprocess.run(['bash', 'scripts/test.sh', *selection], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert 'created: 2/2 workers' in out.stdout and ' 1 passed' in out.stdout
    one = subprocess.run(['bash', 'scripts/test.sh', *selection, '-n', '0'], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert one.returncode == 0, one.stdout[-2000:] + one.stderr[-2000:]
    assert 'workers' not in one.stdout and re.search(r'1 passed, \d+ deselected', one.stdout)   # in this process
