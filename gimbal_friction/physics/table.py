"""Tabulated fast path of the model: build once (vectorised), evaluate in about a microsecond.

The contact torques M_R + M_S depend on temperature only (not on speed), so they are tabulated on a uniform
temperature grid and linearly interpolated (:func:`interp_uniform`). The viscous torque M_L is evaluated exactly
at every call from the Walther viscosity (Eq. 20/21) and Palmgren's Eq. (9), because it is the part that depends
on speed. One method, :meth:`FrictionTable.magnitude_nm`, does it for a Python float (``xp`` = SCALAR: the nodes and
the in-process controller API) or for numpy arrays (``xp`` = ARRAY: the offline replay and the loop study).

>>> table = FrictionTable(AxisParams())
>>> round(table.torque_nmm(-40.0, 1.0 / 3.0), 3)
3.143
>>> table.magnitude_nm(np.array([-40.0, 20.0]), np.full(2, 0.0349066), ARRAY).round(7).tolist()
[0.003143, 0.0010457]
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Generic, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.common.units import NM_PER_NMM, NMM_PER_NM, RAD_S_PER_RPM, RPM_PER_RAD_S
from gimbal_friction.common.xp import ARRAY, SCALAR, FloatArray, Namespace, X
from gimbal_friction.physics.friction import palmgren_coefficient, viscous_torque_from_coefficient
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, AxisParams
from gimbal_friction.physics.thermal import loose_fit_temperature, thermal_expansion_Eq11
from gimbal_friction.physics.viscosity import nu_Walther

__all__ = ['FrictionTable', 'TemperatureTerms', 'interp_uniform', 'magnitude_from_terms']


def interp_uniform(values: Sequence[float] | FloatArray, x: X, x0: float, step: float, n: int, xp: Namespace[X]
                   ) -> X:
    """Linear interpolation in ``values`` (``n`` samples at ``x0 + k·step``), ``x`` clamped to the grid.

    ``values`` is a list for ``xp`` = SCALAR, an array for ARRAY.

    >>> interp_uniform([0.0, 10.0, 30.0], 1.5, 0.0, 1.0, 3, SCALAR)
    20.0
    """
    pos = xp.clip((x - x0) / step, 0.0, n - 1.0)
    i = xp.floor_index(pos, n - 2)
    w = pos - i
    lo = xp.take(values, i)
    return lo + w * (xp.take(values, i + 1) - lo)


class TemperatureTerms(NamedTuple, Generic[X]):
    """The temperature-dependent terms of the tabulated model (floats or arrays): the model's quantities and the
    products :func:`magnitude_from_terms` needs per speed, computed once per temperature."""

    m_contact_nmm: X     #: M_R + M_S of the axis, interpolated [N·mm]
    viscosity_cst: X     #: kinematic viscosity ν (Eq. 20/21) [mm²/s]
    pitch_mm: X          #: pitch diameter d_m at temperature (Eq. 11) [mm]
    viscous_nmm: X       #: the viscosity- and speed-free part of M_L of the axis, bearings × 1e-7 s0 d_m³ [N·mm]
    contact_nm: X        #: ``m_contact_nmm`` in [N·m]
    viscous_nm: X        #: ``viscous_nmm`` in [N·m]
    nu_rpm_per_rad_s: X  #: ν × (rpm per rad/s): ν n of Eq. (9) [cSt·rpm] is this × |ω| [rad/s]


def magnitude_from_terms(terms: TemperatureTerms[X], omega_rad_s: X, xp: Namespace[X]) -> X:
    """Friction torque magnitude [N·m] from the temperature terms of a table
    (:meth:`FrictionTable.temperature_terms`) and the angular velocity ``omega_rad_s`` [rad/s] (magnitude used):
    interpolated M_R + M_S plus the exact M_L of Eq. (9) of all bearings of the axis. (Eq. 10 with M_R + M_S
    tabulated as one term: the one sum left, written inline on this ~1 µs path; the model's sum is
    :func:`~gimbal_friction.physics.friction.total_torque_Eq10`. Eq. 9 takes the coefficient in N·m and ν in
    cSt·rpm per rad/s, so the speed enters in rad/s and M_L comes out in N·m: two products per temperature instead
    of two per call.)"""
    return terms.contact_nm + viscous_torque_from_coefficient(terms.viscous_nm, terms.nu_rpm_per_rad_s, omega_rad_s,
                                                              xp)


class FrictionTable:
    """The model of one axis tabulated over ``[t_min, t_max]`` °C at ``step`` °C.

    Parameters
    ----------
    params : AxisParams
        Model parameters of the axis.
    t_min, t_max : float
        Temperature range of the table, [°C]. Outside it the temperature is clamped to the edge. The grid starts
        up to a step below ``t_min`` so that a node sits on the loose-fit temperature, where the contact torques
        have a kink.
    step : float
        Grid step, [°C].

    Raises
    ------
    ModelDomainError
        A bad range or step, or parameters for which the model cannot be evaluated over the range (the table is
        built here, so a model that breaks is refused before it is used).
    """

    def __init__(self, params: AxisParams, t_min: float = -60.0, t_max: float = 120.0, step: float = 0.1) -> None:
        if not (math.isfinite(t_min) and math.isfinite(t_max) and t_max > t_min):
            raise ModelDomainError('table range must be finite with t_max > t_min')
        if not (math.isfinite(step) and step > 0.0):
            raise ModelDomainError('table step must be > 0 degC')
        # the contact torques have a kink at the loose-fit temperature (docs/model.md §3): put a grid node on it, so
        # linear interpolation stays exact to the grid's error there too (the grid starts up to a step lower)
        t0 = float(t_min)
        kink = loose_fit_temperature(params)
        if t_min < kink < t_max:
            t0 = kink - step * math.ceil((kink - t_min) / step - 1e-9)
        n = int(math.ceil((t_max - t0) / step - 1e-9)) + 1
        if n > 1_000_000:
            raise ModelDomainError(f'table of {n} points is too large; use a coarser step')
        self.params = params
        self.t_min = float(t_min)
        self.t_max = float(t_max)
        self.step = float(step)
        self.n = max(n, 2)
        self.t0 = t0      #: temperature of the first grid node [°C] (≤ t_min)
        self.grid: FloatArray = self.t0 + self.step * np.arange(self.n, dtype=np.float64)
        # (the nodes beyond [t_min, t_max] are interpolation partners only; at the model's own limits they are
        # evaluated at the limit)
        # (a model that overflows is refused below by its result, not by a RuntimeWarning)
        with np.errstate(over='ignore', invalid='ignore'):
            contact = friction_torque(params, np.clip(self.grid, MODEL_T_MIN_C, MODEL_T_MAX_C), 0.0)
        # a lubricant cannot have a negative viscosity (Walther constants fitted elsewhere, a typo); Palmgren's
        # (nu n)^(2/3) would turn it into a positive torque without a word
        thin = np.flatnonzero(~(contact.viscosity_cst > 0.0))
        if thin.size:
            k = int(thin[0])
            raise ModelDomainError(f'the lubricant viscosity from walther_a, walther_b and viscosity_offset_cst is '
                                   f'{float(contact.viscosity_cst[k]):.3g} cSt at {float(self.grid[k]):g} degC; it '
                                   f'must be > 0 over the table [{self.t_min:g}, {self.t_max:g}] degC')
        m_rs = contact.m_rolling_nmm + contact.m_sliding_nmm
        self._m_rs = {ARRAY: m_rs, SCALAR: m_rs.tolist()}
        # the viscous part must be finite over the whole range too (e.g. a Walther constant gone wrong)
        with np.errstate(over='ignore', invalid='ignore'):
            check = self.magnitude_nm(self.grid, np.full(self.n, 1.0, dtype=np.float64), ARRAY)
        if not np.all(np.isfinite(check)) or np.any(check < 0.0):
            raise ModelDomainError('the model gives a non-finite or negative torque in '
                                   f'[{self.t_min:g}, {self.t_max:g}] degC; check the parameters')

    def magnitude_nm(self, t_c: X, omega_rad_s: X, xp: Namespace[X]) -> X:
        """Friction torque magnitude of the axis [N·m] at temperature ``t_c`` [°C] (clamped to the table) and
        angular velocity ``omega_rad_s`` [rad/s] (magnitude used): interpolated M_R + M_S, exact M_L (Eq. 9)."""
        return self.magnitude_from_terms(self.temperature_terms(t_c, xp), omega_rad_s, xp)

    def temperature_terms(self, t_c: X, xp: Namespace[X]) -> TemperatureTerms[X]:
        """The parts of :meth:`magnitude_nm` that depend on temperature only (a caller whose temperature changes
        slowly, like a simulation over many runs, computes them once per temperature)."""
        p = self.params
        t = xp.clip(t_c, self.t_min, self.t_max)
        m_rs = interp_uniform(self._m_rs[xp], t, self.t0, self.step, self.n, xp)
        nu = nu_Walther(t + p.kelvin_offset_k, p.walther_a, p.walther_b, p.viscosity_offset_cst, p.viscosity_model,
                        xp)
        d_m = thermal_expansion_Eq11(p.pitch_diameter_mm, p.steel_cte_per_c, t - p.reference_temperature_c, xp)
        coefficient = p.bearings_per_axis * palmgren_coefficient(p.palmgren_factor, d_m)
        return TemperatureTerms(m_rs, nu, d_m, coefficient, m_rs * NM_PER_NMM, coefficient * NM_PER_NMM,
                                nu * RPM_PER_RAD_S)

    def magnitude_from_terms(self, terms: TemperatureTerms[X], omega_rad_s: X, xp: Namespace[X]) -> X:
        """:meth:`magnitude_nm` from :meth:`temperature_terms` and the angular velocity [rad/s], [N·m]
        (:func:`magnitude_from_terms`)."""
        return magnitude_from_terms(terms, omega_rad_s, xp)

    def viscosity_cst(self, t_c: float) -> float:
        """Kinematic viscosity of the lubricant at ``t_c`` [°C] (Eq. 20/21, exact), [mm²/s]."""
        p = self.params
        return float(nu_Walther(t_c + p.kelvin_offset_k, p.walther_a, p.walther_b, p.viscosity_offset_cst,
                                p.viscosity_model, SCALAR))

    def in_range(self, t_c: float) -> bool:
        """``t_c`` [°C] lies inside the table."""
        return self.t_min <= t_c <= self.t_max

    # ------------------------------------------------------------------ conveniences in the paper's units
    def torque_nmm(self, t_c: float, speed_rpm: float) -> float:
        """Friction torque magnitude of the axis at ``t_c`` [°C] and ``speed_rpm`` [rpm], [N·mm]."""
        return float(self.magnitude_nm(t_c, speed_rpm * RAD_S_PER_RPM, SCALAR)) * NMM_PER_NM

    def torque_nm(self, t_c: float, omega_rad_s: float) -> float:
        """Friction torque magnitude of the axis at ``t_c`` [°C] and ``omega_rad_s`` [rad/s], [N·m]."""
        return float(self.magnitude_nm(t_c, omega_rad_s, SCALAR))

    def evaluate(self, t_c: ArrayLike, speed_rpm: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                        NDArray[np.float64]]:
        """Arrays of (M_R + M_S, M_L, M) of the axis [N·mm] at temperatures [°C] and speeds [rpm]."""
        t = np.clip(np.asarray(t_c, dtype=float), self.t_min, self.t_max)
        n = np.asarray(speed_rpm, dtype=float)
        total = self.magnitude_nm(t, n * RAD_S_PER_RPM, ARRAY) * NMM_PER_NM
        m_rs = interp_uniform(self._m_rs[ARRAY], t, self.t0, self.step, self.n, ARRAY)
        return m_rs, total - m_rs, total
