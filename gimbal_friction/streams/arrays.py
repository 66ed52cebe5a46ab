"""Plain data of the suite's input streams as numpy arrays (no I/O): what a chamber-test bag holds.

Read by :mod:`gimbal_friction.recording.bag`, consumed by the nodes' logic in the offline replay and the closed-loop
study. Times are int64 nanoseconds: ``log_time_ns`` is the receive/log time, ``stamp_ns`` is ``header.stamp``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = ['ChamberArrays', 'JointStateArrays', 'MessageCounts', 'TemperatureArrays', 'chamber_arrays',
           'joint_state_arrays', 'single_message_arrays', 'temperature_arrays']


class TemperatureArrays(NamedTuple):
    """All ``sensor_msgs/Temperature`` samples of a bag, in log-time order."""

    log_time_ns: NDArray[np.int64]
    """Log time [ns]."""
    stamp_ns: NDArray[np.int64]
    """``header.stamp`` [ns]."""
    temperature_c: NDArray[np.float64]
    """Temperature [degC]."""


class JointStateArrays(NamedTuple):
    """All ``sensor_msgs/JointState`` samples of one topic, in log-time order.

    ``position``, ``velocity`` and ``effort`` map each joint name to an array with one value per message (same
    length as ``log_time_ns``); a value is NaN where that message did not carry the joint or the field.
    """

    log_time_ns: NDArray[np.int64]
    """Log time [ns]."""
    stamp_ns: NDArray[np.int64]
    """``header.stamp`` [ns]."""
    names: tuple[str, ...]
    """Joint names in the order they were first seen."""
    position: dict[str, NDArray[np.float64]]
    """Joint position per joint name [rad]."""
    velocity: dict[str, NDArray[np.float64]]
    """Joint velocity per joint name [rad/s]."""
    effort: dict[str, NDArray[np.float64]]
    """Effort per joint name [N*m], or motor current [A] on ``/gimbal/motor_current``."""

    def __len__(self) -> int:
        """Number of messages [-] (not the number of fields)."""
        return int(self.log_time_ns.shape[0])


class ChamberArrays(NamedTuple):
    """The input streams of a chamber-test bag as numpy arrays (the three inputs, and the reference velocity
    when recorded)."""

    temperature: TemperatureArrays
    """``/gimbal/temperature``."""
    joint_states: JointStateArrays
    """``/joint_states`` (position [rad], velocity [rad/s])."""
    motor_current: JointStateArrays
    """``/gimbal/motor_current`` (effort = motor current [A])."""
    reference_velocity: JointStateArrays | None = None
    """``/gimbal/reference_velocity`` (velocity = reference joint rate [rad/s]), if the bag holds it."""


class MessageCounts(NamedTuple):
    """What :func:`joint_state_arrays` found odd in the messages it was given (the rules of
    :func:`~gimbal_friction.streams.inputs.index_joints`), per configured joint (``'*'``: none named)."""

    mismatch: dict[str, int]    #: messages whose value arrays are not as long as the name array (dropped)
    duplicate: dict[str, int]   #: repeated entries of a joint (the first one is used)
    not_a_number: dict[str, int]  #: entries whose needed values are all NaN (the joint is then absent)


def joint_state_arrays(messages: Sequence[tuple[int, int, Sequence[str], Sequence[float], Sequence[float],
                                                Sequence[float]]],
                       fields: tuple[bool, bool, bool] = (True, True, False),
                       configured: Sequence[str] | None = None) -> tuple[JointStateArrays, MessageCounts]:
    """JointState messages ``(log_time_ns, stamp_ns, names, position, velocity, effort)`` as arrays.

    ``fields`` says which of position, velocity, effort the reader needs: a message whose needed arrays are not
    as long as its names is dropped (counted). A joint named twice keeps its first entry (counted). A joint
    whose needed values are all NaN is "absent" in the arrays.
    """
    from gimbal_friction.streams.inputs import index_joints

    names: list[str] = []
    cols: dict[str, list[list[float]]] = {}
    logs: list[int] = []
    stamps: list[int] = []
    mismatch: dict[str, int] = {}
    duplicate: dict[str, int] = {}
    not_a_number: dict[str, int] = {}
    kept = 0
    for log_ns, stamp_ns, msg_names, pos, vel, eff in messages:
        values = [v for v, need in zip((pos, vel, eff), fields) if need]
        wanted = list(msg_names) if configured is None else list(configured)
        idx = index_joints(msg_names, [len(v) for v in values], wanted)
        if idx.mismatch:
            named = [j for j in wanted if j in set(msg_names)] or ['*']
            for j in named:
                mismatch[j] = mismatch.get(j, 0) + 1
            continue
        seen: set[str] = set()
        for name in msg_names:
            if name in seen:
                duplicate[name] = duplicate.get(name, 0) + 1
            seen.add(name)
        for name in msg_names:
            if name not in cols:
                names.append(name)
                cols[name] = [[math.nan] * kept, [math.nan] * kept, [math.nan] * kept]
        first = {name: i for i, name in reversed(list(enumerate(msg_names)))}
        for name, i in first.items():
            needed = [float(v[i]) for v, need in zip((pos, vel, eff), fields) if need and i < len(v)]
            if needed and all(math.isnan(x) for x in needed):
                not_a_number[name] = not_a_number.get(name, 0) + 1
        for name, col in cols.items():
            k = first.get(name)
            for f, (field_values, need) in enumerate(zip((pos, vel, eff), fields)):
                col[f].append(float(field_values[k]) if (k is not None and need and k < len(field_values))
                              else math.nan)
        logs.append(int(log_ns))
        stamps.append(int(stamp_ns))
        kept += 1
    arrays = JointStateArrays(
        np.asarray(logs, dtype=np.int64), np.asarray(stamps, dtype=np.int64), tuple(names),
        {n: np.asarray(c[0], dtype=np.float64) for n, c in cols.items()},
        {n: np.asarray(c[1], dtype=np.float64) for n, c in cols.items()},
        {n: np.asarray(c[2], dtype=np.float64) for n, c in cols.items()})
    return arrays, MessageCounts(mismatch, duplicate, not_a_number)


def temperature_arrays(messages: Sequence[tuple[int, int, float]]) -> TemperatureArrays:
    """Temperature messages ``(log_time_ns, stamp_ns, temperature_c)`` as arrays."""
    if not messages:
        return TemperatureArrays(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.float64))
    logs, stamps, values = zip(*messages)
    return TemperatureArrays(np.asarray(logs, dtype=np.int64), np.asarray(stamps, dtype=np.int64),
                             np.asarray(values, dtype=np.float64))


def chamber_arrays(temperatures: Sequence[tuple[int, int, float]] = (),
                   joint_states: Sequence[tuple[int, int, Sequence[str], Sequence[float], Sequence[float],
                                                Sequence[float]]] = (),
                   currents: Sequence[tuple[int, int, Sequence[str], Sequence[float], Sequence[float],
                                             Sequence[float]]] = (),
                   configured: Sequence[str] | None = None) -> tuple[ChamberArrays, MessageCounts, MessageCounts]:
    """A batch of messages (as a node buffers them) as :class:`ChamberArrays`, with the odd-message counts of the
    joint states and of the currents (a dropped message is counted for each ``configured`` joint it names, or
    under ``'*'`` if none)."""
    js, js_counts = joint_state_arrays(joint_states, (True, True, False), configured)
    cur, cur_counts = joint_state_arrays(currents, (False, False, True), configured)
    return ChamberArrays(temperature_arrays(temperatures), js, cur), js_counts, cur_counts


def single_message_arrays(kind: str, log_time_ns: int, stamp_ns: int, names: Sequence[str] = (),
                          position: Sequence[float] = (), velocity: Sequence[float] = (),
                          effort: Sequence[float] = (), temperature_c: float = math.nan) -> ChamberArrays:
    """One message as :class:`ChamberArrays` (``kind``: ``temperature``, ``joint_states`` or ``motor_current``);
    handy in examples and tests.

    >>> a = single_message_arrays('joint_states', 5, 4, ['elevation'], [0.1], [0.2])
    >>> a.joint_states.velocity['elevation'].tolist(), len(a.motor_current)
    ([0.2], 0)
    """
    msg = (log_time_ns, stamp_ns, list(names), list(position), list(velocity), list(effort))
    if kind == 'temperature':
        return chamber_arrays(temperatures=[(log_time_ns, stamp_ns, temperature_c)])[0]
    if kind == 'joint_states':
        return chamber_arrays(joint_states=[msg])[0]
    if kind == 'motor_current':
        return chamber_arrays(currents=[msg])[0]
    msg_text = f'unknown message kind {kind!r}'
    raise ValueError(msg_text)
