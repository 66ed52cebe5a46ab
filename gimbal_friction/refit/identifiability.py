"""Which parameters the refit's data can determine (a priori and from the solution's standard errors), the
calibration offset's result and its confounding check."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.physics.model import palmgren_threshold_temperature
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.viscosity import nu_Walther, nu_Walther_fitting_jacobian
from gimbal_friction.refit.model import SampleModel
from gimbal_friction.refit.problem import _covariance, _Groups, _label, _Points, _Problem, _Solution
from gimbal_friction.refit.results import (
    ASYMMETRY_PARAMETERS,
    MAX_ASYMMETRY_SE,
    MAX_CONDITION,
    MAX_RELATIVE_SE,
    NOT_CHECKED,
    OFFSET,
    PALMGREN_THRESHOLD,
    VISCOSITY_PARAMETERS,
    Z95,
    Array,
    OffsetConfounding,
    OffsetResult,
    ViscosityInterval,
)
from gimbal_friction.refit.sufficient import SufficientStats


def _a_priori_reasons(base: AxisParams, model: SampleModel, pts: _Points, used: NDArray[np.bool_],
                      requested: list[str], visc_temps0: list[float], groups: _Groups) -> dict[str, str]:
    """Parameters the data cannot determine, known before any fit, and why."""
    reasons: dict[str, str] = {}
    pos = used & (pts.d > 0)
    neg = used & (pts.d < 0)
    if 'scale_positive' in requested and not np.any(pos):
        reasons['scale_positive'] = 'no samples moving in the positive direction'
    if 'scale_negative' in requested and not np.any(neg):
        reasons['scale_negative'] = 'no samples moving in the negative direction'
    for name in ASYMMETRY_PARAMETERS:
        if name not in requested:
            continue
        if not (np.any(pos) and np.any(neg)):
            reasons[name] = 'needs samples moving in both directions'
            continue
        w = model.w
        if name == 'direction_asymmetry_cold' and not (np.any(pos & (w < 1.0)) and np.any(neg & (w < 1.0))):
            reasons[name] = (f'no samples of both directions below direction_asymmetry_warm_c = '
                             f'{base.direction_asymmetry_warm_c:g} degC, where the cold anchor acts')
        if name == 'direction_asymmetry_warm' and not (np.any(pos & (w > 0.0)) and np.any(neg & (w > 0.0))):
            reasons[name] = (f'no samples of both directions above direction_asymmetry_cold_c = '
                             f'{base.direction_asymmetry_cold_c:g} degC, where the warm anchor acts')
    visc = [name for name in requested if name in VISCOSITY_PARAMETERS]
    n_max = float(pts.n[used].max())
    if not visc_temps0:
        t_thr = palmgren_threshold_temperature(base, n_max)
        where = f'; at {n_max:.3g} rpm that needs t <= {t_thr:.0f} degC' if math.isfinite(t_thr) else ''
        for name in visc:
            reasons[name] = (f"no samples in Palmgren's upper branch (nu*n >= {PALMGREN_THRESHOLD:g}{where}), "
                             'where the viscous torque depends on viscosity')
    else:
        temps = ', '.join(f'{x:g}' for x in visc_temps0)
        for i, name in enumerate(visc):
            if i >= len(visc_temps0):
                reasons[name] = (f"needs samples at {i + 1} distinct temperatures in Palmgren's upper branch "
                                 f'(nu*n >= {PALMGREN_THRESHOLD:g}), the data have {len(visc_temps0)} ({temps} '
                                 f'degC), taken by {", ".join(visc[:i])}; add a colder plateau or faster runs')
    del groups
    return reasons


def _offset_mode(mode: str, visc_temps0: list[float], groups: _Groups, requested: list[str]) -> tuple[bool, str]:
    """Whether the offset is fitted, and why (not)."""
    if mode == 'off':
        return False, 'switched off'
    warm = sorted({float(x) for x in groups.t_bin} - set(visc_temps0))
    if mode == 'on':
        return True, 'switched on'
    if 'palmgren_factor' in requested:
        return False, ('auto: off, palmgren_factor is fitted and its low-speed floor is a constant torque too (the '
                       'two are told apart only weakly); --offset on fits both')
    if visc_temps0 and warm:
        return True, (f'auto: plateaus in the viscous regime ({", ".join(f"{x:g}" for x in visc_temps0)} degC) and '
                      f'below it ({", ".join(f"{x:g}" for x in warm)} degC)')
    return False, ("auto: off, needs both a plateau in Palmgren's upper branch (cold) and one below it (warm) "
                   f'(viscous: {", ".join(f"{x:g}" for x in visc_temps0) or "none"}; warm: '
                   f'{", ".join(f"{x:g}" for x in warm) or "none"} degC)')


def _se_reason(name: str, rel: float) -> str:
    if not math.isfinite(rel):
        return 'its standard error cannot be estimated (no more temperature groups than parameters)'
    if name in ASYMMETRY_PARAMETERS:
        return f'standard error {rel * 2 * MAX_ASYMMETRY_SE:.3g} of an asymmetry (> {MAX_ASYMMETRY_SE:g})'
    what = 'effect on the viscosity' if name in VISCOSITY_PARAMETERS[:2] else 'value'
    return f'standard error {100 * rel:.0f} % of its {what} (> {100 * MAX_RELATIVE_SE:.0f} %)'


def _degenerate(active: Sequence[str], J: Array) -> dict[str, str]:
    """Parameters to hold: every one with a (nearly) zero jacobian column, else the lowest-priority one of a
    collinear set (SVD of the column-normalised weighted jacobian)."""
    norms = np.linalg.norm(J, axis=0)
    top = float(norms.max()) if norms.size else 0.0
    zero = {name: 'the data do not depend on it (zero sensitivity)'
            for name, nk in zip(active, norms, strict=False) if not (top > 0.0 and nk > 1e-9 * top)}
    if zero or len(active) < 2:
        return zero
    _, s, vt = np.linalg.svd(J / norms, full_matrices=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0.0 else math.inf
    if cond <= MAX_CONDITION:
        return {}
    involved = [name for name, c in zip(active, vt[-1], strict=False) if abs(c) > 0.1]
    drop = involved[-1]
    others = ', '.join(_label(name) for name in involved if name != drop)
    return {drop: f'collinear with {others}: the data determine only a combination (condition number {cond:.3g})'}


def _relative_se(problem: _Problem, active: Sequence[str], sol: _Solution) -> list[float]:
    """Relative standard error of each active parameter: SE/|value|; for a Walther constant the relative
    viscosity error it causes over the viscous-regime data (centred form); for c1 SE/max(|c1|, 1 cSt); for an
    asymmetry SE/(2·MAX_ASYMMETRY_SE); the offset (a nuisance) is never dropped for its SE."""
    cov, _ = _covariance(sol, problem.absolute)
    se_int = np.sqrt(np.abs(np.diag(cov)))
    model = problem.model
    v = sol.values
    upper = model.upper_branch(v) & problem.used
    sel = upper if np.any(upper) else problem.used
    T = model.T[sel]
    nu = nu_Walther(T, v['walther_a'], v['walther_b'], v['viscosity_offset_cst'], model.base.viscosity_model)
    jac = nu_Walther_fitting_jacobian(T, v['walther_a'], v['walther_b'], v['viscosity_offset_cst'],
                                      model.base.viscosity_model)
    dlnnu_da = jac[:, 0] / np.maximum(nu, 1e-300)
    out = []
    for k, name in enumerate(active):
        if name == 'walther_a':
            out.append(float(se_int[k] * np.max(np.abs(dlnnu_da))))
        elif name == 'walther_b':
            out.append(float(se_int[k] * np.max(np.abs(dlnnu_da * (model.x[sel] - problem.x_ref)))))
        elif name == 'viscosity_offset_cst':
            out.append(float(se_int[k] / max(abs(v[name]), 1.0)))
        elif name in ASYMMETRY_PARAMETERS:
            out.append(float(se_int[k] / (2.0 * MAX_ASYMMETRY_SE)))
        elif name == OFFSET:
            out.append(0.0)
        else:
            out.append(float(se_int[k] / abs(v[name])) if v[name] != 0.0 else math.inf)
    return [x if math.isfinite(x) else math.inf for x in out]




#: Without a calibration uncertainty, the confounding check uses an I_0 error of this much [A].
REFERENCE_I0_ERROR_A = 1e-3


def _offset_confounding(problem: _Problem, sol: _Solution, active: Sequence[str], model: SampleModel,
                        viscosity: Sequence[ViscosityInterval], se_active: Mapping[str, float], off: OffsetResult,
                        calibration_se_nm: float | None) -> OffsetConfounding:
    """Linear response of the fitted parameters (and of ν where the data determine it) to a constant torque
    offset of every group mean: the calibration's T_0 1-sigma when given, else K_T × 1 mA of I_0."""
    kt = off.torque_constant_nm_per_a
    if calibration_se_nm is not None and calibration_se_nm > 0.0:
        ref, label = float(calibration_se_nm), 'the calibration T_0 1-sigma'
    else:
        ref = kt * REFERENCE_I0_ERROR_A
        label = f'an I_0 error of {1e3 * REFERENCE_I0_ERROR_A:g} mA at K_T = {kt:.4g} N*m/A'
    J = sol.jac_internal
    try:  # r = (y - model)/se: y + c changes r by c/se; Gauss-Newton step of the solution
        d_int = -np.linalg.lstsq(J, ref / problem.se, rcond=None)[0]
    except np.linalg.LinAlgError:
        return NOT_CHECKED
    d_raw = sol.to_raw @ d_int
    names = list(active)
    shifts = {name: float(d_raw[k]) for k, name in enumerate(names) if name != OFFSET}
    in_se = {name: abs(x) / se_active[name] if se_active.get(name, 0.0) > 0.0 else math.inf
             for name, x in shifts.items()}
    visc = [name for name in names if name in VISCOSITY_PARAMETERS]
    nu_shift = []
    if visc:
        col = {'walther_a': 0, 'walther_b': 1, 'viscosity_offset_cst': 2}
        v1 = sol.values
        for vi in viscosity:
            T = np.array([vi.temperature_c + model.base.kelvin_offset_k])
            jac = nu_Walther_fitting_jacobian(T, v1['walther_a'], v1['walther_b'], v1['viscosity_offset_cst'],
                                              model.base.viscosity_model)[0]
            g = np.array([jac[col[name]] for name in visc]) / vi.after_cst
            nu_shift.append((vi.temperature_c, float(math.expm1(float(g @ np.array([shifts[n] for n in visc]))))))
    confounded = tuple(name for name, k in in_se.items() if k > 1.0)
    return OffsetConfounding(True, ref, label, shifts, in_se, tuple(nu_shift), confounded)


def _confounding_text(c: OffsetConfounding, why: str) -> str:
    """The warning of a fit set that cannot separate its parameters from a calibration offset (with numbers)."""
    moves = ', '.join(f'{name} by {c.shifts[name]:+.3g} ({c.shifts_in_se[name]:.1f} standard errors)'
                      for name in c.confounded)
    nu = ''.join(f', the viscosity at {t:.1f} degC by {100 * x:+.1f} %' for t, x in c.viscosity_shift_rel[:1])
    held = 'switched off' if why.startswith('auto') else (why or 'not fitted')
    return (f'{", ".join(c.confounded)} cannot be told apart from a calibration torque offset here (the offset is '
            f'{held} with this fit set), so any offset goes into them: an offset of '
            f'{1e3 * c.reference_offset_nm:.3g} N*mm ({c.reference}) moves {moves}{nu}. To keep the calibration '
            'out of the lubricant, refit without palmgren_factor (the offset is then fitted; both directions with '
            '--fit walther_a,direction_asymmetry where the unit has a CW/CCW asymmetry), or check the calibration '
            '(--calibration FILE from calibrate-kt)')


def _offset_result(mode: str, reasons: dict[str, str], se_active: dict[str, float], sol: _Solution, q: float,
                   stats: SufficientStats, base: AxisParams, calibration_se_nm: float | None) -> OffsetResult:
    kt = stats.tally.torque_constant_nm_per_a
    i0 = stats.tally.no_load_current_a
    kt = kt if math.isfinite(kt) else base.torque_constant_nm_per_a
    i0 = i0 if math.isfinite(i0) else base.no_load_current_a
    cal = math.nan if calibration_se_nm is None else float(calibration_se_nm)
    if OFFSET not in se_active:
        return OffsetResult(mode, False, reasons.get(OFFSET, ''), calibration_se_nm=cal, torque_constant_nm_per_a=kt,
                            no_load_current_a=i0)
    value, s = sol.values[OFFSET], se_active[OFFSET]
    exceeds = None if calibration_se_nm is None else bool(abs(value) - Z95 * s > cal)
    why = 'switched on' if mode == 'on' else 'auto: plateaus in the viscous regime and below it'
    return OffsetResult(mode, True, why, value, s, (value - q * s, value + q * s), cal, exceeds, kt, i0,
                        i0 + value / kt)
