"""The residual row, defined once: one measured sample next to the feedforward that was predicted for it.

``residual_logger`` (live) and ``gimbal-friction replay`` (offline) build rows with :func:`residual_rows` from what
the estimator measured (:class:`~gimbal_friction.streams.measurement.MeasurementArrays`) and the feedforward of the
same joint-state stamp; both log each row on ``/gimbal/friction/residual_detail`` (std_msgs/Float64MultiArray,
``layout.dim[0].label`` = joint, ``data`` = :data:`RESIDUAL_FIELDS`) and ``/gimbal/friction/residual``
(sensor_msgs/JointState, effort = residual). ``refit`` reads the rows back with :func:`rows_from_detail`. Every other
form (the column list of the README, the reader's arrays) derives from :data:`RESIDUAL_FIELDS`.

A sample whose feedforward never arrived keeps ``predicted_nm`` and ``residual_nm`` NaN (counted by the logger):
the measurement is still good for a refit, which compares the measured friction with the model, not with the
prediction.

Layout 1 (written before 2026-11, 11 columns: ``stamp_s, temperature_c, position_rad, velocity_rad_s, current_a,
measured_nm, predicted_nm, m_rolling_nm, m_sliding_nm, m_viscous_nm, residual_nm``) is still read; its model
components were never used and are dropped.

>>> RESIDUAL_FIELDS.index('residual_nm')
7
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.streams.measurement import METHOD_STEADY_STATE, MeasurementArrays

#: ``data[]`` of ``/gimbal/friction/residual_detail``, in order (SI; temperature in °C)
RESIDUAL_FIELDS = (
    'stamp_s',                   # joint-state stamp of the measured sample [s]
    'temperature_c',             # bearing temperature of the measurement [degC] (NaN: none)
    'position_rad',              # joint position [rad]
    'velocity_rad_s',            # joint velocity relative to the base [rad/s]
    'current_a',                 # motor current [A]
    'measured_nm',               # measured friction, signed [N*m]
    'predicted_nm',              # feedforward published for the same stamp, signed [N*m] (NaN: none arrived)
    'residual_nm',               # measured - predicted [N*m]
    'acceleration_rad_s2',       # acceleration used by the observer [rad/s^2] (0: steady state)
    'torque_constant_nm_per_a',  # K_T applied by the estimator [N*m/A]
    'no_load_current_a',         # I_0 applied by the estimator [A]
    'method',                    # 0 steady state (Eq. 23), 1 observer (Eq. 23 - J*alpha)
)
#: the columns of layout 1 (read only)
RESIDUAL_FIELDS_V1 = ('stamp_s', 'temperature_c', 'position_rad', 'velocity_rad_s', 'current_a', 'measured_nm',
                      'predicted_nm', 'm_rolling_nm', 'm_sliding_nm', 'm_viscous_nm', 'residual_nm')


class ResidualRows(NamedTuple):
    """Residual rows as arrays, one per field of :data:`RESIDUAL_FIELDS` after the joint name."""

    joint: NDArray[np.str_]
    stamp_s: NDArray[np.float64]
    temperature_c: NDArray[np.float64]
    position_rad: NDArray[np.float64]
    velocity_rad_s: NDArray[np.float64]
    current_a: NDArray[np.float64]
    measured_nm: NDArray[np.float64]
    predicted_nm: NDArray[np.float64]
    residual_nm: NDArray[np.float64]
    acceleration_rad_s2: NDArray[np.float64]
    torque_constant_nm_per_a: NDArray[np.float64]
    no_load_current_a: NDArray[np.float64]
    method: NDArray[np.int8]

    def __len__(self) -> int:
        """Number of rows [-] (not the number of fields)."""
        return int(self.stamp_s.shape[0])

    def matrix(self) -> NDArray[np.float64]:
        """The ``residual_detail`` data of every row: an (n, len(RESIDUAL_FIELDS)) array."""
        cols = [np.asarray(getattr(self, name), dtype=np.float64) for name in RESIDUAL_FIELDS]
        return np.column_stack(cols).reshape(-1, len(RESIDUAL_FIELDS))

    def select(self, index: NDArray[np.intp] | NDArray[np.bool_]) -> ResidualRows:
        """The rows at ``index`` (an index or a boolean mask)."""
        cols: list[Any] = [np.asarray(column)[index] for column in self]
        return ResidualRows(*cols)

    @staticmethod
    def concatenate(parts: list[ResidualRows]) -> ResidualRows:
        """The rows of ``parts``, in order."""
        if not parts:
            return rows_from_detail(np.empty(0, dtype=str), np.empty((0, len(RESIDUAL_FIELDS))))
        if len(parts) == 1:
            return parts[0]
        joined: list[Any] = [np.concatenate(c) for c in zip(*parts, strict=True)]
        return ResidualRows(*joined)


def residual_rows(measured: MeasurementArrays, predicted_nm: NDArray[np.float64]) -> ResidualRows:
    """The residual row of every measured sample, ``predicted_nm`` [N·m] being the feedforward published for the
    same joint and joint-state stamp (NaN where none arrived)."""
    predicted = np.asarray(predicted_nm, dtype=np.float64).reshape(-1)
    if predicted.shape[0] != len(measured):
        msg = f'{predicted.shape[0]} predictions for {len(measured)} measurements'
        raise ValueError(msg)
    stamp_s = np.asarray(measured.stamp_ns, dtype=np.int64) / NS_PER_S
    return ResidualRows(np.asarray(measured.joint, dtype=str), stamp_s, measured.temperature_c,
                        measured.position_rad, measured.velocity_rad_s, measured.current_a, measured.friction_nm,
                        predicted, measured.friction_nm - predicted, measured.acceleration_rad_s2,
                        measured.torque_constant_nm_per_a, measured.no_load_current_a,
                        np.asarray(measured.method, dtype=np.int8))


def rows_from_detail(joints: NDArray[np.str_] | list[str], data: NDArray[np.float64]) -> ResidualRows:
    """Rows from ``residual_detail`` data: (n, 12) in :data:`RESIDUAL_FIELDS` order, or (n, 11) of layout 1
    (K_T, I_0 and acceleration unknown: NaN, NaN, 0; method steady state).

    Raises:
        ValueError: another number of columns, or not one joint label per row.
    """
    d = np.asarray(data, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] not in (len(RESIDUAL_FIELDS), len(RESIDUAL_FIELDS_V1)):
        msg = (f'residual_detail rows must have {len(RESIDUAL_FIELDS)} (or, layout 1, {len(RESIDUAL_FIELDS_V1)}) '
               f'values, got shape {d.shape}')
        raise ValueError(msg)
    j = np.asarray(joints, dtype=str)
    if j.shape[0] != d.shape[0]:
        msg = f'{j.shape[0]} joint labels for {d.shape[0]} rows'
        raise ValueError(msg)
    if d.shape[1] == len(RESIDUAL_FIELDS):
        cols: list[Any] = [j, *(d[:, i] for i in range(d.shape[1] - 1)), d[:, -1].astype(np.int8)]
        return ResidualRows(*cols)
    v1 = {name: d[:, i] for i, name in enumerate(RESIDUAL_FIELDS_V1)}
    n = d.shape[0]
    return ResidualRows(j, v1['stamp_s'], v1['temperature_c'], v1['position_rad'], v1['velocity_rad_s'],
                        v1['current_a'], v1['measured_nm'], v1['predicted_nm'], v1['residual_nm'], np.zeros(n),
                        np.full(n, np.nan), np.full(n, np.nan), np.full(n, METHOD_STEADY_STATE, dtype=np.int8))
