"""Bare rclpy relay: the baseline of ``bench/feedforward_latency.py``.

Subscribes ``/joint_states`` (sensor_msgs/JointState) and republishes the received message unchanged (same
header stamp) on ``/gimbal/friction/feedforward``. Everything else is exactly what ``friction_feedforward`` uses:
reliable keep-last depth-10 QoS on both topics, and the node is run by the same
``gimbal_friction.nodes._common.run_node`` (EventsExecutor driven by a ``spin_once`` loop, the same signal
handling), so the relay follows any change made there. The difference between the two nodes' latency is
therefore the feedforward node's own work.

Run: ``.venv/bin/python bench/relay_node.py [--ros-args ...]``
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState

from gimbal_friction.nodes._common import run_node

JOINT_STATES = '/joint_states'
FEEDFORWARD = '/gimbal/friction/feedforward'


class Relay(Node):
    """``/joint_states`` -> ``/gimbal/friction/feedforward``, message passed through as is."""

    def __init__(self) -> None:
        super().__init__('friction_relay')
        qos = QoSProfile(depth=10)
        self.pub = self.create_publisher(JointState, FEEDFORWARD, qos)
        self.create_subscription(JointState, JOINT_STATES, self.on_joint_state, qos)

    def on_joint_state(self, msg: JointState) -> None:
        self.pub.publish(msg)


def main(args: Sequence[str] | None = None) -> int:
    return run_node('friction_relay', Relay, args)


if __name__ == '__main__':
    sys.exit(main())
