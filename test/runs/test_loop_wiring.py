"""The closed loop's wiring (gimbal_friction.runs.loop_wiring): what ``loop-study --live`` starts is what it says,
the same wiring closed_loop.launch.py hands to launch_ros (test/test_packaging.py)."""

from __future__ import annotations

import contextlib
import types
from typing import ClassVar

import pytest

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.runs import loop_live
from gimbal_friction.runs.loop_study import load_study_inputs
from gimbal_friction.runs.loop_wiring import (
    LOOP_ERROR_REMAP,
    LOOP_NODES,
    SimRun,
    closed_loop,
    loop_nodes,
    write_parameter_files,
)


def test_the_loop_is_three_nodes_then_gimbal_sim_with_the_live_studys_defaults(tmp_path):
    files = write_parameter_files(load_study_inputs([]), tmp_path / 'params')
    assert [f.name for f in files] == ['packaged.yaml', 'axis.yaml', 'study.yaml']
    study = (tmp_path / 'params' / 'study.yaml').read_text()
    assert 'method: observer' in study and 'gimbal_sim:' in study
    specs = closed_loop(files, tmp_path / 'res', SimRun(duration_s=2.5))
    assert [(s.name, s.executable) for s in specs] == [(n, n) for n in (*LOOP_NODES, 'gimbal_sim')]
    assert all(s.parameter_files == tuple(map(str, files)) for s in specs)
    # the feedforward's loop-error input is the simulated seeker's LOS error (the loop judges the correction)
    assert [s.remappings for s in specs] == [
        ((LOOP_ERROR_REMAP,) if s.name == 'friction_feedforward' else ()) for s in specs]
    assert LOOP_ERROR_REMAP == ('/gimbal/loop_error', '/gimbal_sim/los_error')
    assert '-r' in specs[0].ros_args() and '/gimbal/loop_error:=/gimbal_sim/los_error' in specs[0].ros_args()
    assert [dict(s.parameters) for s in specs[:3]] == [{}, {}, {'output_dir': str(tmp_path / 'res')}]
    assert specs[3].parameters == {
        'environment_temperature_c': -40.0, 'profile': 'tracking', 'duration_s': 2.5, 'exit_when_done': True,
        'use_feedforward': True, 'wait_for_subscribers': 3, 'wait_for_feedforward': True, 'realtime_factor': 1.0,
        'record_path': '', 'publish_every_ticks': 2}
    args = specs[3].ros_args()
    assert args[:7] == ['--ros-args', '--params-file', str(files[0]), '--params-file', str(files[1]),
                        '--params-file', str(files[2])]
    assert args[7:11] == ['-p', 'environment_temperature_c:=-40.0', '-p', 'profile:=tracking']
    assert '-p' in args and 'use_feedforward:=true' in args and 'exit_when_done:=true' in args
    assert SimRun(1.0, use_feedforward=False).parameters()['wait_for_feedforward'] is False
    with pytest.raises(ValueError, match='not a node of the loop'):
        loop_nodes(files, tmp_path, names=['gimbal_sim'])


class _RecordingSupervisor:
    """Stands in for the process supervisor: records what would be started; every start "ends" at once."""

    started: ClassVar[list[tuple[str, str, list[str]]]] = []

    def __init__(self, env, log_dir, *, may_exit=None):
        self.env, self.log_dir = env, log_dir

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def start_as(self, name, exe, args):
        self.started.append((name, exe, list(args)))
        (self.log_dir / f'{name}.log').write_text('')
        return types.SimpleNamespace(poll=lambda: 0, returncode=0)

    def check_alive(self):
        return None

    def stop_all(self, **_kw):
        return {}


def test_the_live_study_starts_the_wiring(monkeypatch, tmp_path):
    """loop-study --live's processes get exactly the wiring's arguments (names, executables, files, parameters):
    what closed_loop.launch.py passes to launch_ros."""
    _RecordingSupervisor.started = []
    monkeypatch.setattr(loop_live, 'Supervisor', _RecordingSupervisor)
    monkeypatch.setattr(loop_live, 'free_domain', lambda **_kw: contextlib.nullcontext(42))
    monkeypatch.setattr(loop_live, '_GraphProbe', lambda domain: types.SimpleNamespace(close=lambda: None))
    monkeypatch.setattr(loop_live, '_wait_connected', lambda *a: None)
    inputs = load_study_inputs([])
    work = tmp_path / 'live'
    with pytest.raises(GimbalFrictionError, match=r'gimbal_sim \(feedforward\) failed'):   # no record: not run
        loop_live.live_study(inputs, duration_s=2.5, work_dir=work)
    files = [work / 'packaged.yaml', work / 'axis.yaml', work / 'study.yaml']
    run = SimRun(duration_s=2.5, record_path=str(work / 'run_feedforward.npz'))
    specs = closed_loop(files, work / 'residuals', run)
    assert _RecordingSupervisor.started == [
        *((s.name, s.executable, s.ros_args()) for s in specs[:3]),
        ('gimbal_sim_feedforward', 'gimbal_sim', specs[3].ros_args())]
