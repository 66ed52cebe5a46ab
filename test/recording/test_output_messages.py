"""The feedforward's output messages as bytes without rclpy (gimbal_friction.recording.output_messages): the
templates give the very bytes of the suite's CDR encoder for any stamp, frame_id and names, also past the layouts
kept. (test/ros/test_feedforward_node.py checks that rclpy deserializes them to the messages.)"""

from __future__ import annotations

from types import SimpleNamespace

from gimbal_friction.recording.cdr import float64_multi_array_cdr, joint_state_cdr
from gimbal_friction.recording.output_messages import OutputBytes

S = 1_000_000_000


def header(sec: int, nanosec: int, frame_id: str = '') -> SimpleNamespace:
    return SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec), frame_id=frame_id)


def test_templates_give_the_encoders_bytes():
    out = OutputBytes(2)
    out.MAX_LAYOUTS = 2
    cases = [(['elevation'], [1.5e-3], 7, 250, ''), (['elevation', 'azimuth'], [-2e-3, 0.0], 3, 999_999_999, 'b'),
             (['élévation'], [0.02], 2**31 - 1, 0, 'gimbal/ü'), (['elevation'], [-1e-3], 0, 1, '')]
    for names, torques, sec, nanosec, frame_id in cases * 2:
        want = joint_state_cdr(sec * S + nanosec, names, effort=torques, frame_id=frame_id)
        assert out.feedforward(header(sec, nanosec, frame_id), names, torques) == want, (names, frame_id)
    assert out.commands([1e-3, -2.5e-3]) == float64_multi_array_cdr([1e-3, -2.5e-3], 'joints')
