"""Hertz point contact of a ball on a raceway (Harris & Kotzalas), as needed by Eqs. (1), (6) and (17).

All functions accept numpy arrays and broadcast. Lengths in [mm], forces in [N], moduli in [MPa].

Worked example (docs/model.md §4): the Table-1 ball at α = 15° and Q = 5 N, outer contact:

>>> c = hertz_contact(5.0, 2.381, 21.5, 15.0 * 3.141592653589793 / 180, 0.54, 114285.714, outer=True)
>>> round(float(c.a) * 1000, 1), round(float(c.b) * 1000, 1), round(float(c.kappa), 2)
(111.5, 21.9, 5.1)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ellipe, ellipk

Array = NDArray[np.float64]


def reduced_modulus(E1: float, nu1: float, E2: float, nu2: float) -> float:
    """Hertz reduced modulus ``E* = [(1 − ν1²)/E1 + (1 − ν2²)/E2]⁻¹``, [MPa]."""
    return 1.0 / ((1.0 - nu1**2) / E1 + (1.0 - nu2**2) / E2)


def curvature_sum_Harris(D_w: ArrayLike, d_m: ArrayLike, alpha: ArrayLike, f: float, *,
                         outer: bool) -> tuple[Array, Array]:
    """Curvature sum Σρ [1/mm] and curvature difference F(ρ) [-] of a ball–raceway contact (Harris).

    Parameters
    ----------
    D_w : array_like
        Ball diameter, [mm].
    d_m : array_like
        Pitch diameter, [mm].
    alpha : array_like
        Contact angle, [rad].
    f : float
        Groove curvature ratio r/D_w of the raceway, [-].
    outer : bool
        True for the outer-raceway contact, False for the inner.
    """
    D = np.asarray(D_w, dtype=float)
    gamma = D * np.cos(alpha) / np.asarray(d_m, dtype=float)
    rho_I = 2.0 / D
    if outer:
        rho_II1 = -(2.0 / D) * gamma / (1.0 + gamma)
    else:
        rho_II1 = (2.0 / D) * gamma / (1.0 - gamma)
    rho_II2 = -1.0 / (f * D)
    sum_rho = 2.0 * rho_I + rho_II1 + rho_II2
    F_rho = (rho_II1 - rho_II2) / sum_rho
    return sum_rho, F_rho


def _F_of_kappa(kappa: Array) -> Array:
    m = 1.0 - 1.0 / kappa**2
    E = ellipe(m)
    return ((kappa**2 + 1.0) * E - 2.0 * ellipk(m)) / ((kappa**2 - 1.0) * E)


def ellipticity_Harris(F_rho: ArrayLike) -> Array:
    """Ellipticity κ = a/b solving ``F(ρ) = [(κ²+1)E(e) − 2K(e)] / [(κ²−1)E(e)]``, ``e² = 1 − 1/κ²``.

    Vectorised bisection in ln κ over (1, 10⁴) to machine precision; F(ρ) in [0, 1).

    >>> round(float(ellipticity_Harris(0.9)), 4)
    6.7133
    """
    F = np.atleast_1d(np.asarray(F_rho, dtype=float))
    lo = np.full(F.shape, 1e-9)
    hi = np.full(F.shape, np.log(1e4))
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        above = _F_of_kappa(np.exp(mid)) > F
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    kappa = np.exp(0.5 * (lo + hi))
    kappa = np.where(F <= 0.0, 1.0, kappa)
    return kappa.reshape(np.shape(F_rho))


class HertzContact(NamedTuple):
    """Hertz contact ellipse of one ball–raceway contact (arrays broadcast like the inputs)."""

    a: Array          #: semi-major axis, across the groove [mm]
    b: Array          #: semi-minor axis, rolling direction [mm]
    kappa: Array      #: ellipticity a/b [-]
    E: Array          #: complete elliptic integral of the second kind E(e) = L_E [-]
    K: Array          #: complete elliptic integral of the first kind K(e) [-]
    delta: Array      #: normal approach of ball and raceway [mm]
    sum_rho: Array    #: curvature sum [1/mm]
    p_max: Array      #: maximum Hertz pressure [MPa]


def hertz_contact(Q: ArrayLike, D_w: ArrayLike, d_m: ArrayLike, alpha: ArrayLike, f: float, E_star: float, *,
                  outer: bool) -> HertzContact:
    """Hertz contact of a ball loaded with Q on a raceway (Harris & Kotzalas), docs/model.md §4.

    Parameters
    ----------
    Q : array_like
        Ball–raceway normal load Q_n, [N].
    D_w, d_m : array_like
        Ball and pitch diameter, [mm].
    alpha : array_like
        Contact angle, [rad].
    f : float
        Groove curvature ratio, [-].
    E_star : float
        Reduced modulus E*, [MPa].
    outer : bool
        Outer (True) or inner (False) raceway.

    Returns
    -------
    HertzContact
        ``a = [3κ²E Q/(πΣρE*)]^(1/3)``, ``b = [3E Q/(πκΣρE*)]^(1/3)``,
        ``δ = (2K/π)[π/(2κ²E)]^(1/3)[3Q/(2ΣρE*)]^(2/3) Σρ/2``, ``p_max = 3Q/(2πab)``.
    """
    sum_rho, F_rho = curvature_sum_Harris(D_w, d_m, alpha, f, outer=outer)
    kappa = ellipticity_Harris(F_rho)
    m = 1.0 - 1.0 / kappa**2
    E = ellipe(m)
    K = ellipk(m)
    Qa = np.maximum(np.asarray(Q, dtype=float), 0.0)
    a = np.cbrt(3.0 * kappa**2 * E * Qa / (np.pi * sum_rho * E_star))
    b = np.cbrt(3.0 * E * Qa / (np.pi * kappa * sum_rho * E_star))
    delta = (2.0 * K / np.pi) * np.cbrt(np.pi / (2.0 * kappa**2 * E)) \
        * np.cbrt(3.0 * Qa / (2.0 * sum_rho * E_star))**2 * sum_rho / 2.0
    with np.errstate(divide='ignore', invalid='ignore'):
        p_max = np.where(a * b > 0.0, 3.0 * Qa / (2.0 * np.pi * a * b), 0.0)
    return HertzContact(a, b, kappa, E, K, delta, sum_rho, p_max)


def load_deflection_constant(D_w: ArrayLike, d_m: ArrayLike, alpha: ArrayLike, f_i: float, f_o: float,
                             E_star: float) -> Array:
    """Ball load–deflection constant K_n of the ball with both contacts, ``Q = K_n δ_n^1.5``, [N/mm^1.5].

    ``K_n = [K_i^(−2/3) + K_o^(−2/3)]^(−3/2)`` with each ``K_j = Q/δ_j^1.5`` (independent of Q).

    >>> round(float(load_deflection_constant(2.381, 21.5, 0.2617993877991494, 0.56, 0.54, 114285.714)), -2)
    120200.0
    """
    q_ref = 1.0
    ci = hertz_contact(q_ref, D_w, d_m, alpha, f_i, E_star, outer=False)
    co = hertz_contact(q_ref, D_w, d_m, alpha, f_o, E_star, outer=True)
    return q_ref / (ci.delta + co.delta) ** 1.5
