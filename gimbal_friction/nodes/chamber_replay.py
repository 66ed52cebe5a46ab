"""``chamber_replay``: plays a recorded chamber-test bag into the ROS graph with its recorded timing.

For machines without ``ros2 bag play``. Reads any bag with the contract's topics (rosbag2 MCAP or sqlite3, or a
bare .mcap; whatever wrote it) and publishes every message, in log-time order, as recorded (raw CDR) on the
contract topic names (remappable with ``--ros-args -r``), pacing by the log-time differences divided by ``rate``.

Parameters: ``bag`` (path, required), ``rate`` (playback rate factor, default 1.0), ``loop`` (bool),
``start_offset_s`` (skip the first seconds of the bag), ``topic_map`` (list of ``contract_topic=bag_topic``),
``wait_for_subscribers`` (wait until ``/joint_states`` has this many subscribers before playing, default 0) and
``wait_timeout_s``. Exits 0 at the end of the bag (unless looping), 1 with a one-line reason on a bad bag.
"""

from __future__ import annotations

import importlib
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile

from gimbal_friction.core.errors import ConfigError, GimbalFrictionError
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import open_chamber_bag


def message_class(msgtype: str) -> Any:
    """rclpy message class of ``pkg/msg/Type``."""
    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


def parse_topic_map(items: Sequence[str]) -> dict[str, str]:
    """``['/joint_states=/gimbal/joint_states']`` -> ``{'/joint_states': '/gimbal/joint_states'}``."""
    out = {}
    for item in items:
        if '=' not in item:
            raise ConfigError('topic_map', "entries must read 'contract_topic=bag_topic'", item)
        key, value = (x.strip() for x in item.split('=', 1))
        if key not in topics.CHAMBER_TOPICS:
            raise ConfigError('topic_map', f'{key} is not a chamber-test topic '
                              f'({", ".join(topics.CHAMBER_TOPICS)})', item)
        out[key] = value
    return out


class ChamberReplay(Node):
    """Publishes a bag's messages with recorded timing."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('chamber_replay', **kwargs)
        d = self.declare_parameter
        d('bag', '', ParameterDescriptor(description='chamber-test bag: rosbag2 folder or .mcap file'))
        d('rate', 1.0, ParameterDescriptor(description='playback rate factor [-] (2 = twice as fast)'))
        d('loop', False, ParameterDescriptor(description='start again at the end of the bag'))
        d('start_offset_s', 0.0, ParameterDescriptor(description='skip this much of the bag [s]'))
        d('topic_map', [''], ParameterDescriptor(description="'contract_topic=bag_topic' remaps of bag topics"))
        d('wait_for_subscribers', 0, ParameterDescriptor(description='wait for this many subscribers on '
                                                         '/joint_states before playing [-]'))
        d('wait_timeout_s', 30.0, ParameterDescriptor(description='give up waiting for subscribers after [s]'))
        get = self.get_parameter
        self.bag_path = str(get('bag').value)
        self.rate = float(get('rate').value)
        self.loop = bool(get('loop').value)
        self.start_offset_s = float(get('start_offset_s').value)
        self.wait_for = int(get('wait_for_subscribers').value)
        self.wait_timeout_s = float(get('wait_timeout_s').value)
        if not self.bag_path:
            raise ConfigError('bag', 'is required (--ros-args -p bag:=/path/to/bag)')
        if not (math.isfinite(self.rate) and self.rate > 0.0):
            raise ConfigError('rate', 'must be > 0', self.rate)
        if not (math.isfinite(self.start_offset_s) and self.start_offset_s >= 0.0):
            raise ConfigError('start_offset_s', 'must be >= 0 [s]', self.start_offset_s)
        topic_map = parse_topic_map([x for x in get('topic_map').value if x])
        self.bag = open_chamber_bag(self.bag_path, topic_map or None)
        self.pubs = {}
        for topic, info in self.bag.topics.items():
            self.pubs[topic] = self.create_publisher(message_class(info.msgtype), topic, QoSProfile(depth=100))
        self.published = 0

    def wait_for_subscribers(self, executor: Any) -> bool:
        if self.wait_for <= 0:
            return True
        deadline = time.monotonic() + self.wait_timeout_s
        pub = self.pubs[topics.JOINT_STATES]
        while time.monotonic() < deadline:
            if pub.get_subscription_count() >= self.wait_for:
                return True
            executor.spin_once(timeout_sec=0.05)
        return False

    def play_once(self) -> None:
        start_ns = self.bag.start_ns + int(self.start_offset_s * 1e9)
        t0 = time.monotonic()
        for raw in self.bag.iter_raw():
            if raw.log_time_ns < start_ns:
                continue
            target = t0 + (raw.log_time_ns - start_ns) * 1e-9 / self.rate
            delay = target - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)
            self.pubs[raw.topic].publish(raw.data)
            self.published += 1
            if not rclpy.ok():
                return


def main(args: Sequence[str] | None = None) -> None:
    """``chamber_replay --ros-args -p bag:=bags/chamber_sample -p rate:=10.0``."""
    argv = list(sys.argv if args is None else args)
    try:
        rclpy.init(args=argv)
    except Exception as err:
        print(f'chamber_replay: error: cannot start: {str(err).splitlines()[0]}', file=sys.stderr)
        sys.exit(1)
    node = None
    code = 0
    try:
        node = ChamberReplay()
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if not node.wait_for_subscribers(executor):
            raise ConfigError('wait_for_subscribers', f'fewer than {node.wait_for} subscribers on /joint_states '
                              f'after {node.wait_timeout_s:g} s')
        info = ', '.join(f'{t} ({i.count})' for t, i in node.bag.topics.items())
        node.get_logger().info(f'playing {node.bag_path} at {node.rate:g}x: {info}')
        t_start = time.monotonic()
        while rclpy.ok():
            node.play_once()
            if not node.loop:
                break
        node.get_logger().info(f'played {node.published} messages in {time.monotonic() - t_start:.1f} s')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except GimbalFrictionError as err:
        print(f'chamber_replay: error: {err}', file=sys.stderr)
        code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(code)


if __name__ == '__main__':
    main()
