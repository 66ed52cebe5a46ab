"""The residual logger's /diagnostics without a node (gimbal_friction.recording.log_report)."""

from __future__ import annotations

from pathlib import Path

from gimbal_friction.recording.log_report import LoggerReport
from gimbal_friction.recording.residual_log import ResidualLogStats
from gimbal_friction.streams.diagnostics import ERROR, OK, WARN

COUNTS = {'residuals_logged': 5, 'paired_with_feedforward': 4, 'no_feedforward': 1, 'waiting_for_feedforward': 2,
          'dropped': 0}


def test_logging_then_refusals_warn_for_one_report_and_a_write_error_is_an_error(tmp_path: Path):
    report = LoggerReport()
    stats = ResidualLogStats(messages=10, flushed_messages=8, bytes=1234, current_file=tmp_path / 'residuals_0.mcap',
                             files=(tmp_path / 'residuals_0.mcap',))
    common = {'folder': tmp_path, 'stats': stats, 'counts': COUNTS, 'temperature_reliable': False}
    (main,) = report.statuses(active=True, error=None, refused={}, **common)
    assert (main.name, main.level, main.message, main.hardware_id) == (
        'gimbal_friction/residual_logger', OK, 'logging', 'residual_logger')
    values = dict(main.values)
    assert values['folder'] == str(tmp_path) and values['messages_logged'] == '10' and values['files'] == '1'
    assert values['waiting_for_feedforward'] == '2' and values['temperature_qos'] == 'best_effort'
    main, joint = report.statuses(active=True, error=None, refused={'undecodable feedforward': 2},
                                  lost={'/joint_states': 3}, rms={('elevation', 20.0): (4, 0.001)}, **common)
    assert main.level == WARN
    assert main.message == 'inputs refused: undecodable feedforward 2x; messages lost on the way: /joint_states 3'
    assert dict(main.values)['refused: undecodable feedforward'] == '2'
    assert joint.name == 'gimbal_friction/residual_logger/elevation' and dict(joint.values) == {
        'rms_nm_at_+20C': '0.001', 'samples_at_+20C': '4'}
    (main,) = report.statuses(active=True, error=None, refused={'undecodable feedforward': 2}, **common)
    assert main.level == OK   # nothing new
    (main,) = report.statuses(active=False, error='disk full', refused={}, folder=None, stats=None, counts={},
                              temperature_reliable=True)
    assert main.level == ERROR and main.message == 'not logging: disk full'
    assert dict(main.values)['folder'] == 'none' and dict(main.values)['current_file'] == 'none'
    (main,) = report.statuses(active=True, error=None, refused={}, errors={'callback error: KeyError: x': 1}, **common)
    assert main.level == ERROR and main.message == 'a callback failed (see values); logging'
    # the next report without a new failure is back to OK, the count still in its values
    (main,) = report.statuses(active=True, error=None, refused={}, errors={'callback error: KeyError: x': 1}, **common)
    assert main.level == OK and dict(main.values)['callback error: KeyError: x'] == '1'
