"""Experiment (bench only, not the shipped node): ``friction_feedforward`` with a leaner joint-state callback.

Same node, parameters, QoS and executor loop (``run_node``) as ``friction_feedforward``; only the hot path of
``on_joint_state`` differs, to measure what the changes suggested by ``bench/profile_callback.py`` would buy:

- one output JointState allocated once and reused; the input header object is assigned as a whole (stamp and
  frame_id in one go) instead of a new message with two field copies;
- per joint, ``FeedforwardLogic.joint_torque`` is called directly: no ``FeedforwardOutput``/``JointTorque`` list, no
  index dict or ``command_vector`` dict when the message is the normal case (only configured joints, matching
  arrays); anything unusual goes through the original callback, so rejections and counters stay the same;
- the feedforward is published before any work for ``feedforward_commands`` (as now), whose message is also reused.

Run as the benchmark does: ``.venv/bin/python bench/lean_feedforward.py --ros-args --params-file
config/gimbal_friction.yaml`` (``feedforward_latency.py --nodes relay,feedforward,lean``).
"""

from __future__ import annotations

import sys
from typing import Sequence

from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.nodes._common import monotonic_s, run_node
from gimbal_friction.nodes.feedforward import FrictionFeedforward


class LeanFeedforward(FrictionFeedforward):
    """FrictionFeedforward with the allocation-light hot path described in the module docstring."""

    def __init__(self) -> None:
        super().__init__()
        self._ff_msg = JointState()
        self._cmd_msg = Float64MultiArray()

    def on_joint_state(self, msg: JointState) -> None:
        settings = self.settings
        logic = self.logic
        axes = logic.axes
        names = msg.name
        velocities = msg.velocity
        if (settings.max_rate_hz > 0.0 or settings.velocity_source != 'measured'
                or len(velocities) != len(names) or not all(n in axes for n in names)):
            super().on_joint_state(msg)   # unusual input or options: the original path (counts, rejections)
            return
        temperature, _ = logic.effective_temperature(monotonic_s())
        if len(names) == 1:
            present = names if names[0] in axes else []
            vel = [float(velocities[0])]
        else:
            index = {n: i for i, n in enumerate(names)}
            present = [n for n in axes if n in index]
            vel = [float(velocities[index[n]]) for n in present]
        if not present:
            super().on_joint_state(msg)
            return
        torques = []
        for n, v in zip(present, vel):
            j = logic.joint_torque(n, v, temperature)
            if not j.valid_velocity:
                logic._count(logic.counters.joint_state_rejected, 'non-finite velocity')
            torques.append(j.torque_nm)
        ff = self._ff_msg
        ff.header = msg.header
        ff.name = present
        ff.effort = torques
        self.pub_ff.publish(ff)
        logic.counters.published += 1
        by_name = dict(zip(present, torques))
        cmd = self._cmd_msg
        cmd.layout.dim = [MultiArrayDimension(label='joints', size=len(axes), stride=len(axes))]
        cmd.data = [by_name.get(n, 0.0) for n in axes]
        self.pub_cmd.publish(cmd)


def main(args: Sequence[str] | None = None) -> int:
    return run_node('lean_feedforward', LeanFeedforward, args)


if __name__ == '__main__':
    sys.exit(main())
