"""The refit's parameter names, limits and result types (what :mod:`gimbal_friction.refit.fit` returns)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.physics.friction import PALMGREN_THRESHOLD_CST_RPM
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit_check import FIT_NOT_CHECKED, FitCheck

Array = NDArray[np.float64]

#: Parameters :func:`refit_model` can fit, in priority order (the earlier one is kept when the data can
#: determine only some of them).
FIT_PARAMETERS = ('walther_a', 'walther_b', 'viscosity_offset_cst', 'palmgren_factor',
                  'sliding_friction_coefficient', 'scale_positive', 'scale_negative', 'direction_asymmetry_cold',
                  'direction_asymmetry_warm')
#: What a refit fits unless told otherwise (``refit``, ``fleet``, :func:`~gimbal_friction.refit.fit.refit_model`):
#: the lubricant's viscosity level, with the calibration offset beside it where the data allow (``offset='auto'``).
DEFAULT_FIT = ('walther_a',)
#: The Walther constants of the lubricant (Eq. 20/21).
VISCOSITY_PARAMETERS = ('walther_a', 'walther_b', 'viscosity_offset_cst')
#: The temperature-dependent direction asymmetry (physics/direction.py).
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
    fit_check: FitCheck = FIT_NOT_CHECKED       #: whether the refitted model fits every bin (lack of fit)
    direction: str = 'both'                     #: the samples fitted: 'both', 'cw' or 'ccw'

    @property
    def intervals_are_confidence_intervals(self) -> bool:
        """The intervals may be read as 95 % confidence intervals: the model fits every bin it was fitted to."""
        return self.fit_check.checked and self.fit_check.fits

    @property
    def refitted(self) -> dict[str, float]:
        """Only the parameters that were determined and changed by the fit."""
        return {k: v for k, v in self.fitted.items() if self.identifiability[k].identifiable}
