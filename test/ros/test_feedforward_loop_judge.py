"""friction_feedforward's loop-error input (``/gimbal/loop_error``): subscribed, and /diagnostics and the correction
topic say whether the loop judges the learned correction (``learning_judge``: auto follows a publisher)."""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from test_feedforward_learning import CORRECTION, learning_status, set_param, wait_status

from gimbal_friction.nodes.feedforward import LOOP_ERROR, NOT_JUDGED
from gimbal_friction.streams.delivery import received_key

pytestmark = pytest.mark.ros


def _joint_status(probe) -> dict[str, str] | None:
    msgs = probe.received[CORRECTION]
    for st in (msgs[-1].status if msgs else ()):
        if st.name == 'gimbal_friction/correction/elevation':
            return {kv.key: kv.value for kv in st.values}
    return None


def test_the_node_subscribes_the_loop_error_and_reports_the_judge(spawn, probe):
    probe.subscribe(DiagnosticArray, '/diagnostics')
    probe.subscribe(DiagnosticArray, CORRECTION)
    spawn('friction_feedforward', '--ros-args', '--params-file', 'config/gimbal_friction.yaml',
          '-p', 'diagnostics_period_s:=0.2', '-p', 'correction_publish_period_s:=0.2',
          '-p', 'learning_step_period_s:=0.2')
    st = wait_status(probe, lambda s: True, 'the learning status')
    assert st['learning_judge'] == 'auto' and st['loop_judge'] == NOT_JUDGED   # no loop-error publisher yet
    assert NOT_JUDGED in st['message']
    probe.spin_until(lambda: _joint_status(probe) is not None, what='the correction topic')
    assert _joint_status(probe)['loop_judge'] == NOT_JUDGED
    pub = probe.publisher(JointState, LOOP_ERROR)
    probe.wait_matched(LOOP_ERROR)                       # the node subscribes /gimbal/loop_error
    st = wait_status(probe, lambda s: s['loop_judge'].startswith('judged by the loop'), 'judged by the loop')
    for k in range(5):
        msg = JointState(name=['elevation'], position=[1e-4], velocity=[1e-3])
        msg.header.stamp.sec = 100 + k
        pub.publish(msg)
    wait_status(probe, lambda s: int(s[received_key(LOOP_ERROR)]) >= 1, 'the loop error counted')
    n = len(probe.received[CORRECTION])
    probe.spin_until(lambda: len(probe.received[CORRECTION]) > n + 1, what='a new correction message')
    assert _joint_status(probe)['loop_judge'].startswith('judged by the loop')
    set_param(probe, 'learning_judge', 'off')            # the residual guard alone, publisher or not
    st = wait_status(probe, lambda s: s['loop_judge'] == NOT_JUDGED, 'not judged with learning_judge off')
    assert st['learning_judge'] == 'off'
    assert learning_status(probe) is not None
