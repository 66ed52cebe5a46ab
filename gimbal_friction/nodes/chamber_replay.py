"""``chamber_replay``: plays a recorded chamber-test bag into the ROS graph with its recorded timing.

For machines without ``ros2 bag play``. Reads any bag with the contract's topics (rosbag2 MCAP or sqlite3 folder,
or a bare .mcap / .db3; whatever wrote it) and publishes its messages, in log-time order, as recorded (raw CDR) on
the contract topic names (remappable with ``--ros-args -r``), pacing by the log-time differences divided by
``rate``.

By default only the three input topics (``/gimbal/temperature``, ``/joint_states``, ``/gimbal/motor_current``) are
published: a bag recorded with ``ros2 bag record --all`` also holds ``/rosout``, ``/diagnostics``, ``/tf``, service
events, ..., which must not be replayed into a live graph. ``topics`` adds others by name (or ``'*'``: every topic
whose message type is installed), ``exclude_topics`` removes some. Joint names are not rewritten: the messages are
republished byte for byte (``gimbal-friction replay --joint`` maps joint names offline).

Parameters: ``bag`` (path, required), ``rate`` (playback rate factor, default 1.0), ``loop`` (bool),
``start_offset_s`` (skip the first seconds of the bag), ``topic_map`` (list of ``contract_topic=bag_topic``),
``topics`` (list: topics to publish besides the inputs, ``'*'`` for all), ``exclude_topics`` (list),
``wait_for_subscribers`` (wait until ``/joint_states`` has this many subscribers before playing, default 0) and
``wait_timeout_s``. Exits 0 at the end of the bag (unless looping), 1 with a one-line reason on a bad bag or
parameter (a bag cut short names ``gimbal-friction recover``).

What it sent, on ``/diagnostics`` (status ``gimbal_friction/chamber_replay``, every second while playing and once
more when the bag has been played, ``state: finished``): per topic ``published: <topic>`` (messages sent) and
``publisher_gid: <topic>`` (the DDS gid of its publisher, hex). A subscriber compares them with what arrived:
``residual_logger`` counts what it did not receive of them as lost (:mod:`gimbal_friction.streams.delivery`).
Before exiting it waits (at most ``ACK_TIMEOUT_S``) for the subscribers of ``/diagnostics`` to acknowledge that
last status.
"""

from __future__ import annotations

import importlib
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError
from gimbal_friction.config.loader import CHAMBER_REPLAY_SPECS
from gimbal_friction.config.parameter_rules import parameter_rule
from gimbal_friction.nodes._common import (
    OK,
    diagnostic_array,
    init_rclpy,
    name_undeclared_parameters,
    print_help_if_asked,
    startup_overrides,
    status,
    typed_descriptor,
)
from gimbal_friction.nodes._qos import create_publisher
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import open_chamber_bag
from gimbal_friction.streams.delivery import PUBLISHER_STATUS, STATE_FINISHED, STATE_PLAYING, Sent, publisher_values

#: ``topics`` entry meaning every topic of the bag whose message type is installed
ALL_TOPICS = '*'
_SPECS = {spec['name']: spec for spec in CHAMBER_REPLAY_SPECS}
_KINDS = {float: 'number', int: 'integer', bool: 'boolean (true or false)', str: 'string', list: 'list of strings'}
#: what was sent is said on /diagnostics this often while playing [s]
STATUS_PERIOD_S = 1.0
#: at the end, wait at most this long for the subscribers of /diagnostics to acknowledge the last status [s]
ACK_TIMEOUT_S = 5.0


def message_class(msgtype: str) -> Any:
    """rclpy message class of ``pkg/msg/Type`` (None if the package is not installed)."""
    pkg, _, name = msgtype.partition('/msg/')
    if not pkg or not name:
        return None
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name, None)
    except ImportError:
        return None


def select_topics(available: dict[str, str], include: Sequence[str], exclude: Sequence[str]) -> tuple[
        list[str], list[str]]:
    """The topics to publish: the chamber inputs, plus ``include`` (``'*'``: all), minus ``exclude``.

    Args:
        available: every topic of the bag (contract name) -> message type.
        include: extra topic names, or ``'*'``.
        exclude: topic names not to publish.

    Returns:
        (topics to publish, topics of ``'*'`` left out because their message type is not installed).

    Raises:
        ConfigError: a named topic is not in the bag, or its message type is not installed.
    """
    for name in [*include, *exclude]:
        if name != ALL_TOPICS and name not in available:
            raise ConfigError('topics' if name in include else 'exclude_topics',
                              f'no topic {name} in the bag (topics: {", ".join(sorted(available))})', name)
    chosen = list(topics.CHAMBER_TOPICS)
    skipped = []
    if ALL_TOPICS in include:
        for name, msgtype in available.items():
            if name in chosen:
                continue
            if message_class(msgtype) is None:
                skipped.append(name)
            else:
                chosen.append(name)
    for name in include:
        if name != ALL_TOPICS and name not in chosen:
            if message_class(available[name]) is None:
                raise ConfigError('topics', f'message type {available[name] or "(several)"} of {name} is not '
                                  'installed', name)
            chosen.append(name)
    return [t for t in chosen if t not in exclude], skipped


class ChamberReplay(Node):
    """Publishes a bag's messages with recorded timing."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('chamber_replay', **kwargs)
        name_undeclared_parameters(self)
        self.bag_path = str(self._param('bag'))
        self.rate = float(self._param('rate'))
        self.loop = bool(self._param('loop'))
        self.start_offset_s = float(self._param('start_offset_s'))
        topic_map = self._param('topic_map')
        include = self._param('topics')
        exclude = self._param('exclude_topics')
        self.wait_for = int(self._param('wait_for_subscribers'))
        self.wait_timeout_s = float(self._param('wait_timeout_s'))
        if not self.bag_path:
            raise ConfigError('bag', 'is required (--ros-args -p bag:=/path/to/bag)')
        if not (math.isfinite(self.rate) and self.rate > 0.0):
            raise ConfigError('rate', 'must be > 0', self.rate)
        if not (math.isfinite(self.start_offset_s) and self.start_offset_s >= 0.0):
            raise ConfigError('start_offset_s', 'must be >= 0 [s]', self.start_offset_s)
        if self.wait_for < 0:
            raise ConfigError('wait_for_subscribers', 'must be >= 0 subscribers (0 = do not wait)', self.wait_for)
        if not (math.isfinite(self.wait_timeout_s) and self.wait_timeout_s > 0.0):
            raise ConfigError('wait_timeout_s', 'must be > 0 [s]', self.wait_timeout_s)
        remap = topics.parse_topic_map([x for x in topic_map if x], 'topic_map')
        self.bag = open_chamber_bag(self.bag_path, remap or None)
        duration_s = self.bag.duration_ns * 1e-9
        if self.start_offset_s > duration_s:
            raise ConfigError('start_offset_s', f'is beyond the end of the bag: must be from 0 to {duration_s:.3f} s '
                              f'(the bag lasts {duration_s:.3f} s)', self.start_offset_s)
        available = {name: info.msgtype for name, info in self.bag.topics.items()}
        self.topics, self.skipped = select_topics(available, [x for x in include if x], [x for x in exclude if x])
        self.pubs = {}
        for topic in self.topics:
            self.pubs[topic] = create_publisher(self, message_class(available[topic]), topic, QoSProfile(depth=100))
        self.published = 0
        #: messages sent per topic [-]
        self.sent = dict.fromkeys(self.topics, 0)
        self.gids = {topic: self._own_gid(topic) for topic in self.topics}
        self.pub_diag = create_publisher(self, DiagnosticArray, topics.DIAGNOSTICS, QoSProfile(depth=10))
        self._last_status = -math.inf

    def _own_gid(self, topic: str) -> bytes | None:
        """The DDS gid of this node's publisher of ``topic`` (None if the graph shows none, or several publishers
        of a node of this name and namespace: then which one is ours cannot be told)."""
        mine = [bytes(info.endpoint_gid) for info in self.get_publishers_info_by_topic(topic)
                if info.node_name == self.get_name() and info.node_namespace == self.get_namespace()]
        return mine[0] if len(mine) == 1 else None

    def publish_status(self, state: str) -> None:
        """``/diagnostics``: what was sent so far, per topic, and by which publisher (``state``: playing,
        finished)."""
        values = publisher_values(state, [Sent(t, self.gids[t], n) for t, n in self.sent.items()])
        values.update({'bag': self.bag_path, 'rate': self.rate, 'loop': self.loop})
        self.pub_diag.publish(diagnostic_array(self, [status(PUBLISHER_STATUS, OK, f'{state}: {self.published} '
                                                             'messages sent', 'chamber_replay', values)]))
        self._last_status = time.monotonic()

    def finish(self) -> None:
        """Say what was sent in all (``state: finished``) and wait for the subscribers of ``/diagnostics`` to
        acknowledge it (at most :data:`ACK_TIMEOUT_S`)."""
        self.publish_status(STATE_FINISHED)
        self.pub_diag.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))

    def _param(self, name: str) -> Any:
        """Declare a parameter of :data:`~gimbal_friction.config.CHAMBER_REPLAY_SPECS`; a value of the wrong type
        is a ConfigError (one line), not an rclpy traceback."""
        spec = _SPECS[name]
        default = spec['default']
        rule = parameter_rule('chamber_replay', name)
        try:
            return self.declare_parameter(name, default, typed_descriptor(
                name, spec['unit'], spec['description'], default, rule)).value
        except Exception as err:  # rclpy's InvalidParameterTypeException / InvalidParameterValueException
            if type(err).__module__.startswith('rclpy') and 'Parameter' in type(err).__name__:
                if rule is not None and 'Type' not in type(err).__name__:
                    # out of the descriptor's range: declared without it, the node's own checks word the refusal
                    return self.declare_parameter(name, default, typed_descriptor(
                        name, spec['unit'], spec['description'], default)).value
                kind = _KINDS.get(type(default), type(default).__name__)
                raise ConfigError(name, f'must be a {kind} ({str(err).splitlines()[0]})') from None
            raise

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
        for raw in self.bag.iter_raw(self.topics):
            if raw.log_time_ns < start_ns:
                continue
            target = t0 + (raw.log_time_ns - start_ns) * 1e-9 / self.rate
            delay = target - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)
            if not rclpy.ok():   # SIGINT while sleeping: stop cleanly
                return
            try:
                self.pubs[raw.topic].publish(raw.data)
                self.published += 1
                self.sent[raw.topic] += 1
                if time.monotonic() - self._last_status >= STATUS_PERIOD_S:
                    self.publish_status(STATE_PLAYING)
            except Exception:   # (rclpy's RCLError) the context went down between the check and the publish
                if rclpy.ok():
                    raise
                return


def main(args: Sequence[str] | None = None) -> None:
    """``chamber_replay --ros-args -p bag:=bags/chamber_sample -p rate:=10.0``."""
    argv = list(sys.argv if args is None else args)
    if print_help_if_asked('chamber_replay', argv, __doc__):
        sys.exit(0)
    try:
        # the suite's start-up check: a misspelt name is refused, a -p value rcl would drop is applied
        overrides, _ = startup_overrides(argv, 'chamber_replay')
    except GimbalFrictionError as err:
        print(f'chamber_replay: error: {err}', file=sys.stderr)
        sys.exit(1)
    if not init_rclpy('chamber_replay', argv):  # invalid --ros-args: one line said why
        sys.exit(1)
    node = None
    code = 0
    try:
        node = ChamberReplay(parameter_overrides=overrides) if overrides else ChamberReplay()
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if not node.wait_for_subscribers(executor):
            raise ConfigError('wait_for_subscribers', f'fewer than {node.wait_for} subscribers on /joint_states '
                              f'after {node.wait_timeout_s:g} s')
        info = ', '.join(f'{t} ({node.bag.topics[t].messages})' for t in node.topics)
        node.get_logger().info(f'playing {node.bag_path} at {node.rate:g}x: {info}')
        ignored = sorted(set(node.bag.topics) - set(node.topics))
        if ignored:
            node.get_logger().info(f'not published: {", ".join(ignored)} (add them with -p topics:=[...])')
        t_start = time.monotonic()
        while rclpy.ok():
            node.play_once()
            if not node.loop:
                break
        if rclpy.ok():
            node.finish()
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
