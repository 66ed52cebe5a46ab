"""The whole friction-torque model of one gimbal axis versus temperature and speed (docs/model.md §8).

>>> r = friction_torque(AxisParams(), -40.0)
>>> round(float(r.m_viscous_nmm), 2), round(float(r.m_sliding_nmm + r.m_rolling_nmm), 2)
(2.3, 0.84)
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.physics.friction import (
    PALMGREN_THRESHOLD_CST_RPM,
    contact_radius_Harris,
    hysteresis_torque_Eq3,
    spin_torque_axial_Eq8,
    spin_torque_contact_Eq6,
    total_torque_Eq10,
    viscous_torque_Palmgren_1959,
)
from gimbal_friction.physics.hertz import hertz_contact, reduced_modulus
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, AxisParams
from gimbal_friction.physics.thermal import (
    AxialState,
    RadialState,
    axial_coupling,
    axial_coupling_direct,
    radial_coupling,
)
from gimbal_friction.physics.viscosity import nu_Walther

Array = NDArray[np.float64]

#: Output fields of ``gimbal-friction model --format json`` (docs/ros.md), in order.
CONTRACT_FIELDS = ('temperature_c', 'viscosity_cst', 'free_contact_angle_deg', 'contact_angle_deg',
                   'radial_clearance_mm', 'axial_force_n', 'ball_load_n', 'm_rolling_nmm', 'm_sliding_nmm',
                   'm_viscous_nmm', 'm_total_nmm')


class FrictionResult(NamedTuple):
    """Model state and friction torque of the whole axis at each temperature.

    Torques are for the whole axis (``bearings_per_axis`` × per-bearing) in [N·mm], as the paper reports;
    loads and angles are per bearing.
    """

    temperature_c: Array           #: [°C]
    speed_rpm: Array               #: [rpm]
    viscosity_cst: Array           #: kinematic viscosity ν [mm²/s]
    free_contact_angle_deg: Array  #: α° after radial coupling [deg]
    contact_angle_deg: Array       #: loaded contact angle α [deg]
    radial_clearance_mm: Array     #: P_d2 [mm]
    fit_pressure_mpa: Array        #: outer-ring fit pressure p [MPa]
    loose_fit: NDArray[np.bool_]   #: outer ring loose in the housing
    axial_force_n: Array           #: axial preload per bearing F_a [N]
    ball_load_n: Array             #: ball normal load Q [N]
    m_rolling_nmm: Array           #: hysteresis rolling torque M_R, axis [N·mm]
    m_sliding_nmm: Array           #: spin sliding torque M_S (axial component), axis [N·mm]
    m_viscous_nmm: Array           #: Palmgren viscous torque M_L, axis [N·mm]
    m_total_nmm: Array             #: M = M_R + M_S + M_L, axis [N·mm]

    def records(self) -> list[dict[str, Any]]:
        """One dict per temperature with the contract fields (plain floats), for JSON/CSV output."""
        cols = {name: np.atleast_1d(getattr(self, name)) for name in CONTRACT_FIELDS}
        n = len(cols['temperature_c'])
        return [{name: float(cols[name][i]) for name in CONTRACT_FIELDS} for i in range(n)]


def contact_torques(p: AxisParams, r: RadialState, ax: AxialState) -> tuple[Array, Array]:
    """Per-bearing M_R (Eqs. 1–3) and M_S (Eqs. 5–8) from the loaded state, [N·mm] (docs/model.md §8 steps 7–9)."""
    E_star = reduced_modulus(p.steel_youngs_modulus_mpa, p.steel_poisson_ratio, p.steel_youngs_modulus_mpa,
                             p.steel_poisson_ratio)
    ci = hertz_contact(ax.Q, r.D_w2, r.d_m, ax.alpha, p.inner_groove_curvature, E_star, outer=False)
    co = hertz_contact(ax.Q, r.D_w2, r.d_m, ax.alpha, p.outer_groove_curvature, E_star, outer=True)
    if p.hysteresis_radius == 'harris':
        R_i = contact_radius_Harris(p.inner_groove_curvature, r.D_w2)
        R_o = contact_radius_Harris(p.outer_groove_curvature, r.D_w2)
    else:
        R_i = R_o = 0.5 * r.D_w2
    M_R = hysteresis_torque_Eq3(p.ball_count, p.hysteresis_loss_fraction, ax.Q, ci.b, co.b, R_i, R_o, r.d_m,
                                r.D_w2, ax.alpha)
    mu = p.sliding_friction_coefficient
    M_S = spin_torque_axial_Eq8(p.ball_count, spin_torque_contact_Eq6(mu, ax.Q, ci.a, ci.E),
                                spin_torque_contact_Eq6(mu, ax.Q, co.a, co.E), ax.alpha)
    return M_R, M_S


def viscosity_cst(p: AxisParams, t_c: ArrayLike) -> Array:
    """Kinematic viscosity of the configured lubricant at ``t_c`` [°C], Eq. (20)/(21), [mm²/s]."""
    return nu_Walther(np.asarray(t_c, dtype=float) + p.kelvin_offset_k, p.walther_a, p.walther_b,
                      p.viscosity_offset_cst, p.viscosity_model)


def palmgren_threshold_temperature(p: AxisParams, speed_rpm: float) -> float:
    """Temperature [°C] below which ν·n ≥ 2000 at ``speed_rpm`` [rpm] (Palmgren's upper branch of Eq. 9; inverse
    Walther, Eq. 20/21); NaN if none. The one home of the ν·n ≥ 2000 temperature rule.

    >>> round(palmgren_threshold_temperature(AxisParams(), 1 / 3), 1)
    -27.1
    """
    nu = PALMGREN_THRESHOLD_CST_RPM / speed_rpm
    try:
        x = (math.log10(math.log10(nu + p.viscosity_offset_cst)) - p.walther_a) / p.walther_b
        T = 10.0**x if p.viscosity_model == 'walther' else 10.0 ** (10.0**x)
    except (ValueError, OverflowError, ZeroDivisionError):
        return math.nan
    return float(T) - p.kelvin_offset_k


def _check_temperatures(t: Array) -> None:
    if not np.all(np.isfinite(t)):
        raise ModelDomainError('temperatures must be finite')
    if np.any(t < MODEL_T_MIN_C) or np.any(t > MODEL_T_MAX_C):
        raise ModelDomainError(f'temperatures must lie in [{MODEL_T_MIN_C:g}, {MODEL_T_MAX_C:g}] degC for this model')


def friction_torque(p: AxisParams, t_c: ArrayLike, speed_rpm: ArrayLike | None = None, *,
                    direct: bool = False) -> FrictionResult:
    """Friction torque of the axis and its components at temperatures ``t_c``, Eqs. (1)–(22), docs/model.md §8.

    Parameters
    ----------
    p : AxisParams
        Model parameters.
    t_c : array_like
        Bearing temperatures, [°C].
    speed_rpm : array_like, optional
        Shaft speed, [rpm] (magnitude used); default ``p.speed_rpm`` (the paper's 1/3 rpm).
    direct : bool
        Use the scalar reference solve (brentq with K_n(α) recomputed at every step) per temperature instead of
        the vectorised solver. Slow; for checks.

    Returns
    -------
    FrictionResult
        Arrays shaped like ``t_c`` (after broadcasting with ``speed_rpm``).

    Raises
    ------
    ModelDomainError
        Non-finite temperature or speed, or a state the model cannot represent.
    """
    t = np.asarray(t_c, dtype=float)
    n = np.asarray(p.speed_rpm if speed_rpm is None else speed_rpm, dtype=float)
    _check_temperatures(t)
    if not np.all(np.isfinite(n)):
        raise ModelDomainError('speed must be finite')
    t, n = np.broadcast_arrays(t, n)
    if direct:
        flat = [axial_coupling_direct(p, float(ti)) for ti in t.ravel()]
        r = RadialState(*(np.array([float(getattr(s[0], f)) for s in flat]).reshape(t.shape)
                          for f in RadialState._fields))
        ax = AxialState(*(np.array([float(getattr(s[1], f)) for s in flat]).reshape(t.shape)
                          for f in AxialState._fields))
        r = r._replace(loose=r.loose.astype(bool))
        ax = ax._replace(gap=ax.gap.astype(bool))
    else:
        r = radial_coupling(p, t)
        ax = axial_coupling(p, r)
    M_R, M_S = contact_torques(p, r, ax)
    nu = viscosity_cst(p, t)
    M_L = viscous_torque_Palmgren_1959(p.palmgren_factor, nu, n, r.d_m)
    k = float(p.bearings_per_axis)
    M_R, M_S, M_L = k * M_R, k * M_S, k * M_L
    result = FrictionResult(t.copy(), n.copy(), nu, np.degrees(r.alpha0), np.degrees(ax.alpha), r.P_d,
                            r.fit_pressure, r.loose, ax.F_a, ax.Q, M_R, M_S, M_L, total_torque_Eq10(M_R, M_S, M_L))
    bad = [name for name in ('m_total_nmm', 'viscosity_cst', 'contact_angle_deg')
           if not np.all(np.isfinite(getattr(result, name)))]
    if bad:
        msg = f'model produced non-finite {", ".join(bad)}; check the parameters'
        raise ModelDomainError(msg)
    return result

