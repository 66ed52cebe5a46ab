"""``gimbal-friction loop-study --live --live-cases learning``: the real friction_feedforward learning in service (the
correction topic changes, the file is saved periodically and at SIGINT, a restart resumes it), and the report that
fails when any of it did not happen."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from gimbal_friction.cli.main import main
from gimbal_friction.feedforward.correction import Correction, load, model_identity
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.runs.live_learning import CorrectionState, correction_state, file_cells, learning_report
from gimbal_friction.sim.study import STUDY_CORRECTION

JOINT = 'elevation'


@pytest.mark.ros
@pytest.mark.slow
def test_the_real_feedforward_learns_saves_and_resumes_after_a_restart(tmp_path, capsys):
    pytest.importorskip('rclpy', reason='the live study needs the ros-* wheels (requirements.txt)')
    out = tmp_path / 'study'
    code = main(['loop-study', '--short', '--temperatures', '-40', '--profiles', 'tracking', '--cases', 'none',
                 '--live', '--live-cases', 'learning', '--live-duration-s', '4', '--format', 'json',
                 # the scan reverses every second: the learner moves a cell once it has both directions
                 '--live-profile', 'scan',
                 '--out', str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    doc = json.loads(captured.out)
    lr = doc['live']['learning']
    assert lr['ok'] and lr['failure'] is None, lr
    # the correction topic changed while gimbal_sim ran: from empty to learned samples and a non-zero correction
    assert lr['correction_messages'] >= 2 and lr['distinct_states'] >= 2 and lr['correction_changed']
    assert lr['samples_first'] == 0 < lr['samples_last'] and lr['cells_with_data_last'] >= 1
    # (a few seconds of learning: the guard may hold every cell back to the model, which applies 0)
    assert 0.0 <= lr['max_correction_nm'] < 0.05
    # saved periodically during the run; the SIGINT leaves the file holding everything learned
    assert lr['file_saved_periodic'] and 0 < lr['periodic_save_samples'] <= lr['samples_last']
    assert lr['stop_exit_code'] == 0 and lr['shutdown_save_samples'] >= lr['samples_last']
    # the restarted node's first correction message holds what the file held, and it learns on in the second run
    assert lr['restart_resumed'] and lr['restart_samples'] == lr['shutdown_save_samples']
    assert lr['resumed_run_samples_last'] > lr['restart_samples']
    # the restarted node never saves periodically: what it learned reached the file only through its SIGINT save
    assert lr['resumed_stop_exit_code'] == 0 and lr['file_saved_at_shutdown']
    assert lr['unsaved_samples_at_stop'] == lr['resumed_run_samples_last'] - lr['restart_samples'] > 0
    assert lr['resumed_shutdown_save_samples'] >= lr['resumed_run_samples_last']
    # the file on disk: the library's reader, against this model; the restarted node saved it again at its stop
    path = Path(lr['correction_file'])
    assert path == out / 'live' / 'correction.yaml'
    saved = load(path, expected=model_identity({JOINT: AxisParams()}))
    assert saved.summary()['samples'] == lr['resumed_shutdown_save_samples']
    live = {r['case']: r for r in doc['records'] if r['mode'] == 'live'}
    assert set(live) == {'learning', 'learning_resumed'}
    for case, rec in live.items():
        assert math.isfinite(rec['rate_error_rms_rad_s']) and lr[f'rate_error_rms_rad_s_{case}'] == \
            rec['rate_error_rms_rad_s']
    text = (out / 'loop_study.txt').read_text()
    assert 'live learning' in text and 'resumed' in text and 'NOT' not in text
    # a second run on the same folder would not start from an empty correction: refused before anything runs
    assert main(['loop-study', '--short', '--temperatures', '-40', '--profiles', 'tracking', '--cases', 'none',
                 '--live', '--live-cases', 'learning', '--out', str(out)]) == 1
    assert 'correction.yaml already exists' in capsys.readouterr().err


# ------------------------------------------------------------------------------------- the report (no ROS needed)
def _correction(samples: int) -> Correction:
    c = Correction(STUDY_CORRECTION, model_identity({JOINT: AxisParams()}))
    n = samples
    c.add_residuals(JOINT, [-40.0] * n, [0.03] * n, [0.001 * k for k in range(n)], [2e-4] * n, [5e-3] * n)
    return c


def _state(stamp: float, c: Correction | None) -> CorrectionState:
    if c is None:
        return CorrectionState(stamp, 'active', 0, 0, 0.0, {})
    s = c.summary()
    cells = {k: (n, round(v, 9)) for k, (n, v, _, _) in file_cells(c, JOINT).items()}
    return CorrectionState(stamp, 'active', s['samples'], s['cells_with_data'], s['max_abs_correction_nm'], cells)


def _report(first, resumed, saved, **kw):
    n = saved.summary()['samples'] if saved is not None else 0
    more = _state(3, _correction(n + 10)) if saved is not None else _state(3, None)
    args = {'second': [resumed, more], 'joint': JOINT, 'path': Path('c.yaml'), 'periodic_samples': 5,
            'stop_code': 0, 'shutdown_samples': n, 'file_error': None, 'resumed_stop_code': 0, 'unsaved_at_stop': 10,
            'file_changed_at_stop': True, 'resumed_shutdown_samples': n + 10, 'resumed_file_error': None} | kw
    return learning_report(first=first, resumed=resumed, saved=saved, **args)


def test_the_report_passes_only_when_the_correction_changed_was_saved_and_resumed():
    learned = _correction(40)
    ok = _report([_state(0, None), _state(1, learned)], _state(2, learned), learned)
    assert ok['ok'] and ok['failure'] is None and ok['restart_resumed'] and ok['samples_last'] == 40
    assert ok['restart_max_value_difference_nm'] < 1e-8
    cases = {
        'published no correction message': _report([], _state(2, learned), learned),
        'did not change (0 -> 0 samples': _report([_state(0, None), _state(1, None)], _state(2, learned), learned),
        'no periodic save': _report([_state(0, None), _state(1, learned)], _state(2, learned), learned,
                                    periodic_samples=0),
        'exited with code 1': _report([_state(0, None), _state(1, learned)], _state(2, learned), learned,
                                      stop_code=1),
        'does not hold what was learned (no file)': _report([_state(0, None), _state(1, learned)],
                                                            _state(2, None), None, file_error='no file'),
        'the restarted friction_feedforward learned nothing in its run (40 samples)': _report(
            [_state(0, None), _state(1, learned)], _state(2, learned), learned, second=[_state(2, learned)]),
        'the restarted friction_feedforward exited with code 1': _report(
            [_state(0, None), _state(1, learned)], _state(2, learned), learned, resumed_stop_code=1),
        "after the restarted node's stop the correction file c.yaml does not hold what it learned (40 samples": _report(
            [_state(0, None), _state(1, learned)], _state(2, learned), learned, resumed_shutdown_samples=40),
        '10 samples learned after the restart but no save at shutdown': _report(
            [_state(0, None), _state(1, learned)], _state(2, learned), learned, file_changed_at_stop=False),
        # a restart that starts empty (the file not loaded) or with other values does not resume
        'did not resume the file: first message 0 samples': _report([_state(0, None), _state(1, learned)],
                                                                    _state(2, None), learned),
    }
    for reason, report in cases.items():
        assert not report['ok'] and reason in report['failure'], (reason, report['failure'])
    moved = _state(2, learned)
    key = next(iter(moved.cells))
    moved.cells[key] = (moved.cells[key][0], moved.cells[key][1] + 1e-3)   # beyond the learned value: not resumed
    bad = _report([_state(0, None), _state(1, learned)], moved, learned)
    assert not bad['restart_resumed'] and 'did not resume' in bad['failure']


def test_a_correction_message_is_read_per_joint():
    def st(name, **values):
        return SimpleNamespace(name=name, values=[SimpleNamespace(key=k, value=str(v)) for k, v in values.items()])
    msg = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=5, nanosec=500_000_000)), status=[
        st('gimbal_friction/correction/elevation', state='active', samples=12, cells_with_data=1,
           max_abs_correction_nm='0.00123'),
        st('gimbal_friction/correction/elevation/cw/-40', samples=12, value_nm='-0.00123'),
        st('gimbal_friction/correction/azimuth', state='active', samples=0, cells_with_data=0,
           max_abs_correction_nm='0')])
    s = correction_state(msg, 'elevation')
    assert s == CorrectionState(5.5, 'active', 12, 1, 0.00123, {('cw', '-40'): (12, -0.00123)})
    assert correction_state(msg, 'pitch') is None


@pytest.mark.slow
def test_the_command_fails_with_one_line_when_live_learning_did_nothing(monkeypatch, capsys):
    from gimbal_friction.runs import loop_live
    report = {'failure': 'the correction did not change (0 -> 0 samples, 1 states)'}
    monkeypatch.setattr(loop_live, 'live_study', lambda *a, **k: {'profile': 'tracking', 'learning': report,
                                                                   'records': []})
    code = main(['loop-study', '--short', '--temperatures', '-40', '--profiles', 'tracking', '--cases', 'none',
                 '--live', '--live-cases', 'learning', '--format', 'json'])
    captured = capsys.readouterr()
    assert code == 1
    assert json.loads(captured.out)['live']['learning'] == report   # the report is still printed
    last = captured.err.strip().splitlines()[-1]
    assert last == ('gimbal-friction loop-study: error: live learning: the correction did not change (0 -> 0 '
                    'samples, 1 states)')
