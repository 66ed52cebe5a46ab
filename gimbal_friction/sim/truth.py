"""The truth friction of the simulated axis: the physics model plus what the model does not know.

Sliding (Coulomb) level of the truth at bearing temperature t, relative velocity v and joint angle θ::

    F_C(t, v, θ) = k_dir(t, sgn v) · M_truth(t, |v|) · (1 + r(θ, t))

- ``M_truth`` is the suite's physics model (Yu & Shang 2017, Eq. 10: M_R + M_S from the tabulated contact
  model, M_L from Palmgren's Eq. 9 evaluated exactly at |v|) of the *truth* axis parameters: the configured
  :class:`~gimbal_friction.core.params.AxisParams` with ``walther_a`` shifted by ``lubricant_walther_a_shift``
  (a lubricant that differs from the configuration). The configured ``scale_positive``/``scale_negative`` are
  the *user's* direction factors and play no part in the truth.
- ``k_dir`` are the direction factors of :func:`direction_factors`: the paper's measured means (CW 3.19 vs
  CCW −2.45 N·mm at −40 °C, 1.05 vs −1.34 N·mm at +60 °C, Sec. 6) divided by the *configured* model at the
  paper's speed (``AxisParams.speed_rpm``, 1/3 rpm), interpolated linearly in temperature between the anchors
  and held beyond them. With no lubricant shift the truth's means at 1/3 rpm are therefore exactly the paper's
  four measured means; with the default shift (+0.015, the synthetic chamber bag's truth) the cold end is more
  viscous (CW ≈ 3.97 N·mm at −40 °C, like the sample bag's measured 3.83).
- ``r`` is the position ripple of :func:`ripple`: a sum of sines in the joint angle, amplified in the cold.

The LuGre model (:mod:`gimbal_friction.sim.lugre`) makes it dynamic: Stribeck level
``g(v) = F_C + (F_S − F_C) e^{−(v/v_s)²}`` with ``F_S = breakaway_ratio · F_C`` (the breakaway torque relative to
the sliding level at the same low speed, i.e. to M(t, 0) of the lower Palmgren branch), plus the motor's
no-load torque ``T_0 = K_T I_0`` as a Coulomb term (the torque motor ``τ = K_T (i − sgn(ω) I_0)`` of the issue,
with the sign smoothed by the bristle dynamics). At constant velocity the torque settles at
:meth:`TruthFriction.static_torque_nm`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.core.friction import viscous_torque_Palmgren_1959
from gimbal_friction.core.model import friction_torque, viscosity_cst
from gimbal_friction.core.params import AxisParams
from gimbal_friction.core.table import FrictionTable
from gimbal_friction.core.thermal import radial_coupling
from gimbal_friction.core.units import NM_PER_NMM, RPM_PER_RAD_S
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.lugre import lugre_g_1995, stribeck_curve_LuGre_1995

Array = NDArray[np.float64]

__all__ = ['DirectionFactors', 'ModelMagnitude', 'TemperatureTerms', 'TruthFriction', 'TruthTerms', 'cold_weight',
           'direction_factors', 'ripple', 'truth_params']

#: Temperatures where the ripple's cold amplification is full (−40 °C) and zero (+20 °C and above) [°C].
RIPPLE_COLD_C = -40.0
RIPPLE_WARM_C = 20.0


def truth_params(axis: AxisParams, config: SimConfig) -> AxisParams:
    """Truth model parameters: ``axis`` with ``walther_a`` shifted by ``config.lubricant_walther_a_shift``."""
    return axis.replace(walther_a=axis.walther_a + config.lubricant_walther_a_shift)


class TemperatureTerms(NamedTuple):
    """Temperature-dependent terms of the model magnitude, per run (recomputed when the temperature moves)."""

    temperature_c: Array   #: temperatures they were computed at (clamped to the table) [°C]
    m_contact_nm: Array    #: M_R + M_S of the axis [N·m]
    viscosity_cst: Array   #: kinematic viscosity ν [mm²/s]
    pitch_mm: Array        #: thermally scaled pitch diameter d_m [mm]


class ModelMagnitude:
    """The model magnitude M(t, |v|) of one parameter set, fast over arrays of runs.

    The temperature-dependent terms (contact torques from :class:`~gimbal_friction.core.table.FrictionTable`,
    viscosity, pitch diameter) are computed by :meth:`terms` when the temperature changes; the speed-dependent
    Palmgren torque (Eq. 9) is evaluated exactly at every call of :meth:`magnitude_nm` (about 8 µs for 30 runs).

    >>> mm = ModelMagnitude(AxisParams())
    >>> terms = mm.terms(np.array([-40.0, 20.0]))
    >>> [round(float(x) * 1e3, 3) for x in mm.magnitude_nm(terms, np.full(2, 2.0 * math.pi / 180.0))]
    [3.143, 1.046]
    """

    def __init__(self, params: AxisParams, t_min: float = -60.0, t_max: float = 120.0, step: float = 0.1) -> None:
        self.params = params
        self.table = FrictionTable(params, t_min, t_max, step)
        self._bearings = float(params.bearings_per_axis)

    def terms(self, t_c: ArrayLike) -> TemperatureTerms:
        """Temperature-dependent terms at ``t_c`` [°C] (clamped to the table range like the table)."""
        t = np.clip(np.asarray(t_c, dtype=float), self.table.t_min, self.table.t_max)
        m_rs_nmm, _, _ = self.table.evaluate(t, np.zeros(t.shape))
        return TemperatureTerms(t, NM_PER_NMM * m_rs_nmm, viscosity_cst(self.params, t),
                                np.asarray(radial_coupling(self.params, t).d_m, dtype=float))

    def magnitude_nm(self, terms: TemperatureTerms, speed_rad_s: ArrayLike) -> Array:
        """M(t, |v|) of the axis [N·m] at the temperatures of ``terms`` and speeds ``speed_rad_s`` [rad/s]."""
        n_rpm = np.abs(np.asarray(speed_rad_s, dtype=float)) * RPM_PER_RAD_S
        m_l = viscous_torque_Palmgren_1959(self.params.palmgren_factor, terms.viscosity_cst, n_rpm, terms.pitch_mm)
        return terms.m_contact_nm + NM_PER_NMM * self._bearings * m_l


class DirectionFactors(NamedTuple):
    """Truth direction factors at the anchor temperatures (measured mean / configured model)."""

    temperatures_c: Array   #: anchor temperatures [°C]
    positive: Array         #: k_+ at the anchors [-]
    negative: Array         #: k_- at the anchors [-]

    def at(self, t_c: ArrayLike) -> tuple[Array, Array]:
        """(k_+, k_-) at temperatures ``t_c`` [°C]: linear between the anchors, held beyond them."""
        t = np.asarray(t_c, dtype=float)
        return (np.interp(t, self.temperatures_c, self.positive),
                np.interp(t, self.temperatures_c, self.negative))


def direction_factors(axis: AxisParams, config: SimConfig) -> DirectionFactors:
    """Direction factors k_± that make the truth reproduce the measured CW/CCW means relative to the model.

    ``k_+(t_i) = cw_i / M(t_i, n)``, ``k_-(t_i) = ccw_i / M(t_i, n)`` at the anchor temperatures ``t_i``
    (``asymmetry_temperatures_c``) with ``M`` the configured physics model (scale factors not applied) at the
    paper's speed ``n = axis.speed_rpm``. Factors of 1 when ``asymmetry_enabled`` is false.

    With the paper's means and the default model (M = 3.143 N·mm at −40 °C, 1.084 at +60 °C):

    >>> k = direction_factors(AxisParams(), SimConfig())
    >>> [round(float(x), 3) for x in k.positive], [round(float(x), 3) for x in k.negative]
    ([1.015, 0.969], [0.779, 1.236])
    """
    temps = np.asarray(config.asymmetry_temperatures_c, dtype=float)
    if not config.asymmetry_enabled:
        ones = np.ones(temps.shape)
        return DirectionFactors(temps, ones, ones.copy())
    m_nmm = np.atleast_1d(friction_torque(axis, temps, axis.speed_rpm).m_total_nmm)
    return DirectionFactors(temps, np.asarray(config.asymmetry_cw_nmm) / m_nmm,
                            np.asarray(config.asymmetry_ccw_nmm) / m_nmm)


def cold_weight(t_c: ArrayLike) -> Array:
    """Cold weight of the ripple: 1 at −40 °C and below, 0 at +20 °C and above, linear between [-]."""
    t = np.asarray(t_c, dtype=float)
    return np.asarray(np.clip((RIPPLE_WARM_C - t) / (RIPPLE_WARM_C - RIPPLE_COLD_C), 0.0, 1.0))


def ripple(config: SimConfig, theta_rad: ArrayLike, t_c: ArrayLike) -> Array:
    """Position ripple r(θ, t) = (1 + gain · w(t)) Σ a_k sin(2π θ / p_k + φ_k), a fraction of the friction [-].

    >>> c = SimConfig(ripple_amplitudes=(0.1,), ripple_periods_deg=(4.0,), ripple_phases_rad=(0.0,))
    >>> [round(float(x), 6) for x in ripple(c, np.radians([1.0, 1.0]), [20.0, -40.0])]
    [0.1, 0.2]
    """
    theta_deg = np.degrees(np.asarray(theta_rad, dtype=float))
    out = np.zeros(np.broadcast_shapes(theta_deg.shape, np.shape(t_c)))
    for a, p, phi in zip(config.ripple_amplitudes, config.ripple_periods_deg, config.ripple_phases_rad, strict=True):
        out = out + a * np.sin(2.0 * math.pi * theta_deg / p + phi)
    return np.asarray(out * (1.0 + config.ripple_cold_gain * cold_weight(t_c)))


class TruthTerms(NamedTuple):
    """Everything of the truth that depends on temperature only, per run."""

    model: TemperatureTerms
    k_positive: Array   #: [-]
    k_negative: Array   #: [-]


class TruthFriction:
    """The truth friction of the axis (see the module notes), vectorised over runs.

    Parameters
    ----------
    axis : AxisParams
        The configured model parameters (the suite's configuration).
    config : SimConfig
        Simulator configuration (lubricant shift, LuGre, ripple, asymmetry).
    """

    def __init__(self, axis: AxisParams, config: SimConfig) -> None:
        self.config = config
        self.params = truth_params(axis, config)
        self.model = ModelMagnitude(self.params)
        self.factors = direction_factors(axis, config)
        self.no_load_torque_nm = axis.torque_constant_nm_per_a * axis.no_load_current_a
        self.sigma0 = config.sigma0_nm_per_rad
        self.sigma1 = config.sigma1_nm_s_per_rad
        self.v_s = config.stribeck_velocity_rad_s
        self.beta = config.breakaway_ratio

    def terms(self, t_c: ArrayLike) -> TruthTerms:
        """Temperature-dependent terms at bearing temperatures ``t_c`` [°C]."""
        t = np.asarray(t_c, dtype=float)
        k_pos, k_neg = self.factors.at(t)
        return TruthTerms(self.model.terms(t), k_pos, k_neg)

    def coulomb_nm(self, terms: TruthTerms, v: Array, ripple_factor: Array | float = 1.0) -> Array:
        """Sliding level F_C = k_dir M(t, |v|) (1 + r) [N·m] (``ripple_factor`` = 1 + r)."""
        k = np.where(v >= 0.0, terms.k_positive, terms.k_negative)
        return np.asarray(k * self.model.magnitude_nm(terms.model, v) * ripple_factor)

    def stribeck_level_nm(self, terms: TruthTerms, v: Array, ripple_factor: Array | float = 1.0) -> Array:
        """LuGre level g(v) = F_C + (β F_C − F_C) e^{−(v/v_s)²} + T_0 [N·m] (> 0)."""
        f_c = self.coulomb_nm(terms, v, ripple_factor)
        return lugre_g_1995(v, f_c, self.beta * f_c, self.v_s) + abs(self.no_load_torque_nm)

    def static_torque_nm(self, t_c: ArrayLike, v: ArrayLike, theta_rad: ArrayLike = 0.0) -> Array:
        """Steady-state truth friction at constant velocity ``v`` [rad/s]: the LuGre static Stribeck curve, [N·m].

        ``F_ss = stribeck_curve_LuGre_1995(v, F_C, β F_C, v_s) + T_0 sgn v`` with the ripple at ``theta_rad``.
        """
        v = np.asarray(v, dtype=float)
        t = np.broadcast_to(np.asarray(t_c, dtype=float), v.shape)
        terms = self.terms(t)
        f_c = self.coulomb_nm(terms, v, 1.0 + ripple(self.config, theta_rad, t))
        return np.asarray(stribeck_curve_LuGre_1995(v, f_c, self.beta * f_c, self.v_s) +
                          abs(self.no_load_torque_nm) * np.sign(v))
