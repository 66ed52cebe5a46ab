"""Fixtures of the node and parameter tests of the robustness suite (imported by those test modules; the
package's conftest.py holds the file and CLI fixtures).

- live nodes: ``spawn`` and ``probe`` of test/conftest.py (the harness test/ros uses too).
- ``in_process``: the node classes built in this process on a private rclpy context (isolated domain, loopback),
  their publishers replaced by recorders. Callbacks are called directly: thousands of hostile messages per second
  through the very adapter code the executables run, without DDS in the way.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip('rclpy', reason='node tests need the ros-* wheels (requirements.txt)')

ROOT = Path(__file__).resolve().parents[2]


class Recorder:
    """Stands in for a publisher: keeps what would have been published (serialized and read back, as a
    subscriber would get it: the nodes reuse their message objects, or publish serialized bytes of ``msg_type``)."""

    def __init__(self, msg_type: Any = None) -> None:
        self.msg_type = msg_type
        self.messages: list[Any] = []

    def publish(self, msg: Any) -> None:
        from rclpy.serialization import deserialize_message, serialize_message
        if isinstance(msg, bytes):
            self.messages.append(deserialize_message(msg, self.msg_type))
        else:
            self.messages.append(deserialize_message(serialize_message(msg), type(msg)))

    def clear(self) -> None:
        self.messages.clear()


class InProcess:
    """Builds nodes on one private context; ``make(cls, *args, **parameters)`` returns the node with every
    publisher (attributes named ``pub_*``) replaced by a :class:`Recorder`."""

    def __init__(self, domain: int) -> None:
        self.domain = domain
        self.context = rclpy.Context()
        rclpy.init(args=['robustness'], context=self.context, domain_id=domain)
        self.nodes: list[Any] = []

    def make(self, cls: Callable[..., Any], **parameters: Any) -> Any:
        from rclpy.parameter import Parameter
        overrides = [Parameter(k, value=v) for k, v in parameters.items()]
        node = cls(context=self.context, parameter_overrides=overrides)
        for name in list(vars(node)):
            if name.startswith('pub_'):
                setattr(node, name, Recorder(getattr(node, name).msg_type))
        for one in getattr(getattr(node, 'input_topics', None), 'inputs', {}).values():
            one.watch.required = False   # callbacks are called directly: no publisher is on the graph, by design
        self.nodes.append(node)
        return node

    def close(self) -> None:
        for node in self.nodes:
            close = getattr(node, 'close', None)
            if close is not None:
                close()
            node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture(scope='module')
def in_process(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InProcess]:
    from gimbal_friction.runs.supervisor import free_domain
    log_dir = tmp_path_factory.mktemp('roslog')
    saved = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_LOG_DIR')}
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_LOG_DIR=str(log_dir))
    with free_domain() as did:
        p = InProcess(did)
        try:
            yield p
        finally:
            p.close()
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


def finite_within(values: Any, bound: float) -> bool:
    """Every value finite and at most ``bound`` in magnitude."""
    return all(math.isfinite(v) and abs(v) <= bound for v in values)


def diag_statuses(msgs: list[Any]) -> list[Any]:
    """The DiagnosticStatus entries of the last DiagnosticArray recorded."""
    return list(msgs[-1].status) if msgs else []


def diag_values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


#: the speed of the learnable measured_detail samples [rad/s] (1/3 rpm)
V_DETAIL = 2 * math.pi / 180


def hostile_details(n: int, sec: int) -> list[Any]:
    """``n`` measured_detail messages (std_msgs/Float64MultiArray) stamped ``sec`` for the learning: 5 in 8 of
    them unusable, each kind for another reason the node or the learner refuses, the rest learnable."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS
    width = len(MEASUREMENT_FIELDS)
    stamp, method = MEASUREMENT_FIELDS.index('stamp_sec'), MEASUREMENT_FIELDS.index('method')
    velocity, friction = MEASUREMENT_FIELDS.index('velocity_rad_s'), MEASUREMENT_FIELDS.index('friction_nm')
    fresh = MEASUREMENT_FIELDS.index('temperature_fresh')
    out = []
    for k in range(n):
        data = [0.0] * width
        data[stamp], data[velocity], data[friction], data[fresh], data[method] = sec, V_DETAIL, 3.3e-3, 1.0, 1.0
        label = 'elevation'
        kind = k % 8
        if kind == 0:
            data = data[:5]                                   # not of the layout's width
        elif kind == 1:
            label = 'bogus'                                   # unknown joint
        elif kind == 2:
            data[method] = 7.0                                # unknown method
        elif kind == 3:
            data[velocity] = math.nan                         # non-finite
        elif kind == 4:
            data[friction] = 1e154                            # implausible friction
        elif kind == 5:
            data[stamp] = 0.0                                 # stale temperature
        msg = Float64MultiArray(data=data)
        if kind != 6 or k % 16 == 6:                          # half of kind 6: no joint label at all
            msg.layout.dim = [MultiArrayDimension(label=label, size=1, stride=1)]
        out.append(msg)
    return out

