"""The estimator's /diagnostics without a node (gimbal_friction.estimation.report): the statuses from the logic,
WARN while a cause is new since the last report, ERROR for a callback that failed, back to OK after."""

from __future__ import annotations

import math

from gimbal_friction.estimation.estimator import EstimatorLogic, EstimatorSettings
from gimbal_friction.estimation.report import EstimatorReport
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.diagnostics import ERROR, OK, WARN

EL = 'elevation'
S = 1_000_000_000
DT = 20_000_000
V = 2 * math.pi / 180


def logic() -> EstimatorLogic:
    return EstimatorLogic({EL: AxisParams(torque_constant_nm_per_a=0.05, no_load_current_a=0.01)},
                          EstimatorSettings(min_dwell_s=0.0, temperature_wait_s=0.0))


def test_no_sample_yet_then_bad_inputs_warn_for_one_report():
    est, report = logic(), EstimatorReport()
    joint, rest = report.statuses(est)
    assert joint.name == f'gimbal_friction/estimator/{EL}' and joint.hardware_id == EL
    assert joint.level == WARN and joint.message == 'no sample accepted yet'
    values = dict(joint.values)
    assert values['accepted'] == '0' and values['last_method'] == 'none'
    assert values['torque_constant_nm_per_a'] == '0.05'
    assert rest.name == 'gimbal_friction/estimator' and rest.level == OK
    assert dict(rest.values)['temperature_c'] == 'none'
    est.on_joint_state(S, ['other'], [0.0], [0.0])          # a joint not configured: a bad input of no joint
    est.on_temperature(-20.0, stamp_ns=S)
    _, rest = report.statuses(est, lost={'/joint_states': 2})
    assert rest.level == WARN and 'bad inputs rejected' in rest.message and '/joint_states 2' in rest.message
    assert dict(rest.values)['temperature_c'] == '-20'
    _, rest = report.statuses(est)                          # nothing new: OK again, the counts stay
    assert rest.level == OK and rest.message == 'ok'
    assert any(k.startswith('rejected: ') for k, _ in rest.values)


def test_an_accepted_sample_and_a_failed_callback():
    est, report = logic(), EstimatorReport()
    est.on_temperature(-40.0, stamp_ns=S)
    for k in range(40):
        t = 2 * S + k * DT
        est.on_current(t, [EL], [0.06])
        est.on_joint_state(t, [EL], [0.1 + V * k * DT * 1e-9], [V])
    joint, rest = report.statuses(est, errors={'callback error: ValueError: x': 1},
                                  input_problems=['/gimbal/temperature: no publisher'])
    values = dict(joint.values)
    assert int(values['accepted']) > 0 and joint.level == OK and values['last_method'] == 'steady_state'
    assert rest.level == ERROR and 'a callback failed' in rest.message and 'no publisher' in rest.message
    _, rest = report.statuses(est, errors={'callback error: ValueError: x': 1})
    assert rest.level == OK   # the same count: nothing new
