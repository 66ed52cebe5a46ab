"""Why an input topic delivers nothing: the words of the nodes' input diagnostics (no rclpy, no I/O).

A node subscribing a topic sees three ways of getting nothing, and ``/diagnostics`` must name the topic and the
cause rather than stay OK:

- **a publisher of another type** on the topic (``std_msgs/msg/String`` on ``/joint_states``): DDS never matches
  it;
- **a publisher whose QoS cannot match** the subscription (a best-effort publisher and a reliable subscription,
  for one): the middleware's own reason is quoted;
- **silence**: no publisher at all, or publishers that match but send nothing, for longer than the topic's
  timeout (only for the inputs a node cannot work without: ``required``).

The node only collects the facts (the publishers the graph shows, the middleware's compatibility verdict, how many
messages arrived, a monotonic time); :class:`InputWatch` keeps the times and words the problems.

>>> w = InputWatch('/joint_states', 'sensor_msgs/msg/JointState', required=True, timeout_s=2.0, now_s=0.0)
>>> w.observe(1.0, 0, [])
[]
>>> w.observe(3.0, 0, [])
['/joint_states: no publisher for 3 s']
>>> w.observe(4.0, 0, [PublisherFacts('/driver', 'std_msgs/msg/String', 'reliable')])
['/joint_states: publisher /driver sends std_msgs/msg/String, this node reads sensor_msgs/msg/JointState (nothing \
of it arrives)']
>>> w.observe(5.0, 0, [PublisherFacts('/driver', 'sensor_msgs/msg/JointState', 'best_effort',
...                                   'best effort publisher and reliable subscription')], 'reliable')[0]
'/joint_states: publisher /driver (best_effort) cannot match this reliable subscription: best effort publisher and \
reliable subscription (set qos_overrides./joint_states.subscription.reliability)'
>>> ok = [PublisherFacts('/driver', 'sensor_msgs/msg/JointState', 'reliable')]
>>> w.observe(6.0, 0, ok), w.observe(8.5, 0, ok), w.observe(9.0, 7, ok)
([], ['/joint_states: 1 publisher matched but nothing received for 2.5 s'], [])
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

#: how long a required input may have no publisher, or matched publishers that send nothing, before it is reported
#: (where the node has no timeout of its own for it) [s]
SILENCE_TIMEOUT_S = 5.0


class PublisherFacts(NamedTuple):
    """One publisher of a topic as the ROS graph shows it."""

    node: str             #: fully qualified name of the node that publishes
    type_name: str        #: its message type (``sensor_msgs/msg/JointState``)
    reliability: str      #: its reliability (``reliable``, ``best_effort``)
    incompatible: str = ''  #: why its QoS cannot match the subscription (the middleware's words); '' = it can


def _seconds(dt_s: float) -> str:
    return f'{dt_s:.0f} s' if dt_s >= 3.0 else f'{dt_s:.2g} s'


def _plural(n: int, word: str) -> str:
    return f'{n} {word}' if n == 1 else f'{n} {word}s'


class InputWatch:
    """The health of one input topic of a node, from the facts collected each diagnostics period.

    Parameters
    ----------
    topic : str
        The topic (resolved name) the node subscribes.
    type_name : str
        The message type the node reads (``sensor_msgs/msg/JointState``).
    required : bool
        The node cannot work without it: silence (no publisher, or nothing received) is reported after
        ``timeout_s``. Type and QoS mismatches are reported for every input.
    timeout_s : float
        How long silence is tolerated [s].
    now_s : float
        Monotonic time the watch starts (the node's start) [s].
    """

    def __init__(self, topic: str, type_name: str, *, required: bool, timeout_s: float = SILENCE_TIMEOUT_S,
                 now_s: float) -> None:
        self.topic = topic
        self.type_name = type_name
        self.required = required
        self.timeout_s = timeout_s
        self._since = now_s          #: start of the current silence (no usable publisher, or nothing received)
        self._received = 0
        self._usable = 0

    def observe(self, now_s: float, received: int, publishers: Sequence[PublisherFacts],
                reliability: str = '') -> list[str]:
        """The problems of the topic now: ``received`` = messages received so far [-], ``publishers`` = the
        graph's publishers of the topic, ``reliability`` = the subscription's (for the words only); ``now_s`` [s],
        monotonic."""
        problems = []
        usable = 0
        for p in publishers:
            if p.type_name != self.type_name:
                problems.append(f'{self.topic}: publisher {p.node} sends {p.type_name}, this node reads '
                                f'{self.type_name} (nothing of it arrives)')
            elif p.incompatible:
                sub = f'this {reliability} subscription' if reliability else 'this subscription'
                problems.append(f'{self.topic}: publisher {p.node} ({p.reliability}) cannot match {sub}: '
                                f'{p.incompatible} (set qos_overrides.{self.topic}.subscription.reliability)')
            else:
                usable += 1
        if received != self._received or (usable and not self._usable):
            self._since = now_s       # something arrived, or a usable publisher appeared: silence starts again
        self._received, self._usable = received, usable
        silent = now_s - self._since
        if self.required and silent > self.timeout_s:
            if not publishers:
                problems.append(f'{self.topic}: no publisher for {_seconds(silent)}')
            elif usable:
                problems.append(f'{self.topic}: {_plural(usable, "publisher")} matched but nothing received for '
                                f'{_seconds(silent)}')
        return problems
