"""Lubricant kinematic viscosity versus temperature: Walther (Eq. 20) and improved Walther (Eq. 21).

Only kinematic viscosity ν [mm²/s = cSt] appears here; nothing in this model uses dynamic viscosity η [Pa·s].
Temperatures are absolute, ``T = t + 273`` [K] as the paper's fits use (docs/model.md §5), and ``log`` is log10.

Worked example, Table 2 of Yu & Shang (2017), Krytox 143AA at 38 °C (experimental 35 cSt):

>>> round(nu_Walther_1931(38 + 273.0, 9.597, -3.773, 0.932), 4)
34.9853
>>> round(nu_Walther_improved(38 + 273.0, 8.6195, -21.2471, 1.08), 2)
34.65
"""

from __future__ import annotations

import math
from typing import NamedTuple, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from gimbal_friction.common.errors import FitError, ModelDomainError
from gimbal_friction.common.xp import ARRAY, SCALAR, FloatArray, FloatOrArray, Namespace, X

LN10 = math.log(10.0)

#: Eq. (22), Walther fit of Krytox 143AA: (a1, b1, c1).
KRYTOX_143AA_WALTHER = (9.597, -3.773, 0.932)
#: Eq. (22), improved-Walther fit of Krytox 143AA: (a1, b1, c1). Used for M_L in the paper.
KRYTOX_143AA_WALTHER_IMPROVED = (8.6195, -21.2471, 1.08)

#: Table 2 of the paper: temperature [°C] and experimental kinematic viscosity [cSt] (DuPont data).
TABLE2_T_C = (-32.0, 0.0, 20.0, 38.0, 40.0, 99.0, 100.0, 204.0)
TABLE2_NU_CST = (12000.0, 340.0, 85.0, 35.0, 32.0, 5.3, 5.2, 1.1)
#: Table 2 printed fitting viscosities and errors [%] for Eq. (20) and Eq. (21).
TABLE2_FIT1_CST = (11762.07, 348.26, 87.71, 34.98, 32.04, 5.252, 5.140, 1.108)
TABLE2_ERR1_PCT = (-1.983, 2.431, 3.188, -0.042, 0.123, -0.897, -1.155, 0.760)
TABLE2_FIT2_CST = (11983.82, 337.73, 85.78, 34.65, 31.78, 5.354, 5.240, 1.094)
TABLE2_ERR2_PCT = (-0.135, -0.668, 0.918, -0.993, -0.688, 1.014, 0.768, -0.540)


@overload
def walther_abscissa(T: ArrayLike, model: str, xp: Namespace[FloatArray] = ...) -> FloatArray: ...
@overload
def walther_abscissa(T: float, model: str, xp: Namespace[float]) -> float: ...
def walther_abscissa(T: ArrayLike, model: str, xp: Namespace[float] | Namespace[FloatArray] = ARRAY
                     ) -> FloatOrArray:
    """x of the linear Walther relation: log T (Eq. 20) or log log T (Eq. 21)."""
    if xp is ARRAY:
        t_array = np.asarray(T, dtype=np.float64)
        if np.any(~np.isfinite(t_array)) or np.any(t_array <= 10.0):
            msg = 'viscosity needs a finite absolute temperature above 10 K'
            raise ModelDomainError(msg)
        return _abscissa(t_array, model, ARRAY)
    t_float: float = T  # type: ignore[assignment]  # SCALAR: a float (a cast() call would cost per call)
    if not t_float > 10.0:  # also refuses NaN
        msg = 'viscosity needs a finite absolute temperature above 10 K'
        raise ModelDomainError(msg)
    return _abscissa(t_float, model, SCALAR)


def _abscissa(T: X, model: str, xp: Namespace[X]) -> X:
    """:func:`walther_abscissa` of a checked temperature [K], [-]."""
    if model == 'walther':
        return xp.log10(T)
    if model == 'walther_improved':
        return xp.log10(xp.log10(T))
    msg = f'unknown viscosity model {model!r}'
    raise ModelDomainError(msg)


@overload
def nu_Walther(T: ArrayLike, a1: float, b1: float, c1: float, model: str = ...,
               xp: Namespace[FloatArray] = ...) -> FloatArray: ...
@overload
def nu_Walther(T: float, a1: float, b1: float, c1: float, model: str, xp: Namespace[float]) -> float: ...
def nu_Walther(T: ArrayLike, a1: float, b1: float, c1: float, model: str = 'walther_improved',
               xp: Namespace[float] | Namespace[FloatArray] = ARRAY) -> FloatOrArray:
    r"""Kinematic viscosity from either Walther form, Eq. (20) or Eq. (21) of Yu & Shang (2017).

    .. math:: \log\log(\nu + c_1) = a_1 + b_1 x,\quad x = \log T \text{ (Eq. 20)},\ \log\log T \text{ (Eq. 21)}

    Parameters
    ----------
    T : array_like
        Absolute temperature, [K].
    a1, b1 : float
        Walther constants, [-].
    c1 : float
        Walther offset added to ν, [mm²/s].
    model : str
        ``'walther'`` (Eq. 20) or ``'walther_improved'`` (Eq. 21).
    xp : namespace
        :data:`~gimbal_friction.common.xp.ARRAY` (default: arrays in, array out) or
        :data:`~gimbal_friction.common.xp.SCALAR` (a Python float in and out, the nodes' fast path).

    Returns
    -------
    nu : ndarray or float
        Kinematic viscosity, [mm²/s] (= cSt).

    Notes
    -----
    The Krytox 143AA fits of Eq. (22) were made on data from −32 to 204 °C (Table 2); below −32 °C they are
    extrapolations.
    """
    if xp is ARRAY:
        x_array = walther_abscissa(T, model, ARRAY)
        return 10.0 ** (10.0 ** (a1 + b1 * x_array)) - c1
    t_float: float = T  # type: ignore[assignment]  # SCALAR: a float (a cast() call would cost per call)
    x = walther_abscissa(t_float, model, SCALAR)
    return 10.0 ** (10.0 ** (a1 + b1 * x)) - c1


def nu_Walther_1931(T: float, a1: float, b1: float, c1: float) -> float:
    """Scalar Eq. (20): ``log log(ν + c1) = a1 + b1 log T``; T [K], returns ν [mm²/s]."""
    return float(nu_Walther(T, a1, b1, c1, 'walther'))


def nu_Walther_improved(T: float, a1: float, b1: float, c1: float) -> float:
    """Scalar Eq. (21): ``log log(ν + c1) = a1 + b1 log(log T)``; T [K], returns ν [mm²/s]."""
    return float(nu_Walther(T, a1, b1, c1, 'walther_improved'))


def dnu_dT_Walther(T: ArrayLike, a1: float, b1: float, c1: float,
                   model: str = 'walther_improved') -> NDArray[np.float64]:
    """Temperature derivative dν/dT of Eq. (20)/(21), [mm²/s/K]."""
    T_arr = np.asarray(T, dtype=float)
    x = walther_abscissa(T_arr, model)
    w = np.power(10.0, a1 + b1 * x)
    nu_c = np.power(10.0, w)
    if model == 'walther':
        dx_dT = 1.0 / (T_arr * LN10)
    else:
        dx_dT = 1.0 / (np.log10(T_arr) * LN10 * T_arr * LN10)
    return nu_c * LN10 * w * LN10 * b1 * dx_dT


def nu_Walther_fitting_jacobian(T: ArrayLike, a1: float, b1: float, c1: float,
                                model: str = 'walther_improved') -> NDArray[np.float64]:
    """Jacobian of ν with respect to (a1, b1, c1), shape (n, 3), [mm²/s per unit parameter]."""
    x = walther_abscissa(T, model)
    w = np.power(10.0, a1 + b1 * x)
    nu_c = np.power(10.0, w)
    d_da = nu_c * LN10 * LN10 * w
    return np.column_stack([d_da, d_da * x, -np.ones_like(x)])


class ViscosityFit(NamedTuple):
    """Result of :func:`fit_Walther`: constants, per-point table (as the paper's Table 2) and error summary."""

    model: str
    a1: float
    b1: float
    c1: float
    T_K: NDArray[np.float64]
    nu_exp_cst: NDArray[np.float64]
    nu_fit_cst: NDArray[np.float64]
    error_pct: NDArray[np.float64]
    rms_error_pct: float
    max_abs_error_pct: float
    standard_errors: tuple[float, float, float]


def viscosity_errors_pct(nu_fit: ArrayLike, nu_exp: ArrayLike) -> NDArray[np.float64]:
    """Per-point error ``(fit − exp)/exp × 100`` as printed in Table 2, [%]."""
    fit = np.asarray(nu_fit, dtype=float)
    exp = np.asarray(nu_exp, dtype=float)
    return (fit - exp) / exp * 100.0


def fit_Walther(t_c: ArrayLike, nu_cst: ArrayLike, model: str = 'walther_improved', *,
                kelvin_offset_k: float = 273.0) -> ViscosityFit:
    """Least-squares fit of Eq. (20) or Eq. (21) to (temperature, kinematic viscosity) data.

    Minimises the relative error of ν (the quantity Table 2 reports) with the analytic Jacobian
    :func:`nu_Walther_fitting_jacobian`. The offset c1 is kept where ``ν + c1 > 1`` for every point.

    Parameters
    ----------
    t_c : array_like
        Temperatures, [°C].
    nu_cst : array_like
        Kinematic viscosities, [mm²/s].
    model : str
        ``'walther'`` (Eq. 20) or ``'walther_improved'`` (Eq. 21).
    kelvin_offset_k : float
        T = t + this, [K] (the paper uses 273).

    Raises
    ------
    FitError
        Fewer than 4 points, non-finite or non-positive viscosities, or no convergence.

    Examples
    --------
    Refit of the paper's Table 2 with Eq. (21):

    >>> fit = fit_Walther(TABLE2_T_C, TABLE2_NU_CST)
    >>> fit.max_abs_error_pct < 1.1
    True
    """
    t = np.asarray(t_c, dtype=float)
    nu = np.asarray(nu_cst, dtype=float)
    if t.shape != nu.shape or t.ndim != 1:
        raise FitError('temperature and viscosity must be 1-D arrays of equal length')
    if t.size < 4:
        msg = f'need at least 4 (temperature, viscosity) points for 3 constants, got {t.size}'
        raise FitError(msg)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(nu))):
        raise FitError('temperatures and viscosities must be finite')
    if np.any(nu <= 0.0):
        raise FitError('kinematic viscosities must be > 0 cSt')
    if np.unique(t).size < 3:
        raise FitError('need at least 3 distinct temperatures')
    T = t + kelvin_offset_k
    try:
        x = walther_abscissa(T, model)
    except ModelDomainError as err:
        raise FitError(str(err)) from None
    c_low = 1.0 - float(nu.min()) + 1e-9
    c0 = max(0.7, c_low + 0.1)
    y = np.log10(np.log10(nu + c0))
    b0, a0 = np.polyfit(x, y, 1)

    def residuals(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        return (nu_Walther(T, theta[0], theta[1], theta[2], model) - nu) / nu

    def jac(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        return nu_Walther_fitting_jacobian(T, theta[0], theta[1], theta[2], model) / nu[:, None]

    with np.errstate(over='ignore', invalid='ignore'):
        res = least_squares(residuals, x0=[a0, b0, c0], jac=jac, method='trf', x_scale='jac',
                            bounds=([-np.inf, -np.inf, c_low], [np.inf, np.inf, 100.0]),
                            xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)
    if not res.success or not np.all(np.isfinite(res.fun)):
        msg = f'viscosity fit did not converge: {res.message}'
        raise FitError(msg)
    a1, b1, c1 = (float(v) for v in res.x)
    fit = nu_Walther(T, a1, b1, c1, model)
    err_pct = viscosity_errors_pct(fit, nu)
    dof = max(t.size - 3, 1)
    s2 = float(res.fun @ res.fun) / dof
    try:
        cov = np.linalg.inv(res.jac.T @ res.jac) * s2
        se = tuple(float(v) for v in np.sqrt(np.abs(np.diag(cov))))
    except np.linalg.LinAlgError:
        se = (math.inf, math.inf, math.inf)
    return ViscosityFit(model, a1, b1, c1, T, nu, fit, err_pct, float(np.sqrt(np.mean(err_pct**2))),
                        float(np.max(np.abs(err_pct))), (se[0], se[1], se[2]))
