"""What the estimator measured, defined once: the arrays, and the ``measured_detail`` message layout.

``friction_estimator`` publishes each accepted sample twice over, each for its own reader: on
``/gimbal/friction/measured`` (sensor_msgs/JointState: position, velocity, effort = friction; for plots and
controllers) and on ``/gimbal/friction/measured_detail`` (std_msgs/Float64MultiArray, ``layout.dim[0].label`` = the
joint, ``data`` = :data:`MEASUREMENT_FIELDS`) with everything the measurement used: the motor current, the
temperature, the K_T and I_0 applied, the acceleration and the method. The residual logger reads the detail, so
nothing is reconstructed downstream (data travel once). The stamp travels as two exact integers (sec, nanosec).

>>> MEASUREMENT_FIELDS[:3]
('stamp_sec', 'stamp_nanosec', 'position_rad')
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.units import NS_PER_S

#: ``method`` code of a steady-state sample (paper Eq. 23 in the chamber protocol: constant speed, no
#: acceleration)
METHOD_STEADY_STATE = 0
#: ``method`` code of an observer sample (Eq. 23 minus J·α̂ while the gimbal works)
METHOD_OBSERVER = 1
METHOD_NAMES = {METHOD_STEADY_STATE: 'steady_state', METHOD_OBSERVER: 'observer'}

#: ``data[]`` of ``/gimbal/friction/measured_detail``, in order (SI; temperature in °C as sensor_msgs/Temperature)
MEASUREMENT_FIELDS = (
    'stamp_sec',                 # header.stamp.sec of the joint state of the sample [s], an integer
    'stamp_nanosec',             # header.stamp.nanosec of that joint state [ns], an integer
    'position_rad',              # joint position [rad]
    'velocity_rad_s',            # joint velocity relative to the base [rad/s]
    'acceleration_rad_s2',       # acceleration used by the observer [rad/s^2] (0 for steady-state samples)
    'current_a',                 # motor current [A]
    'temperature_c',             # bearing temperature used [degC] (NaN: none)
    'temperature_fresh',         # 1 if that temperature was fresh for this sample, else 0
    'friction_nm',               # measured friction, signed like the motion [N*m]
    'torque_constant_nm_per_a',  # K_T applied [N*m/A]
    'no_load_current_a',         # I_0 applied [A]
    'inertia_kg_m2',             # J applied by the observer [kg*m^2] (0 for steady-state samples)
    'method',                    # METHOD_STEADY_STATE (0) or METHOD_OBSERVER (1)
)


class Measurement(NamedTuple):
    """One accepted friction sample (a row of :class:`MeasurementArrays`)."""

    joint: str
    stamp_ns: int            #: joint-state stamp of the sample [ns]
    position_rad: float
    velocity_rad_s: float
    acceleration_rad_s2: float
    current_a: float
    temperature_c: float
    temperature_fresh: bool
    friction_nm: float
    torque_constant_nm_per_a: float
    no_load_current_a: float
    inertia_kg_m2: float
    method: int

    @property
    def direction(self) -> int:
        """+1 (positive motion, the paper's CW) or −1."""
        return 1 if self.velocity_rad_s > 0.0 else -1


class MeasurementArrays(NamedTuple):
    """Accepted friction samples as arrays (one entry per sample, in the order they were accepted)."""

    joint: NDArray[np.str_]
    stamp_ns: NDArray[np.int64]            #: joint-state stamp of the sample [ns]
    position_rad: NDArray[np.float64]      #: [rad]
    velocity_rad_s: NDArray[np.float64]    #: relative to the base [rad/s]
    acceleration_rad_s2: NDArray[np.float64]  #: used by the observer [rad/s²] (0: steady state)
    current_a: NDArray[np.float64]         #: motor current [A]
    temperature_c: NDArray[np.float64]     #: temperature used [°C] (NaN: none)
    temperature_fresh: NDArray[np.bool_]   #: that temperature was fresh for this sample
    friction_nm: NDArray[np.float64]       #: signed like the motion [N·m]
    torque_constant_nm_per_a: NDArray[np.float64]  #: K_T applied [N·m/A]
    no_load_current_a: NDArray[np.float64]  #: I_0 applied [A]
    inertia_kg_m2: NDArray[np.float64]     #: J applied [kg·m²] (0: steady state)
    method: NDArray[np.int8]               #: METHOD_STEADY_STATE or METHOD_OBSERVER

    def __len__(self) -> int:
        """Number of samples [-] (not the number of fields)."""
        return int(self.stamp_ns.shape[0])

    @property
    def direction(self) -> NDArray[np.int8]:
        """Direction of motion of each sample: +1 (positive, the paper's CW) or −1."""
        return np.where(self.velocity_rad_s > 0.0, 1, -1).astype(np.int8)

    def records(self) -> list[Measurement]:
        """The samples as :class:`Measurement` records (plain Python values)."""
        cols = [np.asarray(c).tolist() for c in self]
        return [Measurement(*row) for row in zip(*cols, strict=True)] if len(self) else []

    def select(self, index: NDArray[np.intp] | NDArray[np.bool_]) -> MeasurementArrays:
        """The samples at ``index`` (an index or a boolean mask)."""
        cols: list[Any] = [np.asarray(column)[index] for column in self]
        return MeasurementArrays(*cols)

    @staticmethod
    def empty() -> MeasurementArrays:
        """No samples."""
        f = np.empty(0, dtype=np.float64)
        return MeasurementArrays(np.empty(0, dtype=str), np.empty(0, dtype=np.int64), f, f, f, f, f,
                                 np.empty(0, dtype=bool), f, f, f, f, np.empty(0, dtype=np.int8))

    @staticmethod
    def concatenate(parts: list[MeasurementArrays]) -> MeasurementArrays:
        """The samples of ``parts``, in order."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return MeasurementArrays.empty()
        if len(parts) == 1:
            return parts[0]
        joined: list[Any] = [np.concatenate(c) for c in zip(*parts, strict=True)]
        return MeasurementArrays(*joined)


def detail_matrix(m: MeasurementArrays) -> NDArray[np.float64]:
    """The ``measured_detail`` data of every sample: an (n, len(MEASUREMENT_FIELDS)) array."""
    sec, nanosec = np.divmod(np.asarray(m.stamp_ns, dtype=np.int64), NS_PER_S)
    return np.column_stack([sec.astype(np.float64), nanosec.astype(np.float64), m.position_rad, m.velocity_rad_s,
                            m.acceleration_rad_s2, m.current_a, m.temperature_c,
                            m.temperature_fresh.astype(np.float64), m.friction_nm, m.torque_constant_nm_per_a,
                            m.no_load_current_a, m.inertia_kg_m2, m.method.astype(np.float64)]).reshape(
                                -1, len(MEASUREMENT_FIELDS))


def from_detail(joints: NDArray[np.str_] | list[str], data: NDArray[np.float64]) -> MeasurementArrays:
    """Measurements from ``measured_detail`` rows (``data``: (n, len(MEASUREMENT_FIELDS))).

    Raises:
        ValueError: ``data`` does not have one row per joint and the layout's columns, a stamp is not a valid
            ``builtin_interfaces/Time`` (a NaN or 1e300 second would wrap to a plausible stamp when converted), or a
            method code is unknown.

    >>> from_detail(['elevation'], [[float('nan')] + [0.0] * 12])
    Traceback (most recent call last):
    ...
    ValueError: stamp_sec must be a whole number that fits int32 and stamp_nanosec a whole number in [0, 1e9)
    """
    d = np.asarray(data, dtype=np.float64).reshape(-1, len(MEASUREMENT_FIELDS))
    j = np.asarray(joints, dtype=str)
    if j.shape[0] != d.shape[0]:
        msg = f'{j.shape[0]} joint labels for {d.shape[0]} rows'
        raise ValueError(msg)
    sec, nanosec, method = d[:, 0], d[:, 1], d[:, 12]
    with np.errstate(invalid='ignore'):
        stamp_ok = (np.isfinite(sec) & (sec == np.round(sec)) & (sec >= -2.0**31) & (sec < 2.0**31)
                    & np.isfinite(nanosec) & (nanosec == np.round(nanosec)) & (nanosec >= 0) & (nanosec < NS_PER_S))
    if not np.all(stamp_ok):
        msg = 'stamp_sec must be a whole number that fits int32 and stamp_nanosec a whole number in [0, 1e9)'
        raise ValueError(msg)
    if not np.all(np.isin(method, list(METHOD_NAMES))):
        msg = f'method must be one of {sorted(METHOD_NAMES)}'
        raise ValueError(msg)
    stamp = sec.astype(np.int64) * NS_PER_S + nanosec.astype(np.int64)
    return MeasurementArrays(j, stamp, d[:, 2], d[:, 3], d[:, 4], d[:, 5], d[:, 6], d[:, 7] != 0.0, d[:, 8],
                             d[:, 9], d[:, 10], d[:, 11], d[:, 12].astype(np.int8))
