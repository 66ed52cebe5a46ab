"""Unit conversions used across the suite, defined once.

The paper works in N·mm, rpm and cSt (= mm²/s); every ROS interface is SI (REP 103): N·m, rad/s, s. Kinematic
viscosity ν [mm²/s] and dynamic viscosity η [Pa·s] are never mixed: nothing here converts between them.

>>> round(rad_s_from_rpm(1.0 / 3.0), 6)       # the paper's test speed, 1/3 rpm
0.034907
>>> nmm_from_nm(3.19e-3)
3.19
>>> seconds_from_ns(1_500_000_000)
1.5
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

#: [rpm per rad/s]
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
#: [rad/s per rpm]
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
#: [N·mm per N·m]
NMM_PER_NM = 1e3
#: [N·m per N·mm]
NM_PER_NMM = 1e-3
#: [ns per s]
NS_PER_S = 1_000_000_000

X = TypeVar('X', float, NDArray[np.float64])


def rpm_from_rad_s(omega_rad_s: X) -> X:
    """Speed [rpm] from angular velocity [rad/s] (sign kept)."""
    return omega_rad_s * RPM_PER_RAD_S


def rad_s_from_rpm(n_rpm: X) -> X:
    """Angular velocity [rad/s] from speed [rpm] (sign kept)."""
    return n_rpm * RAD_S_PER_RPM


def nm_from_nmm(torque_nmm: X) -> X:
    """Torque [N·m] from [N·mm]."""
    return torque_nmm * NM_PER_NMM


def nmm_from_nm(torque_nm: X) -> X:
    """Torque [N·mm] from [N·m]."""
    return torque_nm * NMM_PER_NM


def seconds_from_ns(t_ns: int) -> float:
    """Time [s] from an integer time [ns]."""
    return t_ns / NS_PER_S


def ns_from_seconds(t_s: float) -> int:
    """Integer time [ns] from [s], rounded to the nearest nanosecond."""
    return int(round(t_s * NS_PER_S))


def split_stamp(t_ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` fields ``(sec, nanosec)`` of a time [ns] (floor division: nanosec ≥ 0)."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return sec, nanosec


def join_stamp(sec: int, nanosec: int) -> int:
    """Time [ns] of ``builtin_interfaces/Time`` fields."""
    return int(sec) * NS_PER_S + int(nanosec)
