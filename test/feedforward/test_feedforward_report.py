"""The feedforward's per-joint /diagnostics without a node (gimbal_friction.feedforward.report)."""

from __future__ import annotations

from gimbal_friction.feedforward.report import FeedforwardReport
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.diagnostics import ERROR, OK, WARN


def test_statuses_follow_the_temperature_and_what_is_new_since_the_last_report():
    ff = Feedforward({'elevation': AxisParams(), 'azimuth': AxisParams()}, FeedforwardSettings())
    report = FeedforwardReport()
    el, az = report.joint_statuses(ff, 1.0)
    assert [el.name, az.name] == ['gimbal_friction/feedforward/elevation', 'gimbal_friction/feedforward/azimuth']
    assert el.level == WARN and el.message == 'no fresh temperature: fallback_temperature'   # none yet
    assert dict(el.values)['temperature_source'] == 'fallback_temperature'
    assert ff.update_temperature(-20.0, 1.0) is None
    assert ff.update_temperature(float('nan'), 1.1) is not None     # a rejected temperature
    el, _ = report.joint_statuses(ff, 1.2, lost={'/joint_states': 4}, rate_limited=3)
    assert el.level == WARN and el.message.startswith('temperatures rejected: ')
    assert el.message.endswith('messages lost on the way: /joint_states 4')
    values = dict(el.values)
    assert values['temperature_c'] == '-20' and values['temperature_source'] == 'measured'
    assert values['rate_limited'] == '3' and any(k.startswith('rejected_temperature: ') for k in values)
    el, _ = report.joint_statuses(ff, 1.3)
    assert el.level == OK and el.message == 'ok'                    # nothing new: OK, the totals stay
    el, _ = report.joint_statuses(ff, 1.3, errors={'callback error: KeyError: x': 1},
                                  input_problems=['/joint_states: no publisher'])
    assert el.level == ERROR and el.message == '/joint_states: no publisher; a callback failed (see values)'
    zero = Feedforward({'elevation': AxisParams()}, FeedforwardSettings(stale_policy='zero'))
    (el,) = FeedforwardReport().joint_statuses(zero, 0.0)
    assert el.level == ERROR and el.message == 'no fresh temperature: zero'
