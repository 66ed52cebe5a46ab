r"""Motor torque constant K_T and no-load offset I_0 (T_0): the electrical friction measurement of Sec. 6.

In steady state the motor torque balances friction, Eq. (23) of Yu & Shang (2017):

.. math:: T_m = T_f + T_0 = K_T (I_f + I_0) \quad\Rightarrow\quad T_f = K_T I - T_0,\quad T_0 = K_T I_0

where ``I = I_f + I_0`` is the measured armature current [A]. The no-load current acts against the motion, so with
a direction ``d = sign(ω)`` the measured load (friction) torque is ``T_f = K_T (I − d I_0)`` [N·m].

K_T is calibrated on a separate rig against a torque sensor (the paper averages many loaded measurements).
:func:`fit_kt` fits K_T and T_0 by robust least squares to (current, reference torque) pairs and reports the
uncertainty; :func:`friction_from_current_Eq23` turns a current into friction torque with the result.

Worked example: K_T = 0.0523 N·m/A, I_0 = 12 mA, a steady 0.5 A while moving positive gives

>>> round(friction_from_current_Eq23(0.5, 0.0523, 0.012), 7)
0.0255224

References
----------
.. [1] N. Yu, J. Shang, "Frictional torque analyzing and testing of Gimbaled-mirror seeker under changing
   environment temperature", J. Adv. Mech. Des. Syst. Manuf. 11(5), 2017, DOI 10.1299/jamdsm.2017jamdsm0052.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from gimbal_friction.common.errors import FitError

#: fewest (current, torque) points a fit accepts (two parameters plus one degree of freedom) [-]
MIN_POINTS = 3
#: a point is an outlier when its residual exceeds this many robust standard deviations [-]
OUTLIER_THRESHOLD = 3.5
#: MAD -> standard deviation of a normal distribution [-]
MAD_TO_SIGMA = 1.482602218505602
#: mean absolute deviation -> standard deviation of a normal distribution, sqrt(pi/2) [-]
MEAN_ABS_TO_SIGMA = 1.2533141373155003


class KtFit(NamedTuple):
    """Result of :func:`fit_kt` (Eq. 23). Standard errors are 1 sigma; statistics are over the inliers.

    Attributes:
        K_T: motor torque constant [N*m/A].
        I_0: no-load current [A].
        T_0: no-load torque, ``K_T * I_0`` [N*m].
        se_K_T: standard error of K_T [N*m/A].
        se_I_0: standard error of I_0 (delta method, with the K_T-T_0 covariance) [A].
        se_T_0: standard error of T_0 [N*m].
        r2: coefficient of determination of the torque over the inliers [-].
        residual_std: residual standard deviation over the inliers, ``sqrt(RSS/(n_in - 2))`` [N*m].
        n: number of points given [-].
        n_outliers: points rejected as outliers [-].
        residuals: ``torque - model`` of every point, outliers included [N*m].
        inliers: boolean mask of the points the final fit used [-].
        direction: sign of motion used for the offset of every point (+1 when no speed was given) [-].
        cov_K_T_T_0: covariance of K_T and T_0 [N*m/A * N*m].
    """

    K_T: float
    I_0: float
    T_0: float
    se_K_T: float
    se_I_0: float
    se_T_0: float
    r2: float
    residual_std: float
    n: int
    n_outliers: int
    residuals: NDArray[np.float64]
    inliers: NDArray[np.bool_]
    direction: NDArray[np.float64]
    cov_K_T_T_0: float

    @property
    def n_inliers(self) -> int:
        """Points the final fit used [-]."""
        return self.n - self.n_outliers


def friction_from_current_Eq23(current_a: ArrayLike, K_T: float, I_0: float,
                               direction: ArrayLike = 1.0) -> NDArray[np.float64] | float:
    r"""Load (friction) torque from the motor current in steady state, Eq. (23).

    .. math:: T_f = K_T (I - d\, I_0)

    Parameters
    ----------
    current_a : array_like
        Measured armature current I = I_f + I_0, [A].
    K_T : float
        Motor torque constant, [N*m/A].
    I_0 : float
        No-load current (its magnitude, acting against motion), [A].
    direction : array_like
        Sign of motion d (+1, -1, or 0 at standstill), broadcast against ``current_a``, [-].

    Returns
    -------
    T_f : ndarray or float
        Friction torque, signed like the motion, [N*m]; a float for scalar inputs.

    Notes
    -----
    Valid in steady state only (constant speed, no acceleration torque) and while K_T is constant (no magnetic
    saturation; the temperature dependence of the magnets is not modelled).

    Examples
    --------
    >>> friction_from_current_Eq23([0.5, -0.5], 0.05, 0.01, direction=[1, -1]).round(6).tolist()
    [0.0245, -0.0245]
    """
    I_arr = np.asarray(current_a, dtype=float)
    d = np.asarray(direction, dtype=float)
    out = K_T * (I_arr - d * I_0)
    if out.ndim == 0:
        return float(out)
    return np.asarray(out, dtype=np.float64)


def friction_from_current_Eq23_jacobian(current_a: ArrayLike, K_T: float, I_0: float,
                                        direction: ArrayLike = 1.0) -> NDArray[np.float64]:
    """Jacobian of Eq. (23) with respect to (K_T, I_0), shape (n, 2), [N*m/(N*m/A)] and [N*m/A].

    >>> friction_from_current_Eq23_jacobian([0.5], 0.05, 0.01).round(6).tolist()
    [[0.49, -0.05]]
    """
    I_arr = np.atleast_1d(np.asarray(current_a, dtype=float))
    d = np.broadcast_to(np.asarray(direction, dtype=float), I_arr.shape)
    return np.column_stack([I_arr - d * I_0, -d * K_T])


def _column(name: str, values: ArrayLike) -> NDArray[np.float64]:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        msg = f'column {name!r} must hold numbers'
        raise FitError(msg) from None
    if arr.ndim != 1:
        msg = f'column {name!r} must be one-dimensional, got shape {arr.shape}'
        raise FitError(msg)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        msg = (f'non-finite values in column {name!r}: {bad.size} of {arr.size} (first at point {bad[0] + 1}: '
               f'{arr[bad[0]]})')
        raise FitError(msg)
    return arr


def _robust_sigma(r: NDArray[np.float64], floor: float) -> float:
    """Standard deviation of fit residuals from their median absolute value [same unit as r].

    The residuals of a fit with an offset are centred on zero, so the median of ``|r|`` is taken about zero: about
    the median, quantised data (a sensor resolution, values rounded in a CSV) often give a MAD of exactly 0. When
    more than half the residuals are zero (exact data) the mean absolute residual is used instead, never less than
    ``floor``.
    """
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(r)))
    if sigma > floor:
        return sigma
    return max(MEAN_ABS_TO_SIGMA * float(np.mean(np.abs(r))), floor)


def _ols(A: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    return np.asarray(beta, dtype=np.float64)


def fit_kt(current_a: ArrayLike, torque_nm: ArrayLike, speed_rad_s: ArrayLike | None = None, *,
           outlier_threshold: float = OUTLIER_THRESHOLD) -> KtFit:
    r"""Fit K_T and the no-load offset of Eq. (23) to calibration data, robust to outliers.

    .. math:: T_{ref} = K_T I - d\, T_0,\qquad T_0 = K_T I_0,\qquad d = \operatorname{sign}(\omega)\ (\text{or } 1)

    The model is linear in (K_T, T_0). The fit has three stages:

    1. ordinary least squares, whose residuals give a first scale ``s = 1.4826 median(|r|)``;
    2. ``scipy.optimize.least_squares`` with ``loss='soft_l1'`` and ``f_scale = s`` from the OLS start, which
       bounds the pull of gross outliers;
    3. hard rejection: points with ``|r| > outlier_threshold * 1.4826 median(|r|)`` (median over the current
       inliers) are outliers, and K_T, T_0 are refit by ordinary least squares on the inliers, repeated until
       the outlier set no longer changes.

    The reported standard errors come from the final (0/1-weighted) Jacobian: ``cov = s² (AᵀA)⁻¹`` over the inliers
    with ``s² = RSS/(n_in − 2)``; the standard error of I_0 = T_0/K_T follows by the delta method. This keeps the
    uncertainty honest (no down-weighted outlier drags the estimate), and the outlier count is explicit.

    Parameters
    ----------
    current_a : array_like
        Motor armature current I, [A].
    torque_nm : array_like
        Reference (load) torque from the torque sensor, [N*m].
    speed_rad_s : array_like, optional
        Shaft speed, [rad/s]; only its sign d is used. Without it every point is taken as loaded in the positive
        direction (d = +1) and the offset is a plain intercept.
    outlier_threshold : float
        Rejection threshold in robust standard deviations, [-].

    Returns
    -------
    KtFit
        K_T [N*m/A], I_0 [A], T_0 [N*m], their standard errors, R² [-], residual std [N*m], counts, residuals and
        the inlier mask.

    Raises
    ------
    FitError
        Too few points (fewer than 3), arrays of different lengths, non-finite values (naming the column),
        all-zero current, all currents equal, speed zero everywhere, more than half the points outliers, or a
        fitted K_T that is not positive.

    Notes
    -----
    Valid for steady-state points (constant speed) in the linear range of the motor. Outlier rejection relies on
    the median, so it breaks down when half or more of the points are bad.

    Examples
    --------
    Exact data with K_T = 0.05 N*m/A and I_0 = 10 mA, plus one gross outlier:

    >>> I = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    >>> T = [0.05 * (i - 0.01) for i in I]
    >>> T[3] = 0.5
    >>> fit = fit_kt(I, T)
    >>> round(fit.K_T, 6), round(fit.I_0, 6), fit.n_outliers, bool(fit.inliers[3])
    (0.05, 0.01, 1, False)
    """
    I_arr = _column('current_a', current_a)
    tau = _column('torque_nm', torque_nm)
    speed = None if speed_rad_s is None else _column('speed_rad_s', speed_rad_s)
    n = I_arr.size
    if tau.size != n or (speed is not None and speed.size != n):
        sizes = f'current_a {n}, torque_nm {tau.size}' + ('' if speed is None else f', speed_rad_s {speed.size}')
        msg = f'columns have different lengths ({sizes})'
        raise FitError(msg)
    if n < MIN_POINTS:
        msg = f'too few points: {n} (need at least {MIN_POINTS} to fit K_T and I_0 with an uncertainty)'
        raise FitError(msg)
    if np.all(I_arr == 0.0):
        raise FitError('all-zero current: current_a is 0 A in every point (wrong column or units?)')
    if np.ptp(I_arr) == 0.0:
        msg = (f'all currents equal ({I_arr[0]:g} A): K_T cannot be separated from the no-load offset; '
               'measure at several loads')
        raise FitError(msg)
    if speed is None:
        d = np.ones(n)
    else:
        d = np.sign(speed)
        if np.all(d == 0.0):
            raise FitError('speed_rad_s is 0 in every point: no direction for the no-load offset '
                           '(omit the column to assume the positive direction)')
    A = np.column_stack([I_arr, -d])  # torque = K_T * I - T_0 * d, Eq. (23)
    scale = float(np.max(np.abs(tau))) or 1.0
    floor = 1e-12 * scale

    # Stage 1: OLS start and scale.
    beta = _ols(A, tau)
    s0 = _robust_sigma(tau - A @ beta, floor)

    # Stage 2: soft-L1 robust fit (linear model: the Jacobian is A).
    res = least_squares(lambda b: A @ b - tau, x0=beta, jac=lambda b: A, loss='soft_l1', f_scale=s0,
                        method='trf', x_scale='jac', xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=200)
    if np.all(np.isfinite(res.x)):
        beta = np.asarray(res.x, dtype=np.float64)

    # Stage 3: hard rejection and inlier OLS until the outlier set is stable.
    inliers = np.ones(n, dtype=bool)
    for _ in range(50):
        r = tau - A @ beta
        sigma = _robust_sigma(r[inliers] if inliers.sum() >= MIN_POINTS else r, floor)
        new = np.abs(r) <= outlier_threshold * sigma
        if new.sum() < MIN_POINTS or np.ptp(I_arr[new]) == 0.0 or np.linalg.matrix_rank(A[new]) < 2:
            msg = (f'too few usable inliers: {int(new.sum())} of {n} points lie within {outlier_threshold:g} '
                   'robust standard deviations of the fit (need at least 3 at different currents)')
            raise FitError(msg)
        beta = _ols(A[new], tau[new])
        if np.array_equal(new, inliers):
            break
        inliers = new
    n_out = int(n - inliers.sum())
    if 2 * n_out > n:
        msg = (f'{n_out} of {n} points are outliers: the data do not follow a straight line torque = K_T*I - T_0 '
               '(check the columns and units)')
        raise FitError(msg)

    K_T, T_0 = float(beta[0]), float(beta[1])
    if not K_T > 0.0:
        msg = (f'fitted K_T = {K_T:.4g} N*m/A is not positive: current and torque do not rise together '
               '(check the sign conventions of current_a and torque_nm)')
        raise FitError(msg)
    residuals = tau - A @ beta
    A_in, r_in, tau_in = A[inliers], residuals[inliers], tau[inliers]
    n_in = int(inliers.sum())
    rss = float(r_in @ r_in)
    s2 = rss / (n_in - 2)
    cov = s2 * np.linalg.inv(A_in.T @ A_in)
    var_K, var_T0, cov_KT = float(cov[0, 0]), float(cov[1, 1]), float(cov[0, 1])
    I_0 = T_0 / K_T
    # delta method for I_0 = T_0 / K_T: gradient (-T_0/K_T², 1/K_T)
    g_K, g_T = -T_0 / K_T**2, 1.0 / K_T
    var_I0 = g_K * g_K * var_K + g_T * g_T * var_T0 + 2.0 * g_K * g_T * cov_KT
    tss = float(np.sum((tau_in - tau_in.mean()) ** 2))
    r2 = 1.0 - rss / tss if tss > 0.0 else math.nan
    return KtFit(K_T=K_T, I_0=I_0, T_0=T_0, se_K_T=math.sqrt(max(var_K, 0.0)), se_I_0=math.sqrt(max(var_I0, 0.0)),
                 se_T_0=math.sqrt(max(var_T0, 0.0)), r2=r2, residual_std=math.sqrt(s2), n=n, n_outliers=n_out,
                 residuals=residuals, inliers=inliers, direction=d, cov_K_T_T_0=cov_KT)
