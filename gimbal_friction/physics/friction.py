"""Bearing friction torque components of Yu & Shang (2017), Sec. 3: Eqs. (1)–(10).

Per-bearing torques in [N·mm] (the paper's unit); lengths [mm], loads [N], pressures [MPa]. Functions broadcast
over numpy arrays.
"""

from __future__ import annotations

from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import dblquad

from gimbal_friction.common.xp import ARRAY, SCALAR, FloatArray, FloatOrArray, Namespace, X

#: Palmgren's branch threshold ν·n of Eq. (9), [cSt·rpm]: above it M_L grows as (ν n)^(2/3), below it is constant
PALMGREN_THRESHOLD_CST_RPM = 2000.0

Array = NDArray[np.float64]


def hysteresis_force_Jiang(alpha_r: float, Q: ArrayLike, b: ArrayLike, R: float) -> Array:
    """Elastic-hysteresis rolling resistance of one ball–raceway contact, Eq. (1) (Jiang et al. 2010).

    ``F_RSE = (3/16) α_r Q_n b / R``

    Parameters
    ----------
    alpha_r : float
        Fraction of elastic energy lost by hysteresis, [-] (≤ 1 % for metals).
    Q : array_like
        Ball–raceway normal load, [N].
    b : array_like
        Semi-minor axis of the contact ellipse (rolling direction), [mm].
    R : float
        Radius of the curved Hertzian contact, [mm].

    Returns
    -------
    F : ndarray
        Rolling resistance force, [N].

    >>> round(float(hysteresis_force_Jiang(0.007, 16.6, 0.0327, 1.2363)), 6)
    0.000576
    """
    return 3.0 / 16.0 * alpha_r * np.asarray(Q, dtype=float) * np.asarray(b, dtype=float) / R


def contact_radius_Harris(f: float, D_w: ArrayLike) -> Array:
    """Radius of the deformed contact surface ``R = 2 f D_w/(2f + 1)`` used for R in Eq. (1), [mm]."""
    return 2.0 * f * np.asarray(D_w, dtype=float) / (2.0 * f + 1.0)


def hysteresis_torque_Eq3(Z: int, alpha_r: float, Q: ArrayLike, b_i: ArrayLike, b_o: ArrayLike, R_i: ArrayLike,
                          R_o: ArrayLike, d_m: ArrayLike, D_w: ArrayLike, alpha: ArrayLike) -> Array:
    """Hysteresis rolling torque of one bearing, Eqs. (2)–(3): ``M_R = Z (M_EI + M_EO)``, [N·mm].

    ``M_EI = F_SEI (d_m − D_w cos α)/2`` and ``M_EO = F_SEO (d_m + D_w cos α)/2``: each contact force acts on
    its contact-circle radius. Inner and outer contact angles are equal (no centrifugal force at low speed).
    """
    cos_a = np.cos(alpha)
    F_i = 3.0 / 16.0 * alpha_r * np.asarray(Q) * np.asarray(b_i) / np.asarray(R_i)
    F_o = 3.0 / 16.0 * alpha_r * np.asarray(Q) * np.asarray(b_o) / np.asarray(R_o)
    M_EI = F_i * (np.asarray(d_m) - np.asarray(D_w) * cos_a) / 2.0
    M_EO = F_o * (np.asarray(d_m) + np.asarray(D_w) * cos_a) / 2.0
    return Z * (M_EI + M_EO)


def spin_torque_contact_Eq6(mu: float, Q: ArrayLike, a: ArrayLike, L_E: ArrayLike) -> Array:
    """Spin (pivoting) sliding torque at one contact ellipse, Eq. (6) closed form, [N·mm].

    ``M_S,j = ∬ μ p(x,y) √(x²+y²) dx dy = (3/8) μ Q_n a L_E`` with the Hertz pressure of Eq. (5) and
    ``L_E = E(e)`` the complete elliptic integral of the second kind.

    >>> import math
    >>> round(float(spin_torque_contact_Eq6(0.1, 10.0, 0.1, math.pi / 2)), 6)  # circle: (3π/16) μ Q a
    0.058905
    """
    return 3.0 / 8.0 * mu * np.asarray(Q, dtype=float) * np.asarray(a, dtype=float) * np.asarray(L_E, dtype=float)


def spin_torque_contact_numerical(mu: float, Q: float, a: float, b: float) -> float:
    """Eq. (6) by numerical double integration of the Hertz pressure (Eq. 5); a check on the closed form."""
    p0 = 3.0 * Q / (2.0 * np.pi * a * b)

    def integrand(y: float, x: float) -> float:
        s = 1.0 - x * x / (a * a) - y * y / (b * b)
        return mu * p0 * np.sqrt(max(s, 0.0)) * np.hypot(x, y)

    def y_hi(x: float) -> float:
        return b * np.sqrt(max(1.0 - x * x / (a * a), 0.0))

    def y_lo(x: float) -> float:
        return -y_hi(x)

    val, _ = dblquad(integrand, -a, a, y_lo, y_hi, epsabs=1e-15, epsrel=1e-12)
    return float(val)


def spin_torque_axial_Eq8(Z: int, M_SI: ArrayLike, M_SO: ArrayLike, alpha: ArrayLike) -> Array:
    """Spin torque of one bearing about its axis, Eqs. (7)–(8): ``M_S = Z max(M_SI, M_SO) sin α``, [N·mm]."""
    return Z * np.maximum(np.asarray(M_SI), np.asarray(M_SO)) * np.sin(alpha)


@overload
def viscous_torque_Palmgren_1959(s0: float, nu0: ArrayLike, n: ArrayLike, d_m: ArrayLike,
                                 xp: Namespace[FloatArray] = ...) -> FloatArray: ...
@overload
def viscous_torque_Palmgren_1959(s0: float, nu0: float, n: float, d_m: float, xp: Namespace[float]) -> float: ...
def viscous_torque_Palmgren_1959(s0: float, nu0: ArrayLike, n: ArrayLike, d_m: ArrayLike,
                                 xp: Namespace[float] | Namespace[FloatArray] = ARRAY) -> FloatOrArray:
    """Load-independent viscous friction torque of one bearing, Eq. (9) (Palmgren 1959), [N·mm].

    ``M_L = 1e-7 s0 (ν0 n)^(2/3) d_m³`` if ``ν0 n ≥ 2000``, else ``160e-7 s0 d_m³``.

    Parameters
    ----------
    s0 : float
        Palmgren factor f0 for bearing type and lubrication, [-].
    nu0 : array_like
        Kinematic viscosity of the (base) oil at operating temperature, [mm²/s].
    n : array_like
        Speed, [rpm] (its magnitude is used).
    d_m : array_like
        Pitch diameter, [mm].
    xp : namespace
        :data:`~gimbal_friction.common.xp.ARRAY` (default) or :data:`~gimbal_friction.common.xp.SCALAR` (floats).

    Returns
    -------
    M_L : ndarray or float
        Viscous torque of one bearing, [N·mm].

    Notes
    -----
    The branches meet at ν0 n = 2000 within 0.8 % (2000^(2/3) = 158.7). At 1/3 rpm the upper branch applies for
    ν ≥ 6000 cSt only.

    >>> round(float(viscous_torque_Palmgren_1959(1.917, 44702.0, 1/3, 21.5)), 4)
    1.1536
    """
    if xp is ARRAY:
        nu_a, n_a, d_a = (np.asarray(x, dtype=np.float64) for x in (nu0, n, d_m))
        return viscous_torque_from_coefficient(palmgren_coefficient(s0, d_a), nu_a, n_a, ARRAY)
    d_f: float = d_m  # type: ignore[assignment]  # SCALAR: floats (a cast() call would cost on the per-call path)
    nu_f: float = nu0  # type: ignore[assignment]  # SCALAR: a float
    n_f: float = n  # type: ignore[assignment]  # SCALAR: a float
    return viscous_torque_from_coefficient(palmgren_coefficient(s0, d_f), nu_f, n_f, SCALAR)


def palmgren_coefficient(s0: float, d_m: X) -> X:
    """The part of Eq. (9) that does not depend on viscosity or speed: ``1e-7 s0 d_m³``, [N·mm] (``s0`` [-],
    pitch diameter ``d_m`` [mm]; floats or arrays)."""
    return 1e-7 * s0 * (d_m * d_m * d_m)


def viscous_torque_from_coefficient(coefficient_nmm: X, nu0: X, n: X, xp: Namespace[X]) -> X:
    """Eq. (9) from :func:`palmgren_coefficient` [N·mm], the viscosity ``nu0`` [mm²/s] and the speed ``n`` [rpm]
    (magnitude used): ``coefficient · (ν0 n)^(2/3)`` if ``ν0 n ≥ 2000``, else ``coefficient · 160``, [N·mm].

    The split lets a caller whose temperature changes slowly (the feedforward, per controller tick) compute the
    coefficient and the viscosity once per temperature. Only the product ``ν0 n`` must be in cSt·rpm and the result
    has the unit of the coefficient: the tabulated model passes the coefficient in N·m, ``ν0`` × (rpm per rad/s)
    and the speed in rad/s (:func:`~gimbal_friction.physics.table.magnitude_from_terms`)."""
    vn = nu0 * xp.abs(n)
    c = xp.cbrt(vn)  # (c * c is numpy's c ** 2, and cheaper on a float)
    return coefficient_nmm * xp.where(vn >= PALMGREN_THRESHOLD_CST_RPM, c * c, 160.0)


def total_torque_Eq10(M_R: ArrayLike, M_S: ArrayLike, M_L: ArrayLike) -> Array:
    """Total friction torque, Eq. (10): ``M = M_R + M_S + M_L`` (same basis as the inputs), [N·mm]."""
    return np.asarray(M_R) + np.asarray(M_S) + np.asarray(M_L)


def ball_load_Eq4(F_a: ArrayLike, Z: int, alpha: ArrayLike) -> Array:
    """Ball normal load under pure axial preload, Eq. (4): ``Q_n = F_a/(Z sin α)``, [N]."""
    return np.asarray(F_a, dtype=float) / (Z * np.sin(alpha))
