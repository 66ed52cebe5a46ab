"""Lack of fit: does a refitted model explain every bin's measured mean within that mean's standard error?

A refit's interval is a 95 % confidence interval only if the model can describe the data: where it cannot, the
least-squares optimum is the best compromise of a wrong model, its "interval" is the scatter of that compromise
and the truth may lie far outside it (issue 31: the sample's cold asymmetry lowers CCW alone, a form the model's
direction term cannot take, and a both-direction refit excluded the truth from its interval). So every refit is
checked bin by bin, and the result says in words and numbers whether its intervals may be read as confidence
intervals.

The test. For every (5 °C temperature bin, direction, speed) group in the fit, ``z = (ȳ − m̄) / se`` with ȳ the
measured mean, m̄ the mean of the refitted model of the measurement (friction + the fitted offset) over the same
samples, and ``se`` the standard error the fit weighted it with (:func:`~gimbal_friction.refit.problem._group_se`):
the larger of the i.i.d. value and the batch-means value (the group's samples in time order cut into 10 stretches:
the samples are correlated — position ripple, slow drifts — so their raw count overstates what they know),
combined with a floor of 0.2 % of the mean for the model's own error. With the standard error itself estimated
from 10 batch means, ``z`` follows Student's t with :data:`BATCH_DOF` degrees of freedom under the model; a bin does
not fit when ``|z|`` exceeds the two-sided quantile at :data:`ALPHA` family-wise over the bins checked (Bonferroni:
a model that fits passes the whole test 95 % of the time, however many bins there are). The result also carries
``χ² = Σ z²`` and its degrees of freedom (bins − fitted parameters) as a summary.

What to try is said from the pattern of the bins that do not fit (:func:`advice`): one direction, or the two with
opposite signs (the direction term), cold bins in both directions (the viscosity–temperature curve), warm bins in
both directions (the warm floor or the calibration).

>>> ok = BinCheck(-40.0, -39.7, 1, 1 / 3, 700, 3.77e-3, 3.76e-3, 3e-5)
>>> round(ok.z, 2)
0.33
>>> bad = BinCheck(-20.0, -20.3, -1, 1 / 3, 1500, 1.07e-3, 1.25e-3, 4e-6)
>>> check = decide([ok, bad], n_params=2)
>>> check.fits, [round(b.z) for b in check.misfits], round(check.z_critical, 2)
(False, [-45], 2.69)
>>> print(describe_bin(bad))
-20.3 degC CCW: measured 1.0700, model 1.2500 N*mm (residual -0.1800 = -14.4 %, se 0.0040, z -45.0)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from scipy.special import stdtrit

#: Family-wise false-alarm rate of the lack-of-fit test [-].
ALPHA = 0.05
#: Degrees of freedom of a bin's standard error (10 batch means) [-].
BATCH_DOF = 9
#: Bins listed by name in a one-line summary [-].
NAMED = 4


class BinCheck(NamedTuple):
    """One group of the fit against the refitted model of the measurement. Torques [N·m]."""

    temperature_bin_c: float    #: bin centre [°C]
    temperature_c: float        #: mean temperature of the bin's samples [°C]
    direction: int              #: +1 (CW) or −1 (CCW)
    speed_rpm: float            #: mean speed [rpm]
    n: int                      #: samples [-]
    measured_mean_nm: float     #: mean |τ| measured [N·m]
    model_nm: float             #: mean of the refitted model of the measurement over the bin's samples [N·m]
    standard_error_nm: float    #: standard error of the measured mean (batch means, floor) [N·m]

    @property
    def residual_nm(self) -> float:
        """Measured − model [N·m]."""
        return self.measured_mean_nm - self.model_nm

    @property
    def z(self) -> float:
        """Residual in standard errors [-]."""
        return self.residual_nm / self.standard_error_nm if self.standard_error_nm > 0.0 else math.inf


class FitCheck(NamedTuple):
    """Whether a model fits the bins it was checked on (see the module notes)."""

    checked: bool                    #: the check ran (False: too few bins, or not a refit)
    fits: bool                       #: every bin within ``z_critical``
    z_critical: float                #: the |z| a bin may reach [-]
    chi2: float                      #: Σ z² over the bins [-]
    dof: int                         #: bins − fitted parameters [-]
    bins: tuple[BinCheck, ...]       #: every bin checked
    misfits: tuple[BinCheck, ...]    #: the bins beyond z_critical, largest |z| first
    pattern: str = ''                #: what the misfits have in common ('' when it fits)
    advice: tuple[str, ...] = ()     #: what to try

    @property
    def worst(self) -> BinCheck | None:
        """The bin of largest |z| (None: no bins)."""
        return max(self.bins, key=lambda b: abs(b.z)) if self.bins else None


#: Not checked.
FIT_NOT_CHECKED = FitCheck(False, True, math.nan, math.nan, 0, (), ())


def z_critical(bins: int, alpha: float = ALPHA, dof: int = BATCH_DOF) -> float:
    """The two-sided Student-t quantile at ``alpha`` family-wise over ``bins`` bins (Bonferroni) [-].

    >>> round(z_critical(1), 2), round(z_critical(42), 2)
    (2.26, 4.66)
    """
    return float(stdtrit(dof, 1.0 - alpha / (2.0 * max(bins, 1))))


def direction_name(sign: int) -> str:
    """'CW' (positive motion) or 'CCW'."""
    return 'CW' if sign > 0 else 'CCW'


def describe_bin(b: BinCheck) -> str:
    """One bin with its numbers, torques in N*mm."""
    rel = b.residual_nm / b.model_nm if b.model_nm else math.nan
    return (f'{b.temperature_c:.1f} degC {direction_name(b.direction)}: measured {1e3 * b.measured_mean_nm:.4f}, '
            f'model {1e3 * b.model_nm:.4f} N*mm (residual {1e3 * b.residual_nm:+.4f} = {100 * rel:+.1f} %, '
            f'se {1e3 * b.standard_error_nm:.4f}, z {b.z:+.1f})')


def decide(bins: Sequence[BinCheck], n_params: int, *, viscous_bins: Sequence[float] = (),
           alpha: float = ALPHA) -> FitCheck:
    """The lack-of-fit verdict over ``bins`` for a model with ``n_params`` fitted parameters; ``viscous_bins``
    (bin centres [°C] in Palmgren's upper branch) shape the advice (:func:`advice`)."""
    bins = tuple(b for b in bins if math.isfinite(b.z))
    if not bins:
        return FIT_NOT_CHECKED
    crit = z_critical(len(bins), alpha)
    misfits = tuple(sorted((b for b in bins if abs(b.z) > crit), key=lambda b: -abs(b.z)))
    chi2 = float(sum(b.z ** 2 for b in bins))
    pattern, tips = advice(bins, misfits, crit, viscous_bins)
    return FitCheck(True, not misfits, crit, chi2, len(bins) - n_params, bins, misfits, pattern, tips)


def advice(bins: Sequence[BinCheck], misfits: Sequence[BinCheck], crit: float, viscous_bins: Sequence[float]
           ) -> tuple[str, tuple[str, ...]]:
    """(what the bins that do not fit have in common, what to try). Per temperature bin holding both directions,
    the residuals split into their difference (CW − CCW: what a direction term must explain) and their mean (what
    the model of both must explain), each in its own standard errors; a part beyond ``crit`` in any bin with a misfit
    names the cause: the direction difference, the cold mean (the viscosity) or the warm mean (the floor or the
    calibration). One direction alone says only cold or warm."""
    if not misfits:
        return '', ()
    by_bin: dict[float, dict[int, BinCheck]] = {}
    for b in bins:
        by_bin.setdefault(b.temperature_bin_c, {})[b.direction] = b
    cold_set = set(viscous_bins)
    off_bins = {b.temperature_bin_c for b in misfits}
    split: list[float] = []
    common_cold: list[float] = []
    common_warm: list[float] = []
    for t_bin in sorted(off_bins):
        pair = by_bin.get(t_bin, {})
        if len(pair) == 2:
            cw, ccw = pair[1], pair[-1]
            se = math.hypot(cw.standard_error_nm, ccw.standard_error_nm)
            if abs(cw.residual_nm - ccw.residual_nm) > crit * se:
                split.append(t_bin)
            if abs(cw.residual_nm + ccw.residual_nm) > crit * se:
                (common_cold if t_bin in cold_set else common_warm).append(t_bin)
        else:
            (common_cold if t_bin in cold_set else common_warm).append(t_bin)
    parts: list[str] = []
    tips: list[str] = []
    if split:
        lower = sum(1 for t in split if by_bin[t][-1].residual_nm < by_bin[t][1].residual_nm)
        side = 'CCW below CW' if lower * 2 >= len(split) else 'CW below CCW'
        parts.append(f"the two directions differ ({side}) at {_temps(split)} degC beyond what the model's "
                     'direction term explains (with the default fit it has none; with direction_asymmetry it raises '
                     'one direction and lowers the other by the same fraction, leaving their mean to the viscosity)')
        tips += [('fit one direction alone (--direction cw or --direction ccw): the file then describes that '
                  'direction only'), 'add direction_asymmetry to --fit']
    if common_cold:
        parts.append(f'both directions are off the same way in the cold, where the viscosity acts, at '
                     f'{_temps(common_cold)} degC')
        tips.append('let the viscosity-temperature curve bend: add walther_b to --fit (needs 2 cold plateaus)')
    if common_warm:
        parts.append(f'the warm level (where the viscosity does not act) is off at {_temps(common_warm)} degC')
        tips += ['check the calibration the logs were measured with (--calibration, calibrate-kt)',
                 ('let the warm floor move: add palmgren_factor or sliding_friction_coefficient to --fit (with '
                  '--offset off: the offset cannot be told from them)')]
    return '; '.join(parts), tuple(dict.fromkeys(tips))


def _temps(values: Sequence[float]) -> str:
    return ', '.join(f'{t:g}' for t in values)


def summary_line(check: FitCheck) -> str:
    """The verdict in one line (what a user reads first)."""
    if not check.checked:
        return 'fit check: not checked (no bins)'
    worst = check.worst
    head = f'chi2 {check.chi2:.4g} over {len(check.bins)} bins (dof {check.dof})'
    if check.fits:
        return (f'fit check: the model fits every bin (worst |z| {abs(worst.z) if worst else 0.0:.2f}, allowed '
                f'{check.z_critical:.2f}; {head}): the intervals are 95 % confidence intervals')
    named = '; '.join(describe_bin(b) for b in check.misfits[:NAMED])
    more = f'; and {len(check.misfits) - NAMED} more' if len(check.misfits) > NAMED else ''
    return (f'fit check: the model does NOT fit {len(check.misfits)} of {len(check.bins)} bins (|z| above '
            f'{check.z_critical:.2f}; {head}): {named}{more}')


def interval_label(check: FitCheck) -> str:
    """What the refit's intervals are: '95% CI' where the model fits, else a label that says they are not."""
    return '95% CI' if check.fits else 'interval (NOT a 95% CI: the model does not fit)'
