"""Coupled thermal deformation of bearing, housing and frames: Yu & Shang (2017) Sec. 4, Eqs. (11)–(19).

Radial coupling: the steel outer ring sits with interference Δ in the aluminium housing; their different CTEs
change the fit pressure with temperature (Lamé thick-walled cylinders, Eqs. 13–14), which squeezes the outer
raceway and reduces the radial clearance and so the free contact angle (Fig. 5). Axial coupling: the steel and
aluminium members holding the bearing pair expand differently, which changes the axial squeeze and preload
(Eqs. 15–16); Eqs. (17)–(19) then give the loaded contact angle and the ball load.

Lengths in [mm], temperatures in [°C], pressures and moduli in [MPa], forces in [N], angles in [rad].
All functions broadcast over numpy arrays of temperature.
"""

from __future__ import annotations

import math
from typing import NamedTuple, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.common.xp import ARRAY, FloatArray, FloatOrArray, Namespace
from gimbal_friction.physics.hertz import load_deflection_constant, reduced_modulus
from gimbal_friction.physics.params import AxisParams

Array = NDArray[np.float64]
ALPHA_MAX = math.radians(80.0)


@overload
def thermal_expansion_Eq11(D: ArrayLike, phi: float, dT: ArrayLike, xp: Namespace[FloatArray] = ...) -> FloatArray: ...
@overload
def thermal_expansion_Eq11(D: float, phi: float, dT: float, xp: Namespace[float]) -> float: ...
def thermal_expansion_Eq11(D: ArrayLike, phi: float, dT: ArrayLike,
                           xp: Namespace[float] | Namespace[FloatArray] = ARRAY) -> FloatOrArray:
    """Free thermal expansion of a diameter, Eq. (11): ``D_1 = D (1 + φ ΔT)``, [mm].

    ``D`` [mm], ``phi`` [1/°C], ``dT`` [°C]; arrays (``xp`` = ARRAY, default) or floats (``xp`` = SCALAR).

    >>> from gimbal_friction.common.xp import SCALAR
    >>> round(thermal_expansion_Eq11(21.5, 11.7e-6, -60.0, SCALAR), 6)
    21.484907
    """
    if xp is ARRAY:
        return np.asarray(D, dtype=np.float64) * (1.0 + phi * np.asarray(dT, dtype=np.float64))
    d_f: float = D  # type: ignore[assignment]  # SCALAR: floats (a cast() call would cost on the per-call path)
    dt_f: float = dT  # type: ignore[assignment]  # SCALAR: a float
    return d_f * (1.0 + phi * dt_f)


def press_fit_Lame_Eq14(D_m1: ArrayLike, d_O1: ArrayLike, D_I1: ArrayLike, D_L1: ArrayLike, E_S: float,
                        gamma_S: float, E_A: float, gamma_A: float) -> tuple[Array, Array, Array, Array]:
    """Steel ring in an aluminium housing: fit pressure and deformed diameters, Eqs. (13)–(14) (Lamé).

    ``k1 = [(D_m1² + d_O1²)/(D_m1² − d_O1²) − γ_S]/E_S``, ``k2 = [(D_L1² + D_I1²)/(D_L1² − D_I1²) + γ_A]/E_A``,
    ``p = (D_m1 − D_I1)/(D_m1 k1 + D_I1 k2)`` when ``D_m1 > D_I1`` (else 0: loose fit),
    ``d_O2 = d_O1 − 2 p D_m1² d_O1 /(E_S (D_m1² − d_O1²))``.

    Parameters
    ----------
    D_m1, d_O1 : array_like
        Free outside diameter and outer groove diameter of the ring, [mm].
    D_I1, D_L1 : array_like
        Free bore and outside diameter of the housing, [mm].
    E_S, gamma_S, E_A, gamma_A : float
        Young modulus [MPa] and Poisson ratio [-] of steel (ring) and aluminium (housing).

    Returns
    -------
    p, D_2, d_O2, D_L2 : ndarray
        Fit pressure [MPa], common diameter after assembly [mm], deformed outer groove diameter [mm] and housing
        outside diameter [mm].

    Examples
    --------
    In the same-material limit with a thin ring this reduces to Shigley's press fit (see tests). docs/model.md §3
    sanity value, Δ = 0 at −40 °C:

    >>> p, D2, dO2, DL2 = press_fit_Lame_Eq14(25.98175, 23.87233, 25.96615, 79.89584, 208000, 0.3, 70000, 0.33)
    >>> round(float(p), 1), round(float(dO2), 4)
    (7.7, 23.861)
    """
    Dm = np.asarray(D_m1, dtype=float)
    dO = np.asarray(d_O1, dtype=float)
    DI = np.asarray(D_I1, dtype=float)
    DL = np.asarray(D_L1, dtype=float)
    k1 = ((Dm**2 + dO**2) / (Dm**2 - dO**2) - gamma_S) / E_S
    k2 = ((DL**2 + DI**2) / (DL**2 - DI**2) + gamma_A) / E_A
    p = np.where(Dm > DI, (Dm - DI) / (Dm * k1 + DI * k2), 0.0)
    D_2 = np.where(Dm > DI, Dm * DI * (k1 + k2) / (Dm * k1 + DI * k2), DI)
    d_O2 = dO - 2.0 * p * Dm**2 * dO / (E_S * (Dm**2 - dO**2))
    D_L2 = DL + 2.0 * p * DI**2 * DL / (E_A * (DL**2 - DI**2))
    return p, D_2, d_O2, D_L2


def free_contact_angle_Harris(P_d: ArrayLike, A: ArrayLike) -> tuple[Array, Array, Array]:
    """Free (unloaded) contact angle from the radial clearance (Harris), docs/model.md §3.

    ``c0 = cos α° = 1 − P_d/(2A)``; ``α° = arccos c0`` for P_d > 0, else 0 (Fig. 5 "drops to zero");
    axial clearance ``p_e = 2 A sin α°``.

    Parameters
    ----------
    P_d : array_like
        Radial clearance, [mm] (negative: radially preloaded).
    A : array_like
        Curvature-centre distance B D_w, [mm].

    Returns
    -------
    c0 [-], alpha0 [rad], p_e [mm]

    >>> c0, a0, pe = free_contact_angle_Harris(0.0162, 0.2381)
    >>> round(math.degrees(float(a0)), 3), round(float(pe), 4)
    (14.988, 0.1232)
    """
    A_arr = np.asarray(A, dtype=float)
    c0 = 1.0 - np.asarray(P_d, dtype=float) / (2.0 * A_arr)
    alpha0 = np.arccos(np.clip(c0, -1.0, 1.0))
    return c0, alpha0, 2.0 * A_arr * np.sin(alpha0)


class RadialState(NamedTuple):
    """Radial coupling result at each temperature (Eqs. 11–14 and the free contact angle)."""

    dT: Array             #: t − T_ref [°C]
    fit_pressure: Array   #: p [MPa]; 0 where the fit is loose
    loose: NDArray[np.bool_]  #: True where the ring is loose in the housing (D_m1 <= D_I1)
    d_O2: Array           #: outer groove diameter after coupling [mm]
    d_I2: Array           #: inner groove diameter [mm]
    D_w2: Array           #: ball diameter [mm]
    d_m: Array            #: pitch diameter (steel expansion) [mm]
    P_d: Array            #: radial clearance P_d2 [mm]
    A: Array              #: curvature-centre distance B D_w2 [mm]
    c0: Array             #: cos of the free contact angle (may exceed 1) [-]
    alpha0: Array         #: free contact angle α° [rad]
    p_e: Array            #: axial clearance [mm]


def radial_coupling(p: AxisParams, t_c: ArrayLike) -> RadialState:
    """Radial coupling thermal deformation at temperatures ``t_c`` [°C], Eqs. (11)–(14), docs/model.md §8 steps 1–3."""
    t = np.asarray(t_c, dtype=float)
    dT = t - p.reference_temperature_c
    phi_S, phi_A = p.steel_cte_per_c, p.aluminium_cte_per_c
    d_O1 = thermal_expansion_Eq11(p.outer_groove_diameter_mm, phi_S, dT)
    D_m1 = thermal_expansion_Eq11(p.outside_diameter_mm, phi_S, dT)
    D_I1 = thermal_expansion_Eq11(p.outside_diameter_mm, phi_A, dT) - p.interference_factor * p.interference_mm
    D_L1 = thermal_expansion_Eq11(p.housing_outside_diameter_mm, phi_A, dT)
    d_I2 = thermal_expansion_Eq11(p.inner_groove_diameter_mm, phi_S, dT)
    D_w2 = thermal_expansion_Eq11(p.ball_diameter_mm, phi_S, dT)
    d_m = thermal_expansion_Eq11(p.pitch_diameter_mm, phi_S, dT)
    pressure, _, d_O2, _ = press_fit_Lame_Eq14(D_m1, d_O1, D_I1, D_L1, p.steel_youngs_modulus_mpa,
                                               p.steel_poisson_ratio, p.aluminium_youngs_modulus_mpa,
                                               p.aluminium_poisson_ratio)
    P_d = d_O2 - d_I2 - 2.0 * D_w2
    A = p.total_curvature * D_w2
    c0, alpha0, p_e = free_contact_angle_Harris(P_d, A)
    return RadialState(dT, pressure, D_m1 <= D_I1, d_O2, d_I2, D_w2, d_m, P_d, A, c0, alpha0, p_e)


def loose_fit_temperature(p: AxisParams) -> float:
    """Temperature above which the outer ring is loose in the housing, [°C].

    ``T_loose = T_ref + f Δ / (D_m (φ_A − φ_S))`` (free diameters equal). Infinite when the CTEs are equal.

    >>> round(loose_fit_temperature(AxisParams()), 1)
    43.1
    """
    d_phi = p.outside_diameter_mm * (p.aluminium_cte_per_c - p.steel_cte_per_c)
    if d_phi == 0.0:
        return math.inf if p.interference_mm > 0 else -math.inf
    return p.reference_temperature_c + p.interference_factor * p.interference_mm / d_phi


def axial_compliance_C1(p: AxisParams) -> float:
    """Axial compliance of the bearing pair's frame, Eq. (16) with the extra compliance, [mm/N].

    ``C1 = (L + 2 b0)/(E_S A_S) + L/(E_A A_A) + C_extra``.
    """
    L, b0 = p.shaft_length_mm, p.width_mm
    return ((L + 2.0 * b0) / (p.steel_youngs_modulus_mpa * p.steel_section_area_mm2)
            + L / (p.aluminium_youngs_modulus_mpa * p.aluminium_section_area_mm2)
            + p.extra_compliance_mm_per_n)


def axial_squeeze_Eq16(p: AxisParams, dT: ArrayLike, p_e: ArrayLike, p_e_ref: float) -> Array:
    """Axial squeeze X to be taken up by the pair's deflection and the frame: ``2 δ_P + C1 F_a = X``, [mm].

    Recommended form (bearing width expands with steel, ``scale_bearing_width``):
    ``X = g P + L (φ_A − φ_S) ΔT + p_e,ref (1 + φ_S ΔT) − p_e(t)``. Paper-literal Eq. (16):
    ``X = g P + [L φ_A − (L + 2 b0) φ_S] ΔT + p_e,ref − p_e(t)``. p_e,ref is p_e at T_ref with the same Δ, so
    that with P = 0 the pair just touches at T_ref.
    """
    dT_arr = np.asarray(dT, dtype=float)
    L, phi_S, phi_A = p.shaft_length_mm, p.steel_cte_per_c, p.aluminium_cte_per_c
    squeeze = p.gasket_factor * p.gasket_thickness_mm
    if p.scale_bearing_width:
        return squeeze + L * (phi_A - phi_S) * dT_arr + p_e_ref * (1.0 + phi_S * dT_arr) - np.asarray(p_e)
    return squeeze + (L * phi_A - (L + 2.0 * p.width_mm) * phi_S) * dT_arr + p_e_ref - np.asarray(p_e)


def axial_deflection_Eq18(A: ArrayLike, c0: ArrayLike, alpha0: ArrayLike, alpha: ArrayLike) -> Array:
    """Axial deflection of one bearing, Eq. (18): ``δ_P = B D_w sin(α − α°)/cos α = A c0 tan α − A sin α°``, [mm]."""
    return np.asarray(A) * (np.asarray(c0) * np.tan(alpha) - np.sin(alpha0))


def axial_load_Harris_Eq17(alpha: ArrayLike, c0: ArrayLike, A: ArrayLike, Z: int, K_n: ArrayLike) -> Array:
    """Axial load of one bearing versus contact angle, Eq. (17) (Harris), [N].

    ``F_a = Z D_w² K sin α (cos α°/cos α − 1)^1.5 = Z K_n [A (c0/cos α − 1)]^1.5 sin α`` with
    ``K = K_n (B D_w)^1.5 / D_w²``.
    """
    delta_n = np.maximum(np.asarray(A) * (np.asarray(c0) / np.cos(alpha) - 1.0), 0.0)
    return Z * np.asarray(K_n) * delta_n**1.5 * np.sin(alpha)


def contact_angle_Harris_Eq19(F_a: float, Z: int, D_w: float, K: float, cos_alpha0: float, alpha_start: float,
                              *, tol: float = 1e-14, max_iter: int = 100) -> float:
    """Loaded contact angle for a known axial load by Newton–Raphson, Eq. (19) (Harris), [rad].

    ``α' = α + [F_a/(Z D_w² K) − sin α (cos α0/cos α − 1)^1.5] /
    [cos α (cos α0/cos α − 1)^1.5 + 1.5 tan²α (cos α0/cos α − 1)^0.5 cos α0]``

    Parameters
    ----------
    F_a : float
        Axial load of the bearing, [N].
    Z : int
        Number of balls, [-].
    D_w : float
        Ball diameter, [mm].
    K : float
        Axial deflection constant ``K_n (B D_w)^1.5 / D_w²``, [N/mm²].
    cos_alpha0 : float
        Cosine of the free contact angle (may exceed 1), [-].
    alpha_start : float
        Starting angle, [rad]; must exceed the free contact angle.

    Raises
    ------
    ModelDomainError
        No convergence.
    """
    target = F_a / (Z * D_w**2 * K)
    alpha = alpha_start
    for _ in range(max_iter):
        r = max(cos_alpha0 / math.cos(alpha) - 1.0, 0.0)
        f = target - math.sin(alpha) * r**1.5
        d = math.cos(alpha) * r**1.5 + 1.5 * math.tan(alpha) ** 2 * math.sqrt(r) * cos_alpha0
        if d <= 0.0:
            alpha += 1e-3
            continue
        step = f / d
        alpha += step
        if abs(step) < tol:
            return alpha
    msg = f'Eq. (19) Newton-Raphson did not converge for F_a = {F_a} N'
    raise ModelDomainError(msg)


class AxialState(NamedTuple):
    """Loaded state of one bearing at each temperature (docs/model.md §8 steps 4–6)."""

    X: Array        #: axial squeeze [mm]
    alpha: Array    #: loaded contact angle [rad]
    K_n: Array      #: ball load-deflection constant at alpha [N/mm^1.5]
    delta_n: Array  #: normal approach, inner + outer [mm]
    Q: Array        #: ball normal load [N]
    F_a: Array      #: axial preload per bearing [N]
    delta_P: Array  #: axial deflection per bearing [mm]
    gap: NDArray[np.bool_]  #: True where the pair does not touch (F_a = 0)


def _coupled_residual(alpha: Array, r: RadialState, X: Array, C1: float, Z: int, K_n: Array) -> Array:
    """g(α) = 2 δ_P(α) + C1 F_a(α) − X (Eqs. 16–18 combined), [mm]."""
    return 2.0 * axial_deflection_Eq18(r.A, r.c0, r.alpha0, alpha) \
        + C1 * axial_load_Harris_Eq17(alpha, r.c0, r.A, Z, K_n) - X


def _finish_axial(p: AxisParams, r: RadialState, X: Array, alpha: Array, K_n: Array) -> AxialState:
    gap = X <= 0.0
    alpha = np.where(gap, r.alpha0, alpha)
    delta_n = np.maximum(r.A * (r.c0 / np.cos(alpha) - 1.0), 0.0)
    Q = K_n * delta_n**1.5
    F_a = p.ball_count * Q * np.sin(alpha)
    delta_P = axial_deflection_Eq18(r.A, r.c0, r.alpha0, alpha)
    return AxialState(X, alpha, K_n, delta_n, Q, F_a, delta_P, gap)


def _E_star(p: AxisParams) -> float:
    return reduced_modulus(p.steel_youngs_modulus_mpa, p.steel_poisson_ratio, p.steel_youngs_modulus_mpa,
                           p.steel_poisson_ratio)


def _squeeze(p: AxisParams, r: RadialState) -> Array:
    ref = radial_coupling(p, p.reference_temperature_c)
    return np.asarray(axial_squeeze_Eq16(p, r.dT, r.p_e, float(ref.p_e)), dtype=float)


def axial_squeeze(p: AxisParams, t_c: ArrayLike) -> Array:
    """The axial squeeze X of Eq. (16) at temperatures ``t_c`` [°C], [mm]: what the pair's deflection and the frame
    take up (:func:`axial_squeeze_Eq16` after the radial coupling). X < 0 is a gap between the pair: the paper's
    F_a of Eq. (16) turns negative, the bearings carry no preload and the model's contact loads no longer hold.

    >>> round(float(axial_squeeze(AxisParams(), 20.0)), 3)   # g P = 2 x 0.03 mm at the reference temperature
    0.06
    """
    return _squeeze(p, radial_coupling(p, t_c))


def axial_coupling(p: AxisParams, r: RadialState) -> AxialState:
    """Preload and loaded contact angle at every temperature of ``r`` (vectorised), docs/model.md §8 steps 4–6.

    Solves ``2 δ_P(α) + C1 F_a(α) = X`` (Eqs. 16–18) for α in (α°, 80°) by vectorised bisection at fixed K_n,
    then recomputes K_n from Hertz at the new α and repeats until K_n changes by less than 1e-13 (relative).
    Where ``X <= 0`` the pair has a gap: F_a = 0 and α = α°.

    Raises
    ------
    ModelDomainError
        The squeeze cannot be taken up below a contact angle of 80° (absurd preload).
    """
    X = _squeeze(p, r)
    C1 = axial_compliance_C1(p)
    Z = p.ball_count
    E_star = _E_star(p)
    f_i, f_o = p.inner_groove_curvature, p.outer_groove_curvature
    shape = np.shape(X)
    lo0 = np.broadcast_to(r.alpha0, shape).astype(float)
    K_n = load_deflection_constant(r.D_w2, r.d_m, np.maximum(lo0, math.radians(1.0)), f_i, f_o, E_star)
    K_n = np.broadcast_to(K_n, shape).astype(float)
    hi0 = np.full(shape, ALPHA_MAX)
    if np.any((_coupled_residual(hi0, r, X, C1, Z, K_n) < 0.0) & (X > 0.0)):
        msg = 'axial squeeze too large: no contact angle below 80 deg takes it up (check gasket/interference)'
        raise ModelDomainError(msg)
    alpha = lo0
    for _ in range(12):
        lo, hi = lo0.copy(), hi0.copy()
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            pos = _coupled_residual(mid, r, X, C1, Z, K_n) > 0.0
            hi = np.where(pos, mid, hi)
            lo = np.where(pos, lo, mid)
        alpha = 0.5 * (lo + hi)
        K_new = load_deflection_constant(r.D_w2, r.d_m, alpha, f_i, f_o, E_star)
        converged = np.all(np.abs(K_new - K_n) <= 1e-13 * np.abs(K_n))
        K_n = np.asarray(K_new, dtype=float)
        if converged:
            break
    return _finish_axial(p, r, X, alpha, K_n)


def axial_coupling_direct(p: AxisParams, t_c: float) -> tuple[RadialState, AxialState]:
    """Scalar reference solve at one temperature: brentq on g(α) with K_n(α) recomputed at every α.

    This is the "direct solve" the tabulated fast path and the vectorised solver are checked against.
    """
    r = radial_coupling(p, float(t_c))
    X = _squeeze(p, r)
    C1 = axial_compliance_C1(p)
    Z = p.ball_count
    E_star = _E_star(p)

    def K_n_at(alpha: float) -> float:
        return float(load_deflection_constant(float(r.D_w2), float(r.d_m), alpha, p.inner_groove_curvature,
                                              p.outer_groove_curvature, E_star))

    def g(alpha: float) -> float:
        return float(_coupled_residual(np.asarray(alpha), r, X, C1, Z, np.asarray(K_n_at(alpha))))

    a0 = float(r.alpha0)
    if float(X) <= 0.0:
        alpha = a0
    else:
        if g(ALPHA_MAX) < 0.0:
            msg = f'axial squeeze too large at {t_c} degC: no contact angle below 80 deg takes it up'
            raise ModelDomainError(msg)
        alpha = brentq(g, a0, ALPHA_MAX, xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=200)
    K_n = np.asarray(K_n_at(max(alpha, 1e-9)))
    return r, _finish_axial(p, r, np.asarray(X), np.asarray(alpha), K_n)
