"""Bare rclpy relay: the baseline of ``bench/feedforward_latency.py``.

Subscribes ``/joint_states`` (sensor_msgs/JointState) and republishes the received message unchanged (same
header stamp) on ``/gimbal/friction/feedforward``. Everything else is set up exactly like
``friction_feedforward`` (``gimbal_friction.nodes._common.run_node``): reliable keep-last depth-10 QoS on both
topics, an ``EventsExecutor`` driven by a ``spin_once(timeout_sec=0.25)`` loop, clean exit on SIGINT/SIGTERM.
The difference between the two nodes' latency is therefore the feedforward node's own work.

Run: ``.venv/bin/python bench/relay_node.py [--ros-args ...]``
"""

from __future__ import annotations

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState

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


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=list(sys.argv if args is None else args))
    node = None
    try:
        node = Relay()
        from rclpy.experimental import EventsExecutor
        executor = EventsExecutor()
        executor.add_node(node)
        # Same loop as run_node: EventsExecutor.spin() busy-loops with these wheels.
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.25)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
