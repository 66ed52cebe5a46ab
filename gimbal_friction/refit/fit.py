"""Refit of the lubricant (and optionally other) model parameters to measured friction (pure: no I/O).

The model of one sample ``i`` (temperature t_i [°C], speed n_i [rpm], direction d_i = ±1) is

.. math:: |\\tau_i| = k_{d_i}(t_i) \\, [M_R(t_i) + \\mu \\, S(t_i) + M_L(t_i, n_i; s_0, \\nu(t_i; a_1, b_1, c_1))] + c

with ``k_d(t)`` the direction factor of :func:`~gimbal_friction.physics.direction.direction_factor` (``scale_positive``
/ ``scale_negative`` times ``1 ± a(t)``, the temperature-dependent asymmetry), M_R the hysteresis torque (Eqs.
1–3), ``μ S`` the spin torque (Eqs. 5–8: linear in μ, so ``S`` = M_S at μ = 1), M_L Palmgren's viscous torque
(Eq. 9, :func:`~gimbal_friction.physics.friction.viscous_torque_Palmgren_1959`), ν the Walther viscosity (Eqs. 20–22,
:func:`~gimbal_friction.physics.viscosity.nu_Walther`) and ``c`` a constant torque offset of the measurement (below).
Torques of the whole axis. M_R and S do not depend on the lubricant: they are computed once, by the full model
:func:`~gimbal_friction.physics.model.friction_torque` on a 0.05 °C grid over the data and interpolated.

Data. The fit runs on per-bin sufficient statistics (:mod:`gimbal_friction.refit.sufficient`): the model is
evaluated once per fine bin (0.1 °C × direction × 2 % of speed) at its mean temperature and speed, never per
sample, so its cost does not grow with the number of samples (10⁷ samples: about 2·10³ bins). The same code with
one sample per cell (``exact=True``) is the per-sample refit; both agree to the bin curvature (tests).

What the data can determine (docs/model.md §2, Eq. 9): M_L depends on viscosity only where ``ν·n ≥ 2000`` (the upper
Palmgren branch; at the paper's 1/3 rpm only below about −27 °C). A Walther constant is therefore identifiable
only from samples in that regime, under the base *and* the fitted parameters, and each such distinct temperature
bin carries one degree of freedom of the viscosity–temperature curve: with one cold plateau only ``walther_a``
(the first of ``walther_a, walther_b, viscosity_offset_cst`` requested) can be determined, with two also
``walther_b``, and so on. The direction asymmetry needs both directions, ``direction_asymmetry_cold`` data below
``direction_asymmetry_warm_c`` and ``direction_asymmetry_warm`` data above ``direction_asymmetry_cold_c``.
Parameters that cannot be determined are reported ``not identifiable: <reason>`` and held at their base values,
never fitted silently. After a fit, parameters whose jacobian column is (nearly) zero, that are collinear with
others (SVD of the column-normalised weighted jacobian, condition > 1e3) or whose standard error exceeds 50 % of
their value (for an asymmetry: 0.1 absolute) are flagged the same way, held at base, and the rest refitted.

Calibration offset. An error δ in the no-load current I_0 (or T_0 = K_T I_0) of Eq. (23) shifts every measured
|τ| by the same ``c = −K_T δ`` in both directions; fitted by the viscosity alone it leaks into ν. With ``offset =
'auto'`` (the default) ``c`` is a nuisance parameter of the fit whenever the data have both a plateau in the
viscous regime (cold) and one below it (warm): the warm plateaus, whose friction does not depend on the viscosity,
fix ``c``, and the cold ones then fix ν. It is reported with its 95 % interval and the no-load current that would
remove it (``I_0 + c/K_T``), and it is compared with the calibration's own uncertainty σ_T0 (the 1-sigma of T_0
that ``calibrate-kt`` prints): a warning is raised when ``|c| − 1.96 se_c > σ_T0``, i.e. when the offset is beyond
the calibration's 1-sigma even at the near end of its own 95 % interval (an I_0 off by 2 σ is flagged once the
offset is known to better than about σ/2). A requested ``palmgren_factor`` (whose low-speed floor is a constant
torque too) switches the automatic offset off; with ``offset='on'`` both are fitted and the offset, lowest in
priority, is the one held if they turn out collinear. Either way any offset of the measurement then goes into the
fitted parameters: when the data could have determined it, the result's ``offset_confounding`` gives the linear
response of every fitted parameter (and of ν at the viscous plateaus) to a 1-sigma offset (the calibration's
σ_T0, else K_T × 1 mA), and a warning names the parameters it moves by more than one standard error.
``offset='on'`` always fits it, ``'off'`` never. The offset is not a model parameter: the written parameters and
the feedforward do not contain it.

Weighting (``weights='bin_se'``, the default). Samples are grouped into (temperature bin, direction, speed)
groups; the fit matches each group's mean measured torque with the group mean of the model (averaged over the
group's own fine bins, so the temperature spread inside a group does not bias it), weighted by ``1/se``. The
standard error ``se`` of a group mean is the larger of the i.i.d. value ``s/√n`` and a batch-means value (10
consecutive stretches of the group's samples in time order, built from its 1 s cells; this accounts for the
position ripple and other correlated noise), combined with a floor of ``se_floor_rel`` (0.2 %) of the mean that
stands for the model's own error. So a long plateau cannot drown a short cold one (its weight saturates at the
floor), noisy groups count less, and every number is in [N·m]. ``weights='relative'`` instead gives every group
the same weight on its relative error. The covariance is ``(JᵀJ)⁻¹ · max(1, χ²/dof)`` (so misfit widens the
intervals) and the 95 % intervals use Student's t with ``dof = groups − parameters``.

The viscosity constants are fitted in a centred form ``log log(ν + c1) = a' + b1 (x − x_ref)`` with ``x_ref`` the
mean Walther abscissa of the viscous-regime data (``a1 = a' − b1 x_ref``): a1 and b1 are almost collinear in the
raw form, not in this one. Bounds keep the fit away from absurd values (``a'`` within ±0.3, i.e. log(ν + c1) at
most ×2 or ÷2; ``b1`` within ×3 of its base value and < 0; ``c1`` in [−1, 100] cSt; factors within ×20;
asymmetries within ±0.9; the offset below the smallest group mean); a fit that ends on one of them, raises the
cost, makes ν ≤ 0 over the data or does not converge is refused (:class:`~gimbal_friction.common.errors.FitError`).

Example: recover a shifted ``walther_a`` from noise-free plateaus at −40, 0 and 40 °C, both directions:

The refit in modules (each one job): :mod:`~gimbal_friction.refit.results` (names, limits, result types),
:mod:`~gimbal_friction.refit.model` (the samples' model and Jacobian), :mod:`~gimbal_friction.refit.problem` (points,
groups, weights, the solve), :mod:`~gimbal_friction.refit.identifiability` (what the data determine, the offset and
its confounding) and this module: the entry points and the result. The public names are all importable from here.

>>> from gimbal_friction.physics.model import friction_torque
>>> base = AxisParams()
>>> truth = base.replace(walther_a=base.walther_a + 0.01)
>>> t = np.repeat([-40.0, 0.0, 40.0], 20).repeat(2)
>>> d = np.tile([1.0, -1.0], 60)
>>> tau = friction_torque(truth, t, 1 / 3).m_total_nmm * 1e-3
>>> res = refit_model(base, t, np.full(t.shape, 1 / 3), tau, d)
>>> round(res.fitted['walther_a'], 4), res.identifiability['walther_a'].identifiable
(8.6295, True)
>>> res.offset.estimated, abs(res.offset.value_nm) < 1e-9   # warm and cold plateaus: the offset is fitted, ~0
(True, True)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from gimbal_friction.common.errors import ConfigError, FitError, GimbalFrictionError
from gimbal_friction.common.units import NM_PER_NMM
from gimbal_friction.physics.model import palmgren_threshold_temperature
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, AxisParams
from gimbal_friction.physics.viscosity import nu_Walther, nu_Walther_fitting_jacobian
from gimbal_friction.refit.fit_check import FIT_NOT_CHECKED, BinCheck, FitCheck, decide
from gimbal_friction.refit.identifiability import (
    _a_priori_reasons,
    _confounding_text,
    _degenerate,
    _offset_confounding,
    _offset_mode,
    _offset_result,
    _relative_se,
    _se_reason,
)
from gimbal_friction.refit.model import SampleModel, measurement_model_nmm
from gimbal_friction.refit.problem import (
    _covariance,
    _distinct_viscous_temperatures,
    _group,
    _group_mean,
    _group_se,
    _Groups,
    _label,
    _Points,
    _points,
    _Problem,
    _Solution,
)
from gimbal_friction.refit.results import (
    ASYMMETRY_PARAMETERS,
    DEFAULT_FIT,
    FIT_PARAMETERS,
    GRID_STEP_C,
    LOSSES,
    MAX_ASYMMETRY_SE,
    MAX_CONDITION,
    MAX_RELATIVE_SE,
    MIN_BIN_SAMPLES,
    MIN_SAMPLES,
    NOT_CHECKED,
    OFFSET,
    OFFSET_MODES,
    PALMGREN_THRESHOLD,
    SPEED_BIN_RATIO,
    VISCOSITY_PARAMETERS,
    WEIGHTS,
    Z95,
    Array,
    BinStats,
    Identifiability,
    OffsetConfounding,
    OffsetResult,
    RefitResult,
    ViscosityInterval,
)
from gimbal_friction.refit.sufficient import SufficientStats

__all__ = [
    'ASYMMETRY_PARAMETERS',
    'DEFAULT_FIT',
    'FIT_PARAMETERS',
    'GRID_STEP_C',
    'LOSSES',
    'MAX_ASYMMETRY_SE',
    'MAX_CONDITION',
    'MAX_RELATIVE_SE',
    'MIN_BIN_SAMPLES',
    'MIN_SAMPLES',
    'NOT_CHECKED',
    'OFFSET',
    'OFFSET_MODES',
    'PALMGREN_THRESHOLD',
    'SPEED_BIN_RATIO',
    'VISCOSITY_PARAMETERS',
    'WEIGHTS',
    'Z95',
    'BinCheck',
    'BinStats',
    'FitCheck',
    'Identifiability',
    'OffsetConfounding',
    'OffsetResult',
    'RefitResult',
    'SampleModel',
    'ViscosityInterval',
    'check_model',
    'palmgren_threshold_temperature',
    'refit_model',
    'refit_stats',
]


def _check_options(fit: Sequence[str], weights: str, loss: str, bin_width_c: float, offset: str,
                   calibration_se_nm: float | None) -> None:
    if not fit:
        raise FitError('nothing to fit: give at least one parameter')
    unknown = [name for name in fit if name not in FIT_PARAMETERS]
    if unknown:
        msg = f'cannot fit {", ".join(unknown)}: choose from {", ".join(FIT_PARAMETERS)}'
        raise FitError(msg)
    if len(set(fit)) != len(fit):
        raise FitError('a parameter is listed twice in fit')
    if weights not in WEIGHTS:
        msg = f'weights {weights!r}: choose from {", ".join(WEIGHTS)}'
        raise FitError(msg)
    if loss not in LOSSES:
        msg = f'loss {loss!r}: choose from {", ".join(LOSSES)}'
        raise FitError(msg)
    if offset not in OFFSET_MODES:
        msg = f'offset {offset!r}: choose from {", ".join(OFFSET_MODES)}'
        raise FitError(msg)
    if not (math.isfinite(bin_width_c) and bin_width_c > 0.0):
        raise FitError('the temperature bin width must be > 0 degC')
    if calibration_se_nm is not None and not (math.isfinite(calibration_se_nm) and calibration_se_nm >= 0.0):
        raise FitError('the calibration uncertainty must be a finite torque >= 0 N*m')


def _check_inputs(base: AxisParams, t: Array, n: Array, y: Array, d: Array) -> None:
    if not (t.ndim == n.ndim == y.ndim == d.ndim == 1 and t.shape == n.shape == y.shape == d.shape):
        raise FitError('temperature, speed, measured torque and direction must be 1-D arrays of equal length')
    if t.shape[0] < MIN_SAMPLES:
        msg = f'too few samples: {t.shape[0]} (need at least {MIN_SAMPLES})'
        raise FitError(msg)
    for label, arr in (('temperature', t), ('speed', n), ('measured torque', y), ('direction', d)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            msg = f'non-finite data: {bad} sample(s) have a NaN or infinite {label}'
            raise FitError(msg)
    if np.any(n <= 0.0):
        msg = f'{int(np.count_nonzero(n <= 0.0))} sample(s) have zero speed: the direction of friction is undefined'
        raise FitError(msg)
    if not np.all(np.abs(d) == 1.0):
        raise FitError('direction must be +1 or -1 for every sample')
    if np.any(t < MODEL_T_MIN_C) or np.any(t > MODEL_T_MAX_C):
        raise FitError(f'temperatures must lie in [{MODEL_T_MIN_C:g}, {MODEL_T_MAX_C:g}] degC for this model')


def refit_model(base: AxisParams, temperature_c: ArrayLike, speed_rpm: ArrayLike, measured_abs_nm: ArrayLike,
                direction: ArrayLike, *, fit: Sequence[str] = DEFAULT_FIT, weights: str = 'bin_se',
                loss: str = 'linear', f_scale: float | None = None, bin_width_c: float = 5.0,
                min_bin_samples: int = MIN_BIN_SAMPLES, se_floor_rel: float = 0.002,
                max_nfev: int = 200, offset: str = 'auto', calibration_se_nm: float | None = None,
                time_s: ArrayLike | None = None, exact: bool = False) -> RefitResult:
    """Refit lubricant (and other) parameters of ``base`` to measured friction by weighted least squares.

    Builds the sufficient statistics of the samples (:meth:`SufficientStats.from_arrays`) and runs
    :func:`refit_stats` on them.

    Parameters
    ----------
    base : AxisParams
        Model parameters of the axis; the starting point, and the value of everything not fitted.
    temperature_c : array_like
        Bearing temperature of every sample, [°C].
    speed_rpm : array_like
        Speed magnitude |v| of every sample, [rpm] (> 0).
    measured_abs_nm : array_like
        Measured friction along the motion (signed friction × direction, so noise may make it negative), [N·m].
    direction : array_like
        +1 (positive motion, the paper's clockwise) or −1 per sample.
    fit : sequence of str
        Parameters to fit, any of :data:`FIT_PARAMETERS`.
    weights : str
        ``'bin_se'`` (group means weighted by 1/standard error, see the module notes) or ``'relative'``.
    loss : str
        ``'linear'`` or a robust loss of :func:`scipy.optimize.least_squares` (``'soft_l1'`` ...), applied to the
        weighted group residuals.
    f_scale : float, optional
        Soft margin of a robust loss (default 3 standard errors, or 3 % with ``weights='relative'``).
    bin_width_c : float
        Width of the temperature bins, [°C]; bins are centred on multiples of it.
    min_bin_samples : int
        Groups with fewer samples are left out of the fit.
    se_floor_rel : float
        Floor of a group's standard error as a fraction of its mean, [-].
    max_nfev : int
        Most model evaluations per least-squares solve.
    offset : str
        The calibration torque offset: ``'auto'`` (fitted when the data have a viscous-regime and a warmer
        plateau), ``'on'`` or ``'off'``.
    calibration_se_nm : float, optional
        1-sigma uncertainty of the calibration's no-load torque T_0, [N·m]; the offset is compared with it.
    time_s : array_like, optional
        Time of every sample (stamps), [s]; default the sample order (used by the batch-means weights).
    exact : bool
        Evaluate the model per sample (the reference; slow for many samples) instead of per fine bin.

    Returns
    -------
    RefitResult

    Raises
    ------
    FitError
        Too few samples (< 20, or no group with ``min_bin_samples``), non-finite data, unknown parameters, a fit
        that does not converge or diverges, or data that determine none of the requested parameters.
    """
    t = np.asarray(temperature_c, dtype=float)
    n = np.abs(np.asarray(speed_rpm, dtype=float))
    y = np.asarray(measured_abs_nm, dtype=float)
    d = np.asarray(direction, dtype=float)
    _check_options(tuple(fit), weights, loss, bin_width_c, offset, calibration_se_nm)
    _check_inputs(base, t, n, y, d)
    stats = SufficientStats.from_arrays(t, n, y, d, time=time_s, exact=exact)
    return refit_stats(base, stats, fit=fit, weights=weights, loss=loss, f_scale=f_scale, bin_width_c=bin_width_c,
                       min_bin_samples=min_bin_samples, se_floor_rel=se_floor_rel, max_nfev=max_nfev, offset=offset,
                       calibration_se_nm=calibration_se_nm)


def refit_stats(base: AxisParams, stats: SufficientStats, *, fit: Sequence[str] = DEFAULT_FIT,
                weights: str = 'bin_se', loss: str = 'linear', f_scale: float | None = None,
                bin_width_c: float = 5.0, min_bin_samples: int = MIN_BIN_SAMPLES, se_floor_rel: float = 0.002,
                max_nfev: int = 200, offset: str = 'auto', calibration_se_nm: float | None = None) -> RefitResult:
    """:func:`refit_model` on sufficient statistics (of one axis; e.g. accumulated while streaming a log).

    The cost depends on the number of fine bins, not on the number of samples. Parameters as
    :func:`refit_model`; ``bin_width_c`` must not be finer than the statistics' temperature resolution.

    Raises
    ------
    FitError
        As :func:`refit_model`.
    """
    fit = tuple(fit)
    _check_options(fit, weights, loss, bin_width_c, offset, calibration_se_nm)
    if base.walther_b >= 0.0:
        raise FitError('the base walther_b must be < 0')
    if not stats.exact and bin_width_c < stats.temperature_resolution_c * (1.0 - 1e-9):
        msg = (f"the temperature bin width {bin_width_c:g} degC is finer than the statistics' resolution "
               f'{stats.temperature_resolution_c:g} degC')
        raise FitError(msg)
    n_total = stats.n_samples
    if n_total < MIN_SAMPLES:
        msg = f'too few samples: {n_total} (need at least {MIN_SAMPLES})'
        raise FitError(msg)
    pts = _points(stats)
    for label, arr in (('temperature', pts.t), ('speed', pts.n), ('measured torque', pts.y)):
        if not np.all(np.isfinite(arr)):
            msg = f'non-finite data: some samples have a NaN or infinite {label}'
            raise FitError(msg)
    if np.any(pts.n <= 0.0):
        raise FitError('some samples have zero speed: the direction of friction is undefined')
    if np.any(pts.t < MODEL_T_MIN_C) or np.any(pts.t > MODEL_T_MAX_C):
        raise FitError(f'temperatures must lie in [{MODEL_T_MIN_C:g}, {MODEL_T_MAX_C:g}] degC for this model')
    groups = _group(pts, bin_width_c, max(int(min_bin_samples), 2))
    if groups.size.shape[0] == 0:
        msg = (f'too few samples per temperature bin: no ({bin_width_c:g} degC bin, direction, speed) group has '
               f'{min_bin_samples} samples or more ({n_total} samples in {len(groups.all_keys)} groups)')
        raise FitError(msg)
    used = groups.of >= 0
    try:
        model = SampleModel(base, pts.t, pts.n, pts.d)
    except GimbalFrictionError as err:
        msg = f'the base model cannot be evaluated at the data: {err}'
        raise FitError(msg) from None
    v0 = model.values()
    tau0 = model.torque_nmm(v0) * NM_PER_NMM
    idx = groups.of[used]
    y_mean = _group_mean(idx, groups.size, pts.weight[used], pts.y[used])
    if weights == 'bin_se':
        se = _group_se(stats, pts, groups, tau0, np.abs(y_mean), se_floor_rel)
        f_default = 3.0
    else:
        se = np.maximum(np.abs(y_mean), 1e-12)
        f_default = 0.03
    scale = f_default if f_scale is None else float(f_scale)
    if not (math.isfinite(scale) and scale > 0.0):
        raise FitError('f_scale must be > 0')

    upper0 = model.upper_branch(v0)
    visc_temps0 = _distinct_viscous_temperatures(pts, groups, upper0, min_bin_samples)
    sel_x = used & upper0 if np.any(used & upper0) else used
    x_ref = float(np.average(model.x[sel_x], weights=pts.weight[sel_x]))
    problem = _Problem(model, pts, groups, y_mean, se, x_ref, loss, scale, max_nfev, weights == 'bin_se')

    requested = [name for name in FIT_PARAMETERS if name in fit]
    reasons = _a_priori_reasons(base, model, pts, used, requested, visc_temps0, groups)
    offset_on, offset_why = _offset_mode(offset, visc_temps0, groups, requested)
    # the data could fix an offset (a cold and a warm plateau): if the fit set does not, say what it costs
    offset_separable = offset != 'off' and bool(visc_temps0) and bool(set(groups.t_bin.tolist()) - set(visc_temps0))
    active = [name for name in requested if name not in reasons]
    if offset_on:
        active.append(OFFSET)
    else:
        reasons[OFFSET] = offset_why

    sol: _Solution | None = None
    visc_temps = visc_temps0
    while any(name in requested for name in active):
        # sensitivity checks at the start (an exactly degenerate problem would not converge) and at the solution
        drop_reasons = _degenerate(active, problem.jacobian(active, problem.internal0(active)))
        if drop_reasons:
            reasons.update(drop_reasons)
            active = [name for name in active if name not in drop_reasons]
            continue
        sol = problem.solve(active)
        drop_reasons = _degenerate(active, sol.jac_internal)
        if drop_reasons:
            reasons.update(drop_reasons)
            active = [name for name in active if name not in drop_reasons]
            continue
        rel = _relative_se(problem, active, sol)
        worst = max(range(len(active)), key=lambda k: rel[k])
        if rel[worst] > MAX_RELATIVE_SE:
            reasons[active[worst]] = _se_reason(active[worst], rel[worst])
            active.pop(worst)
            continue
        upper1 = model.upper_branch(sol.values)
        visc_temps = _distinct_viscous_temperatures(pts, groups, upper0 & upper1, min_bin_samples)
        visc_active = [name for name in active if name in VISCOSITY_PARAMETERS]
        if len(visc_active) > len(visc_temps):
            drop = visc_active[-1]
            reasons[drop] = (f'under the refitted viscosity only {len(visc_temps)} distinct temperature(s) remain in '
                             f"Palmgren's upper branch (nu*n >= {PALMGREN_THRESHOLD:g})")
            active.remove(drop)
            continue
        break
    if sol is None or not any(name in requested for name in active):
        why = '; '.join(f'{name}: not identifiable: {reasons[name]}' for name in requested)
        msg = f'the data determine none of the requested parameters ({why})'
        raise FitError(msg)
    return _result(base, stats, problem, groups, model, pts, tau0, upper0, visc_temps, requested, active, reasons,
                   sol, offset, calibration_se_nm, offset_separable)


def _result(base: AxisParams, stats: SufficientStats, problem: _Problem, groups: _Groups, model: SampleModel,
            pts: _Points, tau0: Array, upper0: NDArray[np.bool_], visc_temps: list[float], requested: list[str],
            active: list[str], reasons: dict[str, str], sol: _Solution, offset_mode: str,
            calibration_se_nm: float | None, offset_separable: bool = False) -> RefitResult:
    cov_int, dof = _covariance(sol, problem.absolute)
    cov = sol.to_raw @ cov_int @ sol.to_raw.T
    se_active = dict(zip(active, np.sqrt(np.abs(np.diag(cov))).tolist(), strict=False))
    q = float(stdtrit(dof, 0.975)) if dof > 0 else Z95
    v0 = model.values()
    fitted, ses, cis, ident = {}, {}, {}, {}
    for name in requested:
        if name in se_active:
            value, s = sol.values[name], se_active[name]
            fitted[name], ses[name] = value, s
            cis[name] = (value - q * s, value + q * s)
            ident[name] = Identifiability(True, '')
        else:
            fitted[name], ses[name] = v0[name], math.nan
            cis[name] = (math.nan, math.nan)
            ident[name] = Identifiability(False, reasons[name])
    written = [name for name in active if name != OFFSET]
    try:
        params = base.replace(**{name: fitted[name] for name in written})
    except ConfigError as err:
        msg = f'the refitted parameters are not valid: {err}'
        raise FitError(msg) from None
    # the refitted model of the measurement (and the friction alone): the one function report --compare averages too
    tau1 = measurement_model_nmm(params, pts.t, pts.n, pts.d, sol.values[OFFSET]) * NM_PER_NMM
    fric1 = measurement_model_nmm(params, pts.t, pts.n, pts.d) * NM_PER_NMM
    upper1 = model.upper_branch(sol.values)
    nu0 = model.viscosity_cst(v0)
    nu1 = model.viscosity_cst(sol.values)
    used = groups.of >= 0
    c = pts.weight
    n_all = len(groups.all_keys)
    ai = groups.all_index

    def gmean(values: Array) -> Array:
        return np.bincount(ai, weights=c * values, minlength=n_all) / groups.all_count

    def grms(model_nm: Array) -> Array:
        return np.sqrt(np.bincount(ai, weights=pts.m2 + c * (pts.y - model_nm) ** 2, minlength=n_all)
                       / groups.all_count)

    t_mean, n_mean, y_mean = gmean(pts.t), gmean(pts.n), gmean(pts.y)
    m0, m1, f1 = gmean(tau0), gmean(tau1), gmean(fric1)
    r0, r1 = grms(tau0), grms(tau1)
    nuv0, nuv1 = gmean(nu0), gmean(nu1)
    n_up = np.bincount(ai, weights=c * (upper0 & upper1), minlength=n_all)
    se_by_group = dict(zip(np.flatnonzero(groups.used).tolist(), problem.se.tolist(), strict=False))
    bins = []
    for j, key in enumerate(groups.all_keys):
        cnt = int(round(float(groups.all_count[j])))
        bins.append(BinStats(
            temperature_bin_c=key[0], temperature_c=float(t_mean[j]), direction=int(key[1]),
            speed_rpm=float(n_mean[j]), n=cnt, used=bool(groups.used[j]),
            viscous=bool(n_up[j] >= 0.5 * cnt and n_up[j] >= 1),
            measured_mean_nm=float(y_mean[j]), measured_se_nm=float(se_by_group.get(j, math.nan)),
            model_before_nm=float(m0[j]), model_after_nm=float(m1[j]),
            rms_before_nm=float(r0[j]), rms_after_nm=float(r1[j]),
            viscosity_before_cst=float(nuv0[j]), viscosity_after_cst=float(nuv1[j]), friction_after_nm=float(f1[j])))
    viscosity = _viscosity_intervals(model, pts, groups, upper0 & upper1, visc_temps, v0, sol.values, active, cov, q)
    off = _offset_result(offset_mode, reasons, se_active, sol, q, stats, base, calibration_se_nm)
    warnings = []
    if off.estimated and off.exceeds_calibration:
        warnings.append(
            f'torque offset {1e3 * off.value_nm:+.4g} N*mm exceeds the calibration uncertainty (T_0 1-sigma '
            f'{1e3 * off.calibration_se_nm:.3g} N*mm): the no-load current is probably off (I_0 = '
            f'{off.implied_no_load_current_a:.6g} A would remove it; configured {off.no_load_current_a:.6g} A), or the '
            'warm friction differs from the model. The fitted offset already keeps it out of the lubricant: check '
            'that --calibration is the calibration the logs were measured with, recalibrate (calibrate-kt) and '
            'replay or re-log with the new I_0, and refit with both directions (do not add palmgren_factor: it '
            'switches the offset off and puts the calibration error into the viscosity)')
    confounding = NOT_CHECKED
    if offset_separable and not off.estimated:
        confounding = _offset_confounding(problem, sol, active, model, viscosity, se_active, off,
                                          calibration_se_nm)
        if confounding.confounded:
            warnings.append(_confounding_text(confounding, reasons.get(OFFSET, '')))
    check = decide([BinCheck(b.temperature_bin_c, b.temperature_c, b.direction, b.speed_rpm, b.n, b.measured_mean_nm,
                             b.model_after_nm, b.measured_se_nm) for b in bins if b.used],
                   len(active), viscous_bins=sorted({b.temperature_bin_c for b in bins if b.used and b.viscous}))
    n_used = float(c[used].sum())
    message = (f'fitted {", ".join(_label(n) for n in active)} from {int(round(n_used))} samples in '
               f'{groups.size.shape[0]} groups, {int(np.count_nonzero(used))} bins ({sol.nfev} evaluations: '
               f'{sol.message})')
    return RefitResult(
        fitted=fitted, base={name: v0[name] for name in requested}, standard_errors=ses, confidence_intervals=cis,
        identifiability=ident, params=params,
        rms_before_nm=float(np.sqrt(np.sum((pts.m2 + c * (pts.y - tau0) ** 2)[used]) / n_used)),
        rms_after_nm=float(np.sqrt(np.sum((pts.m2 + c * (pts.y - tau1) ** 2)[used]) / n_used)),
        bins=tuple(bins), viscous_temperatures_c=tuple(visc_temps), viscosity=viscosity,
        n_samples=int(round(n_used)), n_dropped=int(round(float(c[~used].sum()))), cost=sol.cost,
        success=sol.status > 0, message=message, offset=off, warnings=tuple(warnings),
        n_bins=int(np.count_nonzero(used)), offset_confounding=confounding, fit_check=check)
def _viscosity_intervals(model: SampleModel, pts: _Points, groups: _Groups, upper: NDArray[np.bool_],
                         visc_temps: list[float], v0: Mapping[str, float], v1: Mapping[str, float],
                         active: Sequence[str], cov: Array, q: float) -> tuple[ViscosityInterval, ...]:
    names = [name for name in active if name in VISCOSITY_PARAMETERS]
    if not names:
        return ()
    k = [list(active).index(name) for name in names]
    c = cov[np.ix_(k, k)]
    out = []
    used = groups.of >= 0
    vm = model.base.viscosity_model
    col = {'walther_a': 0, 'walther_b': 1, 'viscosity_offset_cst': 2}
    for t_bin in visc_temps:
        sel = used & upper & np.isin(groups.of, np.flatnonzero(groups.t_bin == t_bin))
        t_c = float(np.average(pts.t[sel], weights=pts.weight[sel]))
        T = np.array([t_c + model.base.kelvin_offset_k])
        nu0 = float(nu_Walther(T, v0['walther_a'], v0['walther_b'], v0['viscosity_offset_cst'], vm)[0])
        nu1 = float(nu_Walther(T, v1['walther_a'], v1['walther_b'], v1['viscosity_offset_cst'], vm)[0])
        jac = nu_Walther_fitting_jacobian(T, v1['walther_a'], v1['walther_b'], v1['viscosity_offset_cst'], vm)[0]
        g = np.array([jac[col[name]] for name in names]) / nu1          # d ln ν / dθ
        half = q * math.sqrt(max(float(g @ c @ g), 0.0))
        out.append(ViscosityInterval(t_c, nu0, nu1, nu1 * math.exp(-half), nu1 * math.exp(half)))
    return tuple(out)


def check_model(params: AxisParams, stats: SufficientStats, *, offset_nm: float = 0.0, bin_width_c: float = 5.0,
                min_bin_samples: int = MIN_BIN_SAMPLES, se_floor_rel: float = 0.002) -> FitCheck:
    """The lack-of-fit check (:mod:`~gimbal_friction.refit.fit_check`) of a model, ``params`` with the calibration
    torque offset ``offset_nm`` [N·m], against statistics it was not fitted to (e.g. the direction a
    ``--direction cw`` refit left out): the same groups, standard errors and test as a refit's own check, with no
    fitted parameter. Not checked when the statistics hold no group of ``min_bin_samples``.

    >>> t = np.repeat([-40.0, 20.0], 200)
    >>> d = np.tile([1.0, -1.0], 200)
    >>> rng = np.random.default_rng(1)
    >>> tau = measurement_model_nmm(AxisParams(), t, np.full(t.shape, 1 / 3), d) * 1e-3
    >>> stats = SufficientStats.from_arrays(t, np.full(t.shape, 1 / 3), tau * (1 + rng.normal(0, 0.01, t.size)), d)
    >>> check_model(AxisParams(), stats).fits, check_model(AxisParams(walther_a=8.64), stats).fits
    (True, False)
    """
    if stats.n_samples == 0:
        return FIT_NOT_CHECKED
    pts = _points(stats)
    ok = np.isfinite(pts.t) & (pts.t >= MODEL_T_MIN_C) & (pts.t <= MODEL_T_MAX_C) & (pts.n > 0.0)
    if not np.all(ok):
        return FIT_NOT_CHECKED
    groups = _group(pts, bin_width_c, max(int(min_bin_samples), 2))
    if groups.size.shape[0] == 0:
        return FIT_NOT_CHECKED
    model = SampleModel(params, pts.t, pts.n, pts.d)
    tau = model.torque_nmm(model.values({OFFSET: offset_nm})) * NM_PER_NMM
    used = groups.of >= 0
    idx = groups.of[used]
    y_mean = _group_mean(idx, groups.size, pts.weight[used], pts.y[used])
    m_mean = _group_mean(idx, groups.size, pts.weight[used], tau[used])
    t_mean = _group_mean(idx, groups.size, pts.weight[used], pts.t[used])
    n_mean = _group_mean(idx, groups.size, pts.weight[used], pts.n[used])
    se = _group_se(stats, pts, groups, tau, np.abs(y_mean), se_floor_rel)
    bins = [BinCheck(float(groups.t_bin[j]), float(t_mean[j]), int(groups.direction[j]), float(n_mean[j]),
                     int(round(float(groups.size[j]))), float(y_mean[j]), float(m_mean[j]), float(se[j]))
            for j in range(groups.size.shape[0])]
    upper = model.upper_branch(model.values())
    viscous = _distinct_viscous_temperatures(pts, groups, upper, min_bin_samples)
    return decide(bins, 0, viscous_bins=viscous)
