"""Tabulated fast path of the model for the nodes: build once (vectorised), evaluate in microseconds.

The contact torques M_R and M_S depend on temperature only (not on speed), so they are tabulated on a uniform
temperature grid and linearly interpolated. The viscous torque M_L is evaluated exactly at every call from the
Walther viscosity and Palmgren's Eq. (9), because it is the part that depends on speed.

>>> table = FrictionTable(AxisParams())
>>> round(table.torque_nmm(-40.0, 1.0 / 3.0), 3)
3.143
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.core.errors import ModelDomainError
from gimbal_friction.core.friction import viscous_torque_Palmgren_1959
from gimbal_friction.core.model import friction_torque, viscosity_cst
from gimbal_friction.core.params import AxisParams

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)


class TableComponents(NamedTuple):
    """Axis torque components [N·mm] and viscosity [cSt] at one (temperature, speed)."""

    m_rolling_nmm: float
    m_sliding_nmm: float
    m_viscous_nmm: float
    m_total_nmm: float
    viscosity_cst: float
    in_range: bool


class FrictionTable:
    """The model tabulated over ``[t_min, t_max]`` °C at ``step`` °C for one axis.

    Parameters
    ----------
    params : AxisParams
        Model parameters of the axis.
    t_min, t_max : float
        Temperature range of the table, [°C]. Outside it the torque is clamped to the edge value and
        ``in_range`` is False.
    step : float
        Grid step, [°C].
    """

    def __init__(self, params: AxisParams, t_min: float = -60.0, t_max: float = 120.0, step: float = 0.1) -> None:
        if not (math.isfinite(t_min) and math.isfinite(t_max) and t_max > t_min):
            raise ModelDomainError('table range must be finite with t_max > t_min')
        if not (math.isfinite(step) and step > 0.0):
            raise ModelDomainError('table step must be > 0 degC')
        self.params = params
        self.t_min = float(t_min)
        self.step = float(step)
        n = int(round((t_max - t_min) / step)) + 1
        self.t_max = self.t_min + (n - 1) * self.step
        grid = self.t_min + self.step * np.arange(n)
        result = friction_torque(params, grid, 0.0)
        self.grid = grid
        self._m_r: list[float] = result.m_rolling_nmm.tolist()
        self._m_s: list[float] = result.m_sliding_nmm.tolist()
        self._n = n
        # Exact viscosity and Palmgren terms (scalar, pure Python for speed).
        p = params
        self._a, self._b, self._c = p.walther_a, p.walther_b, p.viscosity_offset_cst
        self._kelvin = p.kelvin_offset_k
        self._improved = p.viscosity_model == 'walther_improved'
        self._dm0 = p.pitch_diameter_mm
        self._phi_s = p.steel_cte_per_c
        self._t_ref = p.reference_temperature_c
        self._k_l = float(p.bearings_per_axis) * p.palmgren_factor

    # ------------------------------------------------------------------ scalar fast path
    def viscosity_cst(self, t_c: float) -> float:
        """Kinematic viscosity at ``t_c`` [°C] (exact, Eq. 20/21), [mm²/s]."""
        x = math.log10(t_c + self._kelvin)
        if self._improved:
            x = math.log10(x)
        return 10.0 ** (10.0 ** (self._a + self._b * x)) - self._c

    def components(self, t_c: float, speed_rpm: float) -> TableComponents:
        """Axis torque components at temperature ``t_c`` [°C] and speed ``speed_rpm`` [rpm] (magnitude used)."""
        pos = (t_c - self.t_min) / self.step
        in_range = 0.0 <= pos <= self._n - 1
        if pos <= 0.0:
            m_r, m_s = self._m_r[0], self._m_s[0]
            t_eval = self.t_min
        elif pos >= self._n - 1:
            m_r, m_s = self._m_r[-1], self._m_s[-1]
            t_eval = self.t_max
        else:
            i = int(pos)
            w = pos - i
            m_r = self._m_r[i] + w * (self._m_r[i + 1] - self._m_r[i])
            m_s = self._m_s[i] + w * (self._m_s[i + 1] - self._m_s[i])
            t_eval = t_c
        nu = self.viscosity_cst(t_eval)
        vn = nu * abs(speed_rpm)
        dm = self._dm0 * (1.0 + self._phi_s * (t_eval - self._t_ref))
        factor = vn ** (2.0 / 3.0) if vn >= 2000.0 else 160.0
        m_l = 1e-7 * self._k_l * factor * dm * dm * dm
        return TableComponents(m_r, m_s, m_l, m_r + m_s + m_l, nu, in_range)

    def torque_nmm(self, t_c: float, speed_rpm: float) -> float:
        """Friction torque magnitude of the axis, [N·mm]."""
        return self.components(t_c, speed_rpm).m_total_nmm

    def torque_nm(self, t_c: float, omega_rad_s: float) -> float:
        """Friction torque magnitude of the axis at angular velocity ``omega_rad_s`` [rad/s], [N·m]."""
        return 1e-3 * self.components(t_c, omega_rad_s * RPM_PER_RAD_S).m_total_nmm

    # ------------------------------------------------------------------ vectorised
    def evaluate(self, t_c: ArrayLike, speed_rpm: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                        NDArray[np.float64]]:
        """Vectorised (M_R + M_S, M_L, M) of the axis for arrays of temperature [°C] and speed [rpm], [N·mm].

        Same numbers as :meth:`components` (clamped outside the table).
        """
        t = np.clip(np.asarray(t_c, dtype=float), self.t_min, self.t_max)
        n = np.abs(np.asarray(speed_rpm, dtype=float))
        m_rs = np.interp(t, self.grid, np.add(self._m_r, self._m_s))
        p = self.params
        nu = viscosity_cst(p, t)
        dm = self._dm0 * (1.0 + self._phi_s * (t - self._t_ref))
        m_l = float(p.bearings_per_axis) * viscous_torque_Palmgren_1959(p.palmgren_factor, nu, n, dm)
        return m_rs, m_l, m_rs + m_l
