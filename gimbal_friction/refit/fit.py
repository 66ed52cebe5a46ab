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

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.special import stdtrit

from gimbal_friction.common.errors import ConfigError, FitError, GimbalFrictionError
from gimbal_friction.common.units import NM_PER_NMM
from gimbal_friction.estimation.plateaus import plateau_of
from gimbal_friction.physics.direction import ARRAY, asymmetry_weight, direction_asymmetry, direction_factor
from gimbal_friction.physics.friction import PALMGREN_THRESHOLD_CST_RPM, viscous_torque_Palmgren_1959
from gimbal_friction.physics.model import friction_torque, palmgren_threshold_temperature
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, AxisParams
from gimbal_friction.physics.thermal import radial_coupling
from gimbal_friction.physics.viscosity import nu_Walther, nu_Walther_fitting_jacobian, walther_abscissa
from gimbal_friction.refit.sufficient import SufficientStats

Array = NDArray[np.float64]

#: Parameters :func:`refit_model` can fit, in priority order (the earlier one is kept when the data can
#: determine only some of them).
FIT_PARAMETERS = ('walther_a', 'walther_b', 'viscosity_offset_cst', 'palmgren_factor',
                  'sliding_friction_coefficient', 'scale_positive', 'scale_negative', 'direction_asymmetry_cold',
                  'direction_asymmetry_warm')
#: The Walther constants of the lubricant (Eq. 20/21).
VISCOSITY_PARAMETERS = ('walther_a', 'walther_b', 'viscosity_offset_cst')
#: The temperature-dependent direction asymmetry (core/direction.py).
ASYMMETRY_PARAMETERS = ('direction_asymmetry_cold', 'direction_asymmetry_warm')
#: Name of the nuisance torque offset inside the fit [N·m] (not a model parameter).
OFFSET = 'torque_offset_nm'
OFFSET_MODES = ('auto', 'on', 'off')
#: Palmgren's branch threshold ν·n of Eq. (9), [cSt·rpm].
PALMGREN_THRESHOLD = PALMGREN_THRESHOLD_CST_RPM
#: Losses accepted (those of :func:`scipy.optimize.least_squares`).
LOSSES = ('linear', 'soft_l1', 'huber', 'cauchy', 'arctan')
WEIGHTS = ('bin_se', 'relative')

#: Refusal thresholds: samples overall, samples per group.
MIN_SAMPLES = 20
MIN_BIN_SAMPLES = 5
#: A parameter whose relative standard error exceeds this is not identifiable [-].
MAX_RELATIVE_SE = 0.5
#: An asymmetry whose standard error exceeds this is not identifiable [-] (absolute: its value may be 0).
MAX_ASYMMETRY_SE = 0.1
#: Condition number of the column-normalised jacobian above which parameters are collinear [-].
MAX_CONDITION = 1e3
#: Grid step of the tabulated M_R and S [°C].
GRID_STEP_C = 0.05
#: Speed groups are geometric bins of this ratio [-].
SPEED_BIN_RATIO = 1.25
#: Two-sided 95 % normal quantile used to compare the offset with the calibration's uncertainty [-].
Z95 = 1.959963984540054


class Identifiability(NamedTuple):
    """Whether the data determine a parameter, and if not, why."""

    identifiable: bool
    reason: str

    def __str__(self) -> str:
        return 'identifiable' if self.identifiable else f'not identifiable: {self.reason}'


class BinStats(NamedTuple):
    """One (temperature bin, direction, speed) group of samples, before and after the fit. Torques [N·m]."""

    temperature_bin_c: float    #: bin centre [°C]
    temperature_c: float        #: mean temperature of the group's samples [°C]
    direction: int              #: +1 (positive motion, the paper's CW) or −1
    speed_rpm: float            #: mean speed [rpm]
    n: int                      #: samples [-]
    used: bool                  #: in the fit (at least ``min_bin_samples`` samples)
    viscous: bool               #: in Palmgren's upper branch (ν·n ≥ 2000) under base and fitted parameters
    measured_mean_nm: float     #: mean |τ| measured along the motion [N·m]
    measured_se_nm: float       #: standard error of that mean used for the weight [N·m]
    model_before_nm: float      #: group mean of the base model [N·m]
    model_after_nm: float       #: group mean of the refitted model of the measurement (friction + offset) [N·m]
    rms_before_nm: float        #: RMS of (measured − base model) over the group's samples [N·m]
    rms_after_nm: float         #: RMS of (measured − refitted model) [N·m]
    viscosity_before_cst: float  #: ν at the mean temperature, base [mm²/s]
    viscosity_after_cst: float  #: ν at the mean temperature, refitted [mm²/s]
    friction_after_nm: float = math.nan  #: group mean of the refitted friction alone (no offset) [N·m]


class ViscosityInterval(NamedTuple):
    """Refitted viscosity where the data determine it, with its 95 % interval (delta method on ln ν)."""

    temperature_c: float   #: mean temperature of a viscous-regime bin [°C]
    before_cst: float      #: base ν [mm²/s]
    after_cst: float       #: refitted ν [mm²/s]
    low_cst: float         #: 95 % interval [mm²/s]
    high_cst: float


class OffsetResult(NamedTuple):
    """The constant torque offset of the measurement (calibration nuisance), see the module notes."""

    mode: str                          #: 'auto', 'on' or 'off'
    estimated: bool                    #: fitted (else held at 0)
    reason: str                        #: why it was (not) fitted
    value_nm: float = math.nan         #: c: measured |τ| = model + c [N·m]
    standard_error_nm: float = math.nan  #: 1-sigma [N·m]
    confidence_interval_nm: tuple[float, float] = (math.nan, math.nan)  #: 95 % [N·m]
    calibration_se_nm: float = math.nan  #: 1-sigma of the calibration's T_0 (NaN: not given) [N·m]
    exceeds_calibration: bool | None = None  #: |c| − 1.96 se > σ_T0 (None: no calibration uncertainty)
    torque_constant_nm_per_a: float = math.nan  #: K_T the data were measured with [N·m/A]
    no_load_current_a: float = math.nan  #: I_0 the data were measured with [A]
    implied_no_load_current_a: float = math.nan  #: I_0 that removes the offset, I_0 + c/K_T [A]


class OffsetConfounding(NamedTuple):
    """How far a calibration torque offset that the fit did not estimate moves the fitted parameters.

    Checked when the data could determine the offset (a viscous-regime and a warmer plateau) but the requested
    fit set switched it off or made it collinear (``palmgren_factor``: its low-speed floor is a constant torque
    too): any offset of the measurement then goes into the fitted parameters. The shifts are the linear response of
    the weighted least-squares solution to a constant torque ``reference_offset_nm`` added to every group mean.
    """

    checked: bool                   #: the check ran (see above)
    reference_offset_nm: float      #: the offset the shifts are for [N·m]
    reference: str                  #: what that offset is (the calibration's T_0 1-sigma, or 1 mA of I_0)
    shifts: dict[str, float]        #: parameter change for that offset [unit of the parameter]
    shifts_in_se: dict[str, float]  #: the same in standard errors of the parameter [-]
    viscosity_shift_rel: tuple[tuple[float, float], ...]  #: (temperature [°C], relative change of ν [-])
    confounded: tuple[str, ...]     #: parameters moved by more than one standard error


#: Not checked (the offset was fitted, switched off, or the data could not have determined it).
NOT_CHECKED = OffsetConfounding(False, math.nan, '', {}, {}, (), ())


class RefitResult(NamedTuple):
    """Outcome of :func:`refit_model`. Parameter dicts are keyed by the requested names, in priority order."""

    fitted: dict[str, float]                    #: refitted value, or the base value if not identifiable
    base: dict[str, float]                      #: value before the fit
    standard_errors: dict[str, float]           #: 1-sigma (NaN if not identifiable)
    confidence_intervals: dict[str, tuple[float, float]]  #: 95 % (NaN, NaN) if not identifiable
    identifiability: dict[str, Identifiability]
    params: AxisParams                          #: base with the refitted values
    rms_before_nm: float                        #: RMS residual of the samples used, base model [N·m]
    rms_after_nm: float                         #: same, refitted model (with the offset) [N·m]
    bins: tuple[BinStats, ...]                  #: per (temperature bin, direction, speed), sorted
    viscous_temperatures_c: tuple[float, ...]   #: bins in Palmgren's upper branch (base and fitted) [°C]
    viscosity: tuple[ViscosityInterval, ...]    #: refitted ν at those bins (empty if no Walther constant fitted)
    n_samples: int                              #: samples used in the fit
    n_dropped: int                              #: samples in groups too small to use
    cost: float                                 #: final least-squares cost (0.5 Σ ρ(r²)) [-]
    success: bool
    message: str
    offset: OffsetResult = OffsetResult('off', False, 'not requested')  #: calibration offset
    warnings: tuple[str, ...] = ()              #: things a user must look at (e.g. an offset beyond calibration)
    n_bins: int = 0                             #: fine bins the model was evaluated on [-]
    offset_confounding: OffsetConfounding = NOT_CHECKED  #: an offset the fit set could not separate

    @property
    def refitted(self) -> dict[str, float]:
        """Only the parameters that were determined and changed by the fit."""
        return {k: v for k, v in self.fitted.items() if self.identifiability[k].identifiable}


# ------------------------------------------------------------------------------------------------------------
# the model of the samples (or of the fine bins)


def _dML_dnu_Palmgren_1959(s0: float, nu0: Array, n: Array, d_m: Array) -> Array:
    """dM_L/dν of Eq. (9) (Palmgren 1959), [N·mm per mm²/s]: ``(2/3) M_L/ν`` in the upper branch ``ν n ≥ 2000``,
    0 in the lower one (where M_L does not depend on ν). Uses
    :func:`~gimbal_friction.physics.friction.viscous_torque_Palmgren_1959` for M_L."""
    m_l = viscous_torque_Palmgren_1959(s0, nu0, n, d_m)
    upper = nu0 * np.abs(n) >= PALMGREN_THRESHOLD
    safe = np.where(upper, nu0, 1.0)
    return np.where(upper, (2.0 / 3.0) * m_l / safe, 0.0)


class SampleModel:
    """|τ| of every sample (or fine bin) as a function of the fit parameters, with its analytic jacobian, [N·mm].

    M_R and S = M_S/μ come from the full model of ``base`` on a grid (they do not depend on the fit parameters);
    the pitch diameter d_m(t) likewise (steel expansion). Everything else is evaluated per call with the
    package's functions (Walther, Palmgren Eq. 9, the direction factor).

    Parameters
    ----------
    base : AxisParams
        Parameters held fixed (and the starting values of the fit).
    temperature_c, speed_rpm, direction : array_like
        Per sample: temperature [°C], speed magnitude [rpm], direction ±1.
    """

    def __init__(self, base: AxisParams, temperature_c: ArrayLike, speed_rpm: ArrayLike,
                 direction: ArrayLike) -> None:
        self.base = base
        self.t = np.asarray(temperature_c, dtype=float)
        self.n = np.abs(np.asarray(speed_rpm, dtype=float))
        self.d = np.where(np.asarray(direction, dtype=float) > 0.0, 1.0, -1.0)
        self.positive = self.d > 0.0
        lo = math.floor(float(self.t.min()) / GRID_STEP_C) * GRID_STEP_C - GRID_STEP_C
        hi = math.ceil(float(self.t.max()) / GRID_STEP_C) * GRID_STEP_C + GRID_STEP_C
        grid = lo + GRID_STEP_C * np.arange(int(round((hi - lo) / GRID_STEP_C)) + 1)
        unit = dataclasses.replace(base, sliding_friction_coefficient=1.0)
        res = friction_torque(unit, grid, 0.0)
        self.m_rolling = np.interp(self.t, grid, res.m_rolling_nmm)        # M_R of the axis [N·mm]
        self.s_unit = np.interp(self.t, grid, res.m_sliding_nmm)           # M_S at μ = 1 [N·mm]
        self.d_m = radial_coupling(base, self.t).d_m                       # [mm]
        self.T = self.t + base.kelvin_offset_k                             # [K]
        self.x = walther_abscissa(self.T, base.viscosity_model)                   # Walther abscissa [-]
        self.w = asymmetry_weight(base, self.t, ARRAY)                     # warm-anchor weight [-]

    def values(self, changes: Mapping[str, float] | None = None) -> dict[str, float]:
        """The fit parameters of ``base`` (and the offset, 0) with ``changes`` applied."""
        out = {name: float(getattr(self.base, name)) for name in FIT_PARAMETERS}
        out[OFFSET] = 0.0
        out.update({k: float(v) for k, v in (changes or {}).items()})
        return out

    def params(self, v: Mapping[str, float]) -> AxisParams:
        """``base`` with the fit parameters ``v`` (not validated: used inside the fit only)."""
        changes = cast('dict[str, Any]', {name: v[name] for name in FIT_PARAMETERS})
        return dataclasses.replace(self.base, **changes)

    def viscosity_cst(self, v: Mapping[str, float]) -> Array:
        """ν of every sample, Eq. (20)/(21), [mm²/s]."""
        return nu_Walther(self.T, v['walther_a'], v['walther_b'], v['viscosity_offset_cst'],
                          self.base.viscosity_model)

    def upper_branch(self, v: Mapping[str, float]) -> NDArray[np.bool_]:
        """Samples in Palmgren's upper branch ``ν·n ≥ 2000`` (M_L depends on ν), Eq. (9)."""
        return np.asarray(self.viscosity_cst(v) * self.n >= PALMGREN_THRESHOLD, dtype=bool)

    def torque_nmm(self, v: Mapping[str, float], *, offset: bool = True) -> Array:
        """|τ| of every sample, [N·mm] (with the offset, or the friction alone)."""
        tau = self._evaluate(v, ())[0]
        return tau if offset else tau - 1e3 * v[OFFSET]

    def jacobian_nmm(self, v: Mapping[str, float], names: Sequence[str]) -> Array:
        """d|τ|/dθ of every sample for the parameters ``names`` (raw, as in AxisParams; the offset per N·m),
        shape (n, len(names))."""
        return self._evaluate(v, names)[1]

    def _evaluate(self, v: Mapping[str, float], names: Sequence[str]) -> tuple[Array, Array]:
        model = self.base.viscosity_model
        a1, b1, c1, s0 = v['walther_a'], v['walther_b'], v['viscosity_offset_cst'], v['palmgren_factor']
        nu = nu_Walther(self.T, a1, b1, c1, model)
        z = float(self.base.bearings_per_axis)
        m_l = z * viscous_torque_Palmgren_1959(s0, nu, self.n, self.d_m)
        m = self.m_rolling + v['sliding_friction_coefficient'] * self.s_unit + m_l
        p = self.params(v)
        k = direction_factor(p, self.t, self.d, ARRAY)
        tau = k * m + 1e3 * v[OFFSET]
        if not names:
            return tau, np.empty((tau.shape[0], 0))
        dtau_dnu = k * z * _dML_dnu_Palmgren_1959(s0, nu, self.n, self.d_m)
        jac_nu = nu_Walther_fitting_jacobian(self.T, a1, b1, c1, model)       # dν/d(a1, b1, c1)
        a_t = direction_asymmetry(p, self.t, ARRAY)
        s_d = np.where(self.positive, p.scale_positive, -p.scale_negative)    # d k / d a
        cols = {
            'walther_a': dtau_dnu * jac_nu[:, 0],
            'walther_b': dtau_dnu * jac_nu[:, 1],
            'viscosity_offset_cst': dtau_dnu * jac_nu[:, 2],
            'palmgren_factor': k * m_l / s0 if s0 != 0.0 else k * 0.0,
            'sliding_friction_coefficient': k * self.s_unit,
            'scale_positive': np.where(self.positive, (1.0 + a_t) * m, 0.0),
            'scale_negative': np.where(self.positive, 0.0, (1.0 - a_t) * m),
            'direction_asymmetry_cold': s_d * (1.0 - self.w) * m,
            'direction_asymmetry_warm': s_d * self.w * m,
            OFFSET: np.full(tau.shape, 1e3),
        }
        return tau, np.column_stack([cols[name] for name in names])


# ------------------------------------------------------------------------------------------------------------
# points (fine bins), groups and weights


class _Points(NamedTuple):
    """Fine bins of the statistics: the model is evaluated at their mean temperature and speed."""

    weight: Array                # samples [-]
    t: Array                     # mean temperature [°C]
    n: Array                     # mean speed [rpm]
    d: Array                     # ±1
    y: Array                     # mean |τ| [N·m]
    m2: Array                    # Σ (y − ȳ)² [N²·m²]
    cell_point: NDArray[np.intp]  # point of every cell of the statistics


def _points(stats: SufficientStats) -> _Points:
    c = stats.samples
    if stats.exact:
        return _Points(c, stats.sum_t / c, stats.sum_n / c, stats.direction.astype(float), stats.mean_y, stats.m2_y,
                       np.arange(len(stats), dtype=np.intp))
    keys = np.column_stack([stats.t_index, stats.direction, stats.s_index])
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1).astype(np.intp)
    m = int(inverse.max()) + 1 if inverse.size else 0
    count = _sum(inverse, c, m)
    y = _sum(inverse, c * stats.mean_y, m) / count
    m2 = _sum(inverse, stats.m2_y + c * (stats.mean_y - y[inverse]) ** 2, m)
    d = np.zeros(m)
    d[inverse] = stats.direction
    return _Points(count, _sum(inverse, stats.sum_t, m) / count, _sum(inverse, stats.sum_n, m) / count, d, y, m2,
                   inverse)


def _sum(index: NDArray[np.intp], weights: Array, m: int) -> Array:
    """Sum of ``weights`` per ``index`` (0 … m−1)."""
    return np.asarray(np.bincount(index, weights=weights, minlength=m), dtype=np.float64)


class _Groups(NamedTuple):
    of: NDArray[np.intp]         # group of every point (−1: dropped)
    size: Array                  # samples per group
    t_bin: Array                 # bin centre [°C]
    direction: NDArray[np.int64]
    speed_bin: NDArray[np.int64]
    all_index: NDArray[np.intp]  # group of every point among all groups (used or not)
    all_count: Array
    all_keys: list[tuple[float, int, int]]
    used: NDArray[np.bool_]      # per entry of all_keys


def _group(pts: _Points, bin_width_c: float, min_bin_samples: int) -> _Groups:
    t_bin = plateau_of(pts.t, bin_width_c)  # the one plateau rule (replay's summary and report use it too)
    s_bin = np.round(np.log(pts.n) / math.log(SPEED_BIN_RATIO)).astype(np.int64)
    d = np.where(pts.d > 0, 1, -1).astype(np.int64)
    keys = np.column_stack([t_bin, d.astype(float), s_bin.astype(float)])
    uniq_arr, all_index = np.unique(keys, axis=0, return_inverse=True)
    all_index = all_index.reshape(-1).astype(np.intp)
    uniq = [(float(a), int(b), int(c)) for a, b, c in uniq_arr.tolist()]
    all_count = _sum(all_index, pts.weight, len(uniq))
    used = all_count >= min_bin_samples
    remap = np.full(len(uniq), -1, dtype=np.intp)
    remap[used] = np.arange(int(used.sum()))
    index = remap[all_index]
    sel = np.flatnonzero(used)
    return _Groups(index, all_count[used], np.array([uniq[i][0] for i in sel]),
                   np.array([uniq[i][1] for i in sel], dtype=np.int64),
                   np.array([uniq[i][2] for i in sel], dtype=np.int64), all_index, all_count, uniq, used)


def _group_mean(index: NDArray[np.intp], size: Array, weights: Array, values: Array) -> Array:
    """Sample-weighted mean of point ``values`` per group (``index`` of the used points)."""
    return np.bincount(index, weights=weights * values, minlength=size.shape[0]) / size


def _group_se(stats: SufficientStats, pts: _Points, groups: _Groups, tau0: Array, mean_abs: Array,
              floor_rel: float) -> Array:
    """Standard error of each group mean: max(i.i.d., batch means) combined with a relative floor, [N·m].

    i.i.d.: the sample standard deviation of (measured − base model) from the points' centred sums. Batch means:
    the group's cells in time order cut into 10 consecutive stretches of (nearly) equal sample counts, as
    ``numpy.array_split`` cuts samples; a cell goes to the stretch its first sample falls in.
    """
    k = groups.size.shape[0]
    used_pt = groups.of >= 0
    idx = groups.of[used_pt]
    c = pts.weight[used_pt]
    r = (pts.y - tau0)[used_pt]
    r_mean = np.bincount(idx, weights=c * r, minlength=k) / groups.size
    ss = np.bincount(idx, weights=pts.m2[used_pt] + c * (r - r_mean[idx]) ** 2, minlength=k)
    n = groups.size
    s = np.sqrt(np.where(n > 1.0, ss / np.maximum(n - 1.0, 1.0), 0.0))
    se = s / np.sqrt(n)
    # batch means over the cells
    cell_group = groups.of[pts.cell_point]
    keep = cell_group >= 0
    cg = cell_group[keep]
    cc = stats.samples[keep]
    cr = stats.mean_y[keep] - tau0[pts.cell_point[keep]]
    order = np.lexsort((np.flatnonzero(keep), stats.batch[keep], cg))
    cg, cc, cr = cg[order], cc[order], cr[order]
    bounds = np.searchsorted(cg, np.arange(k + 1))
    for j in range(k):
        a, b = int(bounds[j]), int(bounds[j + 1])
        total = int(round(float(n[j])))
        if total < 20 or b - a < 2:
            continue
        counts = cc[a:b]
        first = np.concatenate([[0.0], np.cumsum(counts)[:-1]])  # position of each cell's first sample
        size, extra = divmod(total, 10)
        edges = np.array([i * size + min(i, extra) for i in range(11)], dtype=float)
        which = np.searchsorted(edges, first, side='right') - 1
        bsum = np.bincount(which, weights=counts * cr[a:b], minlength=10)
        bcnt = np.bincount(which, weights=counts, minlength=10)
        ok = bcnt > 0
        if int(ok.sum()) < 2:
            continue
        means = bsum[ok] / bcnt[ok]
        se[j] = max(float(se[j]), float(np.std(means, ddof=1)) / math.sqrt(int(ok.sum())))
    return np.maximum(np.hypot(se, floor_rel * mean_abs), 1e-12)


# ------------------------------------------------------------------------------------------------------------
# the fit


def _rho(z: Array, loss: str) -> Array:
    if loss == 'linear':
        return z
    if loss == 'soft_l1':
        return 2.0 * (np.sqrt(1.0 + z) - 1.0)
    if loss == 'huber':
        return np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    if loss == 'cauchy':
        return np.log1p(z)
    return np.arctan(z)


def _cost(r: Array, loss: str, f_scale: float) -> float:
    return float(0.5 * f_scale**2 * np.sum(_rho((r / f_scale) ** 2, loss)))


class _Solution(NamedTuple):
    values: dict[str, float]       # all fit parameters and the offset
    internal: Array
    jac_internal: Array            # weighted jacobian of the group residuals, internal parameters
    to_raw: Array                  # d(raw active)/d(internal active)
    residuals: Array               # weighted group residuals
    cost: float
    nfev: int
    message: str
    status: int


class _Problem:
    """Weighted group residuals r_j = (ȳ_j − mean model_j)/se_j as a function of the active parameters."""

    def __init__(self, model: SampleModel, pts: _Points, groups: _Groups, y_mean: Array, se: Array, x_ref: float,
                 loss: str, f_scale: float, max_nfev: int, absolute: bool) -> None:
        self.model = model
        self.pts = pts
        self.groups = groups
        self.y_mean = y_mean
        self.se = se
        self.x_ref = x_ref
        self.loss = loss
        self.f_scale = f_scale
        self.max_nfev = max_nfev
        self.base = model.values()
        self.used = groups.of >= 0
        self.absolute = absolute  # weights are 1/standard error (False: relative, scale from the residuals)
        self.offset_limit = float(np.min(np.abs(y_mean))) if y_mean.size else 0.0

    # internal <-> raw: a' = a + b x_ref (centred Walther form), everything else raw
    def _to_values(self, names: Sequence[str], theta: Array) -> dict[str, float]:
        v = dict(self.base)
        v.update({name: float(x) for name, x in zip(names, theta, strict=False)})
        if 'walther_a' in names:
            v['walther_a'] = v['walther_a'] - v['walther_b'] * self.x_ref
        return v

    def internal0(self, names: Sequence[str]) -> Array:
        v = self.base
        return np.array([v['walther_a'] + v['walther_b'] * self.x_ref if name == 'walther_a' else v[name]
                         for name in names])

    def bounds(self, names: Sequence[str]) -> tuple[Array, Array]:
        v = self.base
        lo, hi = [], []
        for name, x0 in zip(names, self.internal0(names), strict=False):
            if name == 'walther_a':
                lo.append(x0 - 0.3)
                hi.append(x0 + 0.3)
            elif name == 'walther_b':
                lo.append(3.0 * v[name])
                hi.append(v[name] / 3.0)
            elif name == 'viscosity_offset_cst':
                lo.append(-1.0)
                hi.append(100.0)
            elif name in ASYMMETRY_PARAMETERS:
                lo.append(-0.9)
                hi.append(0.9)
            elif name == OFFSET:
                lo.append(-self.offset_limit)
                hi.append(self.offset_limit)
            else:
                top = {'palmgren_factor': 100.0, 'sliding_friction_coefficient': 2.0}.get(name, 10.0)
                lo.append(x0 / 20.0)
                hi.append(min(top, 20.0 * x0) if x0 > 0.0 else top)
        return np.array(lo), np.array(hi)

    def residuals(self, names: Sequence[str], theta: Array) -> Array:
        v = self._to_values(names, theta)
        tau = self.model.torque_nmm(v)[self.used] * NM_PER_NMM
        g = self.groups
        return (self.y_mean - _group_mean(g.of[self.used], g.size, self.pts.weight[self.used], tau)) / self.se

    def jacobian(self, names: Sequence[str], theta: Array) -> Array:
        v = self._to_values(names, theta)
        raw = self.model.jacobian_nmm(v, names)[self.used] * NM_PER_NMM
        if 'walther_a' in names and 'walther_b' in names:  # d/db at fixed a' = d/db raw − x_ref d/da raw
            ia, ib = names.index('walther_a'), names.index('walther_b')
            raw[:, ib] = raw[:, ib] - self.x_ref * raw[:, ia]
        g = self.groups
        idx = g.of[self.used]
        w = self.pts.weight[self.used]
        cols = [np.bincount(idx, weights=w * raw[:, k], minlength=g.size.shape[0]) / g.size
                for k in range(len(names))]
        return -np.column_stack(cols) / self.se[:, None]

    def solve(self, names: Sequence[str]) -> _Solution:
        x0 = self.internal0(names)
        lo, hi = self.bounds(names)
        cost0 = _cost(self.residuals(names, x0), self.loss, self.f_scale)
        with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
            res = least_squares(lambda th: self.residuals(names, th), x0, jac=lambda th: self.jacobian(names, th),
                                bounds=(lo, hi), method='trf', x_scale='jac', loss=self.loss,
                                f_scale=self.f_scale, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                                max_nfev=self.max_nfev)
        if res.status <= 0 or not np.all(np.isfinite(res.fun)) or not np.all(np.isfinite(res.x)):
            msg = (f'the fit of {", ".join(_label(n) for n in names)} did not converge after {res.nfev} evaluations '
                   f'({res.message})')
            raise FitError(msg)
        if res.cost > cost0 * (1.0 + 1e-9) + 1e-300:
            msg = (f'the fit of {", ".join(_label(n) for n in names)} diverged: the cost rose from {cost0:.6g} to '
                   f'{res.cost:.6g}')
            raise FitError(msg)
        span = hi - lo
        for name, x, low, high, width in zip(names, res.x, lo, hi, span, strict=False):
            if (x - low <= 1e-6 * width and low != 0.0) or high - x <= 1e-6 * width:
                raw = self._to_values(names, res.x)[name]
                msg = (f'the fit diverged: {_label(name)} ran to the edge of its plausible range ({raw:.6g}); the '
                       'data do not support a physical value (check the logs, the temperature sensor and the base '
                       'parameters)')
                raise FitError(msg)
        values = self._to_values(names, res.x)
        nu = self.model.viscosity_cst(values)
        if not np.all(nu > 0.0):
            msg = 'the fit diverged: the refitted viscosity is not positive at some data temperatures'
            raise FitError(msg)
        to_raw = np.eye(len(names))
        if 'walther_a' in names and 'walther_b' in names:
            to_raw[names.index('walther_a'), names.index('walther_b')] = -self.x_ref
        return _Solution(values, res.x, self.jacobian(names, res.x), to_raw, res.fun, float(res.cost),
                         int(res.nfev), str(res.message), int(res.status))


def _label(name: str) -> str:
    return 'the torque offset' if name == OFFSET else name


def _covariance(sol: _Solution, absolute: bool) -> tuple[Array, int]:
    """Covariance of the internal parameters and the degrees of freedom.

    With absolute weights (1/se) it is scaled by max(1, χ²/dof); with relative weights (no absolute scale) by
    χ²/dof, and infinite without degrees of freedom.
    """
    J = sol.jac_internal
    m, p = J.shape
    dof = m - p
    chi2 = float(sol.residuals @ sol.residuals)
    if absolute:
        s2 = max(1.0, chi2 / dof) if dof > 0 else 1.0
    else:
        s2 = chi2 / dof if dof > 0 else math.inf
    try:
        cov = np.linalg.inv(J.T @ J) * s2
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.inf)
    return cov, dof


def _distinct_viscous_temperatures(pts: _Points, groups: _Groups, upper: NDArray[np.bool_],
                                   min_bin_samples: int) -> list[float]:
    """Temperature bins of used groups with at least half (and ``min_bin_samples``) of their samples in the upper
    Palmgren branch."""
    g = groups
    used = g.of >= 0
    n_upper = np.bincount(g.of[used], weights=pts.weight[used] * upper[used].astype(float),
                          minlength=g.size.shape[0])
    ok = (n_upper >= min_bin_samples) & (n_upper >= 0.5 * g.size)
    return sorted({float(x) for x in g.t_bin[ok]})


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
                direction: ArrayLike, *, fit: Sequence[str] = ('walther_a',), weights: str = 'bin_se',
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


def refit_stats(base: AxisParams, stats: SufficientStats, *, fit: Sequence[str] = ('walther_a',),
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
        msg = (f'the temperature bin width {bin_width_c:g} degC is finer than the statistics\' resolution '
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
                             f'Palmgren\'s upper branch (nu*n >= {PALMGREN_THRESHOLD:g})')
            active.remove(drop)
            continue
        break
    if sol is None or not any(name in requested for name in active):
        why = '; '.join(f'{name}: not identifiable: {reasons[name]}' for name in requested)
        msg = f'the data determine none of the requested parameters ({why})'
        raise FitError(msg)
    return _result(base, stats, problem, groups, model, pts, tau0, upper0, visc_temps, requested, active, reasons,
                   sol, offset, calibration_se_nm, offset_separable)


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
            reasons[name] = (f'no samples in Palmgren\'s upper branch (nu*n >= {PALMGREN_THRESHOLD:g}{where}), '
                             'where the viscous torque depends on viscosity')
    else:
        temps = ', '.join(f'{x:g}' for x in visc_temps0)
        for i, name in enumerate(visc):
            if i >= len(visc_temps0):
                reasons[name] = (f'needs samples at {i + 1} distinct temperatures in Palmgren\'s upper branch '
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
    return False, ('auto: off, needs both a plateau in Palmgren\'s upper branch (cold) and one below it (warm) '
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
    tau1 = model.torque_nmm(sol.values) * NM_PER_NMM
    fric1 = model.torque_nmm(sol.values, offset=False) * NM_PER_NMM
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
        n_bins=int(np.count_nonzero(used)), offset_confounding=confounding)


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
