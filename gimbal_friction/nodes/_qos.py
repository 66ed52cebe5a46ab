"""QoS of the nodes' publishers and subscriptions: ``qos_overrides`` parameters, inputs that follow their publishers'
reliability, and the graph facts behind the input diagnostics.

One job in one module: every publisher and subscription of a node is made here, so that each takes the standard
``qos_overrides.<topic>.<publisher|subscription>.<history|depth|reliability>`` parameters (rclpy
:class:`~rclpy.qos_overriding_options.QoSOverridingOptions`, read-only, set from a parameter file or ``-p``), and
each input hears reliable and best-effort publishers alike:

- **a followed input** (the default of the nodes' inputs): its reliability parameter is ``best_available`` (declared
  here, with rclpy's name and form); the subscription is reliable while every publisher of the topic is reliable
  (a reliable publisher then resends what was lost: nothing is lost) and best-effort as soon as one is not (a
  reliable subscription would not hear it). The graph is read every :data:`QOS_CHECK_PERIOD_S`; the new
  subscription is made first and the old one dropped once the new one hears every publisher; a message both deliver
  is handled once (publisher sequence numbers, :meth:`~gimbal_friction.streams.delivery.InputCounter.count`).
  ``reliable`` or ``best_effort`` instead fixes it (rclpy's ``best_available`` resolves once, at creation: the
  nodes follow the publishers for as long as they run instead).
- **a fixed input** (the temperature: best-effort, ``qos_profile_sensor_data``, which hears every publisher): its
  three parameters are rclpy's own.

What each input receives is checked against the graph for ``/diagnostics``
(:class:`~gimbal_friction.streams.input_health.InputWatch` words it): a publisher of another type, a publisher whose
QoS cannot match (the middleware's reason, :func:`rclpy.qos.qos_check_compatible`), and for the inputs a node needs,
no publisher or nothing received for longer than the input's timeout.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.qos import QoSCompatibility, QoSPolicyKind, QoSProfile, ReliabilityPolicy, qos_check_compatible
from rclpy.qos_overriding_options import QoSOverridingOptions

from gimbal_friction.config.loader import check_qos_override
from gimbal_friction.nodes._common import InputCounter, subscribe
from gimbal_friction.streams.input_health import SILENCE_TIMEOUT_S, InputWatch, PublisherFacts

#: how often a followed input's reliability is matched to its publishers' [s]
QOS_CHECK_PERIOD_S = 0.2
#: a new subscription that has not matched every publisher after this long replaces the old one anyway [s]
SWITCH_TIMEOUT_S = 2.0
#: the reliability parameter's value that makes an input follow its publishers
FOLLOW = 'best_available'


def create_publisher(node: Node, msg_type: Any, topic: str, qos: QoSProfile | int, managed: bool = True) -> Any:
    """``node.create_publisher`` with the ``qos_overrides.<topic>.publisher.*`` parameters (history, depth,
    reliability); of a lifecycle node, unless not ``managed``, a ``LifecyclePublisher`` (publishes only while the
    node is active)."""
    profile = QoSProfile(depth=qos) if isinstance(qos, int) else copy.copy(qos)  # (rclpy overrides it in place)
    if isinstance(node, LifecycleNode) and managed:   # publishes only while the node is active
        return node.create_lifecycle_publisher(msg_type, topic, profile,
                                               qos_overriding_options=QoSOverridingOptions.with_default_policies())
    return node.create_publisher(msg_type, topic, profile,
                                 qos_overriding_options=QoSOverridingOptions.with_default_policies())


def type_name(msg_type: Any) -> str:
    """``sensor_msgs/msg/JointState`` of a message class, as the ROS graph names types."""
    package, kind = msg_type.__module__.split('.')[:2]
    return f'{package}/{kind}/{msg_type.__name__}'


def _node_name(info: Any) -> str:
    namespace = info.node_namespace.rstrip('/')
    return f'{namespace}/{info.node_name}'


def _reliability(profile: Any) -> str:
    return str(profile.reliability.name).lower()


class Input:
    """One input topic of a node: its subscription (followed or fixed) and its health.

    ``callback(msg)`` runs once per message (counted by ``counter``), whichever subscription delivers it. ``qos``
    is the profile of a reliable input (history, depth); ``follow`` makes its reliability follow the publishers
    (``start_reliable``: the reliability before the first look at the graph; None: from the graph now).
    """

    def __init__(self, node: Node, counter: InputCounter, msg_type: Any, topic: str,
                 callback: Callable[[Any], None], qos: QoSProfile, *, raw: bool = False, follow: bool = True,
                 required: bool = False, timeout_s: float = SILENCE_TIMEOUT_S,
                 start_reliable: bool | None = None) -> None:
        self.node = node
        self.counter_topic = topic
        self.topic = node.resolve_topic_name(topic)
        self.type_name = type_name(msg_type)
        self.watch = InputWatch(self.topic, self.type_name, required=required, timeout_s=timeout_s,
                                now_s=time.monotonic())
        self._counter, self._msg_type, self._callback, self._raw = counter, msg_type, callback, raw
        profile = copy.copy(qos)  # (rclpy applies the overrides to the profile in place)
        self.following = False
        if follow:
            name = f'qos_overrides.{self.topic}.subscription.reliability'
            value: Any = node.get_parameter(name).value if node.has_parameter(name) else node.declare_parameter(
                name, FOLLOW, ParameterDescriptor(
                description=f'reliability for subscription `{self.topic}`: {FOLLOW} = follow the publishers '
                '(reliable while every publisher is), reliable, best_effort', read_only=True)).value
            check_qos_override(name, value)
            self.following = value == FOLLOW
            if self.following:
                reliable = self._publishers_reliable() if start_reliable is None else start_reliable
                profile.reliability = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
            else:
                profile.reliability = ReliabilityPolicy[str(value).upper()]
            options = QoSOverridingOptions([QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH])
        else:
            options = QoSOverridingOptions.with_default_policies()
        self.subscription = self._create(profile, options)
        #: the profile after the overrides (the reliability follows, the rest stays)
        self.profile: QoSProfile = copy.copy(self.subscription.qos_profile)
        self._next: Any = None
        self._next_since = 0.0

    def _create(self, profile: QoSProfile, options: QoSOverridingOptions | None) -> Any:
        return subscribe(self.node, self._counter, self._msg_type, self.counter_topic, self._callback, profile,
                         raw=self._raw, qos_overriding_options=options)

    @property
    def reliable(self) -> bool:
        """The subscription delivering now is reliable."""
        return bool(self.profile.reliability == ReliabilityPolicy.RELIABLE)

    def _infos(self) -> list[Any]:
        return list(self.node.get_publishers_info_by_topic(self.topic))

    def _publishers_reliable(self, infos: list[Any] | None = None) -> bool:
        infos = self._infos() if infos is None else infos
        return all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos
                   if i.topic_type == self.type_name)

    def _profile(self, reliable: bool) -> QoSProfile:
        profile = copy.copy(self.profile)
        profile.reliability = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
        return profile

    def follow(self) -> None:
        """Match a followed input's reliability to its publishers' (see the module)."""
        if not self.following:
            return
        infos = [i for i in self._infos() if i.topic_type == self.type_name]
        if self._next is not None:
            if (self._next.get_publisher_count() >= len(infos)
                    or time.monotonic() - self._next_since > SWITCH_TIMEOUT_S):
                self.node.destroy_subscription(self.subscription)
                self.subscription, self._next = self._next, None
                self.profile = self._profile(not self.reliable)
            return
        if not infos:
            return
        reliable = self._publishers_reliable(infos)
        if reliable != self.reliable:
            self._next = self._create(self._profile(reliable), None)   # (the overrides are in self.profile)
            self._next_since = time.monotonic()

    def qos_text(self) -> str:
        """The subscription's reliability for ``/diagnostics`` (``reliable``, ``best_effort``), and whether it
        follows the publishers."""
        return f'{_reliability(self.profile)} ({"follows the publishers" if self.following else "fixed"})'

    def problems(self, received: int) -> list[str]:
        """What keeps this input from delivering (words of :class:`InputWatch`), from the graph now."""
        infos = self._infos()
        # a followed input is judged with the reliability it is following to (it switches within a check period)
        profile = self._profile(self._publishers_reliable(infos)) if self.following else self.profile
        facts = []
        for i in infos:
            why = ''
            if i.topic_type == self.type_name:
                verdict, reason = qos_check_compatible(i.qos_profile, profile)
                if verdict == QoSCompatibility.ERROR:
                    why = reason.removeprefix('ERROR:').strip().rstrip(';') or 'incompatible QoS'
            facts.append(PublisherFacts(_node_name(i), i.topic_type, _reliability(i.qos_profile), why))
        return self.watch.observe(time.monotonic(), received, facts, _reliability(profile))


class Inputs:
    """The input topics of one node (:class:`Input`), followed together by one timer, with their diagnostics."""

    def __init__(self, node: Node, counter: InputCounter) -> None:
        self.node = node
        self.counter = counter
        self.inputs: dict[str, Input] = {}
        self._timer = node.create_timer(QOS_CHECK_PERIOD_S, self.follow)

    def add(self, msg_type: Any, topic: str, callback: Callable[[Any], None], qos: QoSProfile | int,
            **options: Any) -> Input:
        """Subscribe ``topic`` (see :class:`Input` for ``options``)."""
        profile = QoSProfile(depth=qos) if isinstance(qos, int) else qos
        made = self.inputs[topic] = Input(self.node, self.counter, msg_type, topic, callback, profile, **options)
        return made

    def follow(self) -> None:
        for one in self.inputs.values():
            one.follow()

    def problems(self) -> list[str]:
        """What keeps each input from delivering, for ``/diagnostics`` (empty: nothing)."""
        out: list[str] = []
        for one in self.inputs.values():
            out += one.problems(self.counter.received.get(one.counter_topic, 0))
        return out

    def values(self) -> dict[str, str]:
        """``qos: <topic>`` -> the reliability of each input, for ``/diagnostics``."""
        return {f'qos: {one.topic}': one.qos_text() for one in self.inputs.values()}
