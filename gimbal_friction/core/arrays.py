"""Plain data of the suite's input streams as numpy arrays (no I/O): what a chamber-test bag holds.

Read by :mod:`gimbal_friction.recording.bag`, consumed by the nodes' logic in the offline replay and the closed-loop
study. Times are int64 nanoseconds: ``log_time_ns`` is the receive/log time, ``stamp_ns`` is ``header.stamp``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = ['ChamberArrays', 'JointStateArrays', 'TemperatureArrays']


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
    """The three input streams of a chamber-test bag as numpy arrays."""

    temperature: TemperatureArrays
    """``/gimbal/temperature``."""
    joint_states: JointStateArrays
    """``/joint_states`` (position [rad], velocity [rad/s])."""
    motor_current: JointStateArrays
    """``/gimbal/motor_current`` (effort = motor current [A])."""
