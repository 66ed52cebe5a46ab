"""Parameters at start-up: what rcl gives a node from ``--params-file`` and ``-p``, and what the nodes refuse.

- ``command_line_parameters`` resolves a command line exactly as rcl + rclpy do (differential test against rclpy on
  generated command lines: files with node sections and wildcards, typed scalars spelled every way rcl reads them,
  ``-p`` rules with and without node prefix, renamed nodes) and also knows the value the user wrote last, which rcl
  drops when a file set the name with another type (``--params-file config.yaml -p model.ball_count:=15.5`` gave
  the file's 15).
- Every parameter of every node, given a wrong-typed or impossible value with ``-p`` over the packaged file, stops
  the node with exit code 1 and one line naming the parameter (run through ``run_node``, the executables' main).
- Misspelled names in a file or on the command line are refused; names of other nodes of the suite shared under
  ``/**`` are not.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import threading
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.config.loader import (
    CHAMBER_REPLAY_PARAMETERS,
    MODEL_PARAMETERS,
    ROS_PARAMETERS,
    check_parameter_names,
    node_parameter_names,
)
from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
from gimbal_friction.config.rcl import command_line_parameters, rcl_scalar
from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.params import parameter_specs

rclpy = pytest.importorskip('rclpy')
from rclpy.node import Node  # noqa: E402

pytestmark = pytest.mark.ros  # real rclpy nodes and contexts on an isolated domain
ROOT = Path(__file__).resolve().parents[2]
PACKAGED = str(ROOT / 'config' / 'gimbal_friction.yaml')
FF = 'friction_feedforward'


@pytest.fixture(scope='module')
def domain() -> Any:
    from gimbal_friction.runs.supervisor import free_domain
    with free_domain() as did:
        yield did


def rclpy_overrides(argv: list[str], node_name: str, domain: int) -> dict[str, Any] | None:
    """The parameter overrides rclpy gives a node built with ``argv`` (None: rcl refused the arguments)."""
    ctx = rclpy.Context()
    try:
        rclpy.init(args=['test', *argv], context=ctx, domain_id=domain)
    except Exception:  # rcl refuses the command line (e.g. a list of mixed types)
        return None
    try:
        node = Node(node_name, context=ctx, start_parameter_services=False)
        out = {}
        for name, p in node._parameter_overrides.items():
            v = p.value
            out[name] = list(v) if isinstance(v, (list, tuple)) or type(v).__name__ == 'array' else v
        node.destroy_node()
        return out
    finally:
        ctx.try_shutdown()


def same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


# ------------------------------------------------------------------------------------------------ rcl's typing
SPELLINGS = ['1', '-3', '+5', '0x1F', '010', '08', '1.5', '1.', '.5', '1e-5', '1E3', '1e400', '-1e400', '1e-400',
             '5e-324', 'nan', '.nan', '-.inf', 'inf', 'Infinity', 'yes', 'No', 'ON', 'off', 'True', 'y', 'abc',
             '1_000', '0x', '~', 'null', '"1.0"', "'true'", '99999999999999999999', '0xFFFFFFFFFFFFFFFFFF', '-0']


def test_scalars_are_typed_as_rcl_types_them(tmp_path, domain):
    """rcl_scalar against rclpy itself, for spellings where PyYAML and rcl disagree (1e-5, 1e400, nan, 0x1F...)."""
    f = tmp_path / 'scalars.yaml'
    f.write_text('/**:\n  ros__parameters:\n' + ''.join(f'    p{k}: {t}\n' for k, t in enumerate(SPELLINGS)))
    got = rclpy_overrides(['--ros-args', '--params-file', str(f)], FF, domain)
    assert got is not None
    for k, text in enumerate(SPELLINGS):
        quoted = text[:1] in ('"', "'")
        mine = rcl_scalar(text.strip('"\'') if quoted else text, quoted=quoted)
        assert same(mine, got[f'p{k}']), (text, mine, got[f'p{k}'])


# ------------------------------------------------------------------------------------------------ resolution
NAMES = ['a', 'b', 'm.n', 'model.ball_count']
NODE_KEYS = ['/**', FF, '/' + FF, 'other', '/*', '**', '/**/' + FF, 'ns/' + FF]
SCALAR_TEXT = st.sampled_from(['1', '2', '15.5', '-0.5', 'abc', 'true', '1e-5', '1e400', '"x"', '0x10', 'nan'])
VALUE_TEXT = st.one_of(SCALAR_TEXT, st.sampled_from(['[1, 2]', '[a, b]', '[1.5]', '[true, false]', '[]', '[1, a]']))


@st.composite
def command_line(draw: st.DrawFn, tmp: Path) -> list[str]:
    argv: list[str] = ['--ros-args']
    for k in range(draw(st.integers(1, 5))):
        if draw(st.booleans()):
            sections = draw(st.lists(st.tuples(st.sampled_from(NODE_KEYS),
                                               st.lists(st.tuples(st.sampled_from(NAMES), VALUE_TEXT), max_size=4)),
                                     min_size=1, max_size=3))
            lines = []
            for key, params in sections:
                lines.append(f'"{key}":\n  ros__parameters:')
                lines += [f'    {name}: {text}' for name, text in dict(params).items()] or ['    {}']
            path = tmp / f'f{len(list(tmp.iterdir()))}_{k}.yaml'
            path.write_text('\n'.join(lines).replace('  ros__parameters:\n    {}', '  ros__parameters: {}') + '\n')
            argv += ['--params-file', str(path)]
        else:
            prefix = draw(st.sampled_from(['', f'{FF}:', 'other:']))
            argv += ['-p', f'{prefix}{draw(st.sampled_from(NAMES))}:={draw(VALUE_TEXT)}']
    if draw(st.booleans()):
        argv += ['-r', draw(st.sampled_from(['__node:=renamed', '__ns:=/ns', f'{FF}:__node:=x', 'y:__node:=z']))]
    return argv


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_resolution_equals_rclpy_and_knows_what_rcl_dropped(data, tmp_path, domain):
    argv = data.draw(command_line(tmp_path))
    got = rclpy_overrides(argv, FF, domain)
    if got is None:
        with pytest.raises(ConfigError):   # what rcl refuses, we refuse too
            command_line_parameters(['x', *argv], FF)
        return
    cl = command_line_parameters(['x', *argv], FF)
    as_rclpy = {**cl.values, **cl.ignored_by_rcl}
    assert set(as_rclpy) == set(got)
    for name, value in got.items():
        assert same(as_rclpy[name], value), (name, argv)
    for name, dropped in cl.ignored_by_rcl.items():   # the user's last value differs from what rclpy reads
        assert not same(cl.values[name], dropped)


def test_the_issue_command_line(tmp_path):
    cl = command_line_parameters(['x', '--ros-args', '--params-file', PACKAGED, '-p', 'model.ball_count:=15.5'], FF)
    assert cl.values['model.ball_count'] == 15.5 and cl.ignored_by_rcl == {'model.ball_count': 15}
    assert cl.sources['model.ball_count'] == '-p model.ball_count:=15.5'
    assert cl.node == '/friction_feedforward'


# ------------------------------------------------------------------------------------------------ names
def test_misspelled_and_foreign_names(tmp_path):
    values = {'model.bal_count': 16}
    with pytest.raises(ConfigError, match=r"did you mean 'model\.ball_count'"):
        check_parameter_names(FF, values)
    with pytest.raises(ConfigError, match=r"did you mean 'stale_policy'.*from f\.yaml"):
        check_parameter_names(FF, {'stale_polcy': 'zero'}, sources={'stale_polcy': 'f.yaml'})
    with pytest.raises(ConfigError, match=r'a QoS override is qos_overrides\.<topic>\.<publisher\|subscription>'):
        check_parameter_names('residual_logger', {'qos_overrides./x.depth': 5})   # (the form, not a name)
    with pytest.raises(ConfigError, match="axis 'azimuth' is not configured"):
        check_parameter_names(FF, {'axis.azimuth.interference_mm': 0.004})
    check_parameter_names(FF, {'axes': ['elevation', 'azimuth'], 'axis.azimuth.interference_mm': 0.004})
    with pytest.raises(ConfigError, match='not of friction_feedforward'):
        check_parameter_names(FF, {'method': 'observer'}, node_specific={'method'})
    check_parameter_names(FF, {'method': 'observer', 'output_dir': 'x', 'bag': 'b',   # shared under /**
                               'inertia_truth_ratio': 1.0})                       # (gimbal_sim's)
    with pytest.raises(ConfigError, match='non-empty list'):
        check_parameter_names(FF, {'axes': []}, sources={'axes': '-p axes:=[]'})


def test_the_packaged_file_is_accepted_by_every_node():
    for node in ('friction_feedforward', 'friction_estimator', 'residual_logger', 'chamber_replay', 'gimbal_sim'):
        cl = command_line_parameters(['x', '--ros-args', '--params-file', PACKAGED], node)
        check_parameter_names(node, cl.values, cl.node_specific, cl.sources)
        assert cl.ignored_by_rcl == {}


def test_chamber_replay_names_are_its_declarations(monkeypatch, domain):
    """CHAMBER_REPLAY_PARAMETERS (config.py) lists exactly what chamber_replay declares."""
    from rclpy.node import Node as RclNode

    from gimbal_friction.nodes.chamber_replay import ChamberReplay
    declared: list[str] = []
    original = RclNode.declare_parameter

    def record(self: Any, name: str, *args: Any, **kwargs: Any) -> Any:
        declared.append(name)
        return original(self, name, *args, **kwargs)

    monkeypatch.setattr(RclNode, 'declare_parameter', record)
    ctx = rclpy.Context()
    rclpy.init(args=['x'], context=ctx, domain_id=domain)
    try:
        with pytest.raises(ConfigError):   # no bag given: refused after declaring everything
            ChamberReplay(context=ctx, start_parameter_services=False)
    finally:
        ctx.try_shutdown()
    assert sorted(set(declared) - set(ROS_PARAMETERS)) == sorted(CHAMBER_REPLAY_PARAMETERS)


# ------------------------------------------------------------------------------------------------ every parameter
def _wrong_values(default: Any, bound: Any = None, choices: Any = None) -> list[str]:
    """-p spellings of a wrong type or an impossible value for a parameter with this default."""
    if isinstance(default, bool):
        return ['abc', '1']
    if isinstance(default, int):
        out = ['15.5', 'abc', 'nan', '-.inf']
    elif isinstance(default, float):
        out = ['abc', '[1.0, 2.0]', 'nan', '1e400']
    else:
        return ['5', '[a, b]'] if choices is None else ['5', 'no_such_choice']
    if bound is not None and bound.high is not None:
        out.append(repr(float(bound.high) * 10 + 1) if isinstance(default, float) else str(int(bound.high) * 10 + 1))
    elif bound is not None and bound.low is not None:
        out.append(repr(float(bound.low) - 1.0) if isinstance(default, float) else str(int(bound.low) - 1))
    return out


def _cases() -> list[tuple[str, str, str]]:
    cases = []
    for spec in parameter_specs():
        for node in ('friction_feedforward', 'friction_estimator'):
            for text in _wrong_values(spec['default'], spec['bound'], spec['choices'])[:1 if node != FF else None]:
                cases.append((node, f'model.{spec["name"]}', text))
    for node, classes in (('friction_feedforward', (FeedforwardSettings, FeedforwardNodeSettings)),
                          ('friction_estimator', (EstimatorSettings, EstimatorNodeSettings)),
                          ('residual_logger', (LoggerSettings,))):
        for cls in classes:
            for f in dataclasses.fields(cls):
                absurd = ['1e300', '-1e300'] if isinstance(f.default, (int, float)) and \
                    not isinstance(f.default, bool) else []
                for text in _wrong_values(f.default) + absurd:
                    cases.append((node, f.name, text))
    return cases


CASES = _cases()
# values that parse but are possible for these parameters (the type or the bound is what the test is about)
ALLOWED = {('position_min_rad', '-1e300'), ('position_max_rad', '1e300')}


@pytest.fixture
def isolated_env(monkeypatch, tmp_path, domain):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path / 'roslog'))


def _main(node: str) -> Any:
    if node == 'friction_feedforward':
        from gimbal_friction.nodes.feedforward import FrictionFeedforward
        return FrictionFeedforward
    if node == 'friction_estimator':
        from gimbal_friction.nodes.estimator import FrictionEstimator
        return FrictionEstimator
    from gimbal_friction.nodes.residual_logger import ResidualLogger
    return ResidualLogger


@pytest.mark.slow
def test_every_parameter_with_a_wrong_value_stops_the_node_naming_it(isolated_env, capfd, tmp_path):
    """Each of ~270 cases through run_node (the executables' main) on the documented start command: exit 1, one
    line on stderr naming the parameter and where the value came from, no traceback, no node left running."""
    from gimbal_friction.nodes._common import run_node
    failures = []
    for node, name, text in CASES:
        if (name, text) in ALLOWED:
            continue
        extra = ['-p', f'output_dir:={tmp_path / "log"}'] if node == 'residual_logger' else []
        argv = [node, '--ros-args', '--params-file', PACKAGED, *extra, '-p', f'{name}:={text}']
        guard = threading.Timer(5.0, os.kill, (os.getpid(), signal.SIGINT))  # an accepted value: stop the node
        guard.start()
        try:
            code = run_node(node, _main(node), argv, suite_node=node)
        finally:
            guard.cancel()
        err = capfd.readouterr().err
        lines = [line for line in err.splitlines() if f'{node}: error:' in line]
        if code != 1 or len(lines) != 1 or name not in lines[0] or 'Traceback' in err:
            failures.append((node, name, text, code, err.strip()[-300:]))
    assert not failures, '\n'.join(map(str, failures[:10]))
    assert len(CASES) > 300


def test_the_file_and_the_command_line_name_the_source(isolated_env, capfd, tmp_path):
    from gimbal_friction.nodes._common import run_node
    from gimbal_friction.nodes.feedforward import FrictionFeedforward
    bad = tmp_path / 'mine.yaml'
    bad.write_text(yaml.safe_dump({'/**': {'ros__parameters': {'model': {'bal_count': 16}}}}))
    code = run_node(FF, FrictionFeedforward, [FF, '--ros-args', '--params-file', PACKAGED, '--params-file', str(bad)],
                    suite_node=FF)
    err = capfd.readouterr().err.strip()
    assert code == 1 and err == (f"{FF}: error: parameter 'model.bal_count' = 16: unknown parameter (did you mean "
                                 f"'model.ball_count'?) (from {bad})")
    # a -p of the right meaning but another type than the file's (16.0 for the file's 15) is applied, not dropped
    from gimbal_friction.nodes import _common
    overrides, _ = _common.startup_overrides([FF, '--ros-args', '--params-file', PACKAGED, '-p',
                                              'model.ball_count:=16.0'], FF)
    assert [(p.name, p.value) for p in overrides] == [('model.ball_count', 16.0)]


def test_model_parameters_are_the_axis_fields():
    assert set(MODEL_PARAMETERS) == {s['name'] for s in parameter_specs()}
    names = node_parameter_names('friction_estimator', ['elevation'])
    assert 'axis.elevation.ball_count' in names and 'use_sim_time' in names and 'output_dir' not in names
    assert Path(PACKAGED).exists()


# ------------------------------------------------------------------------------------------------ one rule, all nodes
@pytest.mark.parametrize('node', ['residual_logger', 'chamber_replay'])
@pytest.mark.parametrize(('rule', 'name'), [('model.ball_count:=abc', 'model.ball_count'),
                                            ('model.ball_diameter_mm:=-1.0', 'model.ball_diameter_mm'),
                                            ('axis.elevation.width_mm:=abc', 'axis.elevation.width_mm'),
                                            ('max_torque_nm:=abc', 'max_torque_nm'),
                                            ('method:=guess', 'method'),
                                            ('rate:=fast', 'rate')])
def test_a_node_refuses_an_invalid_value_of_a_parameter_it_does_not_use(node, rule, name):
    """The shared file gives every node every parameter: a node that does not use one refuses an invalid value of
    it like the node that uses it does, naming it and where it came from (used to start silently)."""
    from gimbal_friction.nodes._common import startup_overrides
    if node == 'chamber_replay' and name == 'rate':
        node = 'residual_logger'  # rate is chamber_replay's own: checked by the node itself
    argv = [node, '--ros-args', '--params-file', PACKAGED, '-p', rule]
    with pytest.raises(ConfigError) as err:
        startup_overrides(argv, node)
    assert err.value.parameter == name and f'(from -p {rule})' in str(err.value)


def test_valid_values_of_other_nodes_parameters_are_accepted():
    from gimbal_friction.nodes._common import startup_overrides
    sim = str(ROOT / 'config' / 'gimbal_sim.yaml')
    for node in ('friction_feedforward', 'friction_estimator', 'residual_logger', 'chamber_replay', 'gimbal_sim'):
        startup_overrides([node, '--ros-args', '--params-file', PACKAGED, '--params-file', sim, '-p',
                           'model.ball_count:=16', '-p', 'max_torque_nm:=0.01', '-p', 'rate:=2.0'], node)


def test_the_issue_command_line_stops_the_logger_naming_the_parameter(isolated_env, capfd, tmp_path):
    from gimbal_friction.nodes._common import run_node
    from gimbal_friction.nodes.residual_logger import ResidualLogger
    node = 'residual_logger'
    argv = [node, '--ros-args', '--params-file', PACKAGED, '-p', f'output_dir:={tmp_path / "log"}',
            '-p', 'model.ball_count:=abc']
    code = run_node(node, ResidualLogger, argv, suite_node=node)
    err = capfd.readouterr().err.strip()
    assert code == 1 and err == ("residual_logger: error: parameter 'model.ball_count' = 'abc': must be a number, "
                                 'not str (from -p model.ball_count:=abc)')
    assert not (tmp_path / 'log').exists()


# ------------------------------------------------------------------------------------------------ --help
EXECUTABLES = {'friction_feedforward': 'feedforward', 'friction_estimator': 'estimator',
               'residual_logger': 'residual_logger', 'chamber_replay': 'chamber_replay', 'gimbal_sim': 'gimbal_sim'}


@pytest.mark.parametrize('exe', sorted(EXECUTABLES))
@pytest.mark.parametrize('flag', ['--help', '-h'])
def test_help_prints_parameters_and_topics_without_starting_ros(exe, flag, monkeypatch, capsys):
    """Every executable answers --help / -h with its usage, topics and every parameter (default, unit) and exits 0;
    rclpy.init is never called (it would start the node)."""
    import importlib

    from gimbal_friction.config.loader import node_parameter_names
    module = importlib.import_module(f'gimbal_friction.nodes.{EXECUTABLES[exe]}')

    def no_init(*args: Any, **kwargs: Any) -> None:
        raise AssertionError('--help started ROS')

    monkeypatch.setattr(rclpy, 'init', no_init)
    with pytest.raises(SystemExit) as stop:
        module.main([exe, flag])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f'usage: {exe} ') and '/joint_states' in out
    assert '/diagnostics' in out  # chamber_replay: in what it does not republish by default
    listed = {line.split(' = ')[0].strip() for line in out.splitlines() if line.startswith('  ') and ' = ' in line}
    declared = node_parameter_names(exe, ['<joint>']) - set(ROS_PARAMETERS)
    assert {n for n in declared if not n.startswith('axis.')} <= listed
    assert any(n.startswith('axis.') for n in declared) == ('axis.<joint>.<field>' in listed)
    if exe != 'chamber_replay':
        assert 'axes = ' in out
    if exe in ('friction_feedforward', 'friction_estimator', 'gimbal_sim'):
        assert 'model.ball_count = 15:' in out and 'model.width_mm = 5.0 [mm]:' in out


def test_help_only_among_the_programs_own_arguments():
    from gimbal_friction.nodes._common import wants_help
    assert wants_help(['x', '--help']) and wants_help(['x', '-h', '--ros-args', '-p', 'a:=1'])
    assert not wants_help(['x', '--ros-args', '-r', '__node:=-h']) and not wants_help(['x'])


@pytest.mark.slow
def test_help_of_the_installed_executable(tmp_path):
    """What `ros2 run gimbal_friction friction_feedforward --help` runs: the console script, exit 0, no node."""
    import shutil
    import subprocess
    import sys
    exe = shutil.which('friction_feedforward', path=str(Path(sys.executable).parent))
    assert exe is not None
    proc = subprocess.run([exe, '--help'], capture_output=True, text=True, timeout=60,
                          env={**os.environ, 'ROS_LOG_DIR': str(tmp_path)})
    assert proc.returncode == 0 and proc.stdout.startswith('usage: friction_feedforward') and not proc.stderr
    version = subprocess.run([str(Path(sys.executable).parent / 'gimbal-friction'), '--version'],
                             capture_output=True, text=True, timeout=60)
    from importlib.metadata import version as installed
    assert version.returncode == 0 and version.stdout.strip() == f'gimbal-friction {installed("gimbal_friction")}'
    assert installed('gimbal_friction') in (ROOT / 'package.xml').read_text()


# ------------------------------------------------------------------------------------------------ bad command lines
@pytest.mark.parametrize('exe', sorted(EXECUTABLES))
@pytest.mark.slow
def test_a_bad_params_file_prints_exactly_one_line(exe, tmp_path, domain):
    """The documented promise: a parameter file that cannot be read, or is not YAML, ends every executable with
    exit code 1 and exactly one line on stderr naming the file (rcl used to print its own "Failed to parse global
    arguments" line before the node's). Arguments only rcl refuses (a malformed remap, a trailing --params-file)
    give one line too. The real executables, stderr apart from stdout."""
    import subprocess
    import sys

    bad_yaml = tmp_path / 'bad.yaml'
    bad_yaml.write_text('a: [1, 2\nb: 3\n')
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_LOG_DIR=str(tmp_path / 'roslog'))
    path = Path(sys.executable).parent / exe  # the executables of this environment
    cmd = [str(path)] if path.exists() else [sys.executable, '-m', f'gimbal_friction.nodes.{exe}']
    cases = [(['--params-file', '/nonexistent.yaml'], 'parameter file /nonexistent.yaml: cannot read'),
             (['--params-file', str(bad_yaml)], f'parameter file {bad_yaml}: not valid YAML'),
             (['--params-file', str(tmp_path)], 'cannot read'),
             (['-r', 'foo'], "cannot start: failed to initialize rcl: Couldn't parse remap rule"),
             (['--params-file'], 'cannot start: failed to initialize rcl')]
    for args, said in cases:
        run = subprocess.run([*cmd, '--ros-args', *args], env=env, capture_output=True, text=True, timeout=60)
        lines = run.stderr.splitlines()
        assert run.returncode == 1 and len(lines) == 1, (args, run.returncode, run.stderr)
        assert lines[0].startswith(f'{exe}: error: ') and said in lines[0], (args, lines[0])
