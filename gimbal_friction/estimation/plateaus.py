"""Which samples belong to which temperature plateau: the one rule of the replay summary, the report and the refit.

A sample belongs to the temperature bin ``plateau_of(t, bin_c) = round(t / bin_c) · bin_c`` [°C] (bins of width
``bin_c`` centred on its multiples; half to even), whatever else it is used for: the estimator's running
statistics, the refit's groups (:mod:`gimbal_friction.refit.fit`) and the per-plateau summary of ``replay`` and
``report`` (:func:`gimbal_friction.estimation.residuals.plateau_summary`) all bin with it, and count every usable
sample of a bin (finite temperature, velocity and measurement; moving). A bin is listed as a *plateau* in a summary when
at least ``min_steady`` of its samples were taken while the bearing temperature held steady
(:func:`gimbal_friction.estimation.residuals.steady_temperature`, judged on the samples' own temperatures), so a
ramp the chamber only passed through is not a plateau of its own; that choice decides which bins are shown, never which
samples a shown bin counts. So the
summary's ``samples`` of a plateau and direction equal the refit's count of the same bin and direction.

>>> plateau_of([-39.2, -37.6, 2.4, float('nan')], 5.0).tolist()
[-40.0, -40.0, 0.0, nan]
>>> usable_samples([1.0, float('nan'), 2.0, 3.0], [0.1, 0.1, 0.0, -0.2], [1e-3, 1e-3, 1e-3, 1e-3]).tolist()
[True, False, False, True]
>>> plateau_bins(np.array([-40.0, -40.0, 0.0]), np.array([True, True, False]), min_steady=2).tolist()
[-40.0]
"""

from __future__ import annotations

from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray


@overload
def plateau_of(temperature_c: float, bin_c: float) -> float: ...
@overload
def plateau_of(temperature_c: ArrayLike, bin_c: float) -> NDArray[np.float64]: ...
def plateau_of(temperature_c: ArrayLike, bin_c: float) -> float | NDArray[np.float64]:
    """Plateau (temperature bin centre) of a temperature: ``round(t / bin_c) * bin_c`` [°C] (half to even; arrays
    too; NaN stays NaN)."""
    with np.errstate(invalid='ignore'):
        return np.round(np.asarray(temperature_c, dtype=np.float64) / bin_c) * bin_c + 0.0


def usable_samples(temperature_c: ArrayLike, velocity_rad_s: ArrayLike, measured_nm: ArrayLike) -> NDArray[np.bool_]:
    """Samples that count on a plateau: finite temperature [°C], velocity [rad/s] and measurement [N·m], and
    moving (at zero velocity the direction of friction is unknown); the refit skips the others the same way."""
    t = np.asarray(temperature_c, dtype=np.float64)
    v = np.asarray(velocity_rad_s, dtype=np.float64)
    m = np.asarray(measured_nm, dtype=np.float64)
    return np.isfinite(t) & np.isfinite(v) & np.isfinite(m) & (v != 0.0)


def plateau_bins(bins_c: ArrayLike, steady: ArrayLike | None, *, min_steady: int) -> NDArray[np.float64]:
    """The bins [°C] (of :func:`plateau_of`, one per sample, NaN: none) that are plateaus: with ``steady`` (a mask
    per sample) those holding at least ``min_steady`` steady samples, else every bin; sorted."""
    b = np.asarray(bins_c, dtype=np.float64)
    ok = np.isfinite(b)
    if steady is None:
        return np.unique(b[ok])
    values, counts = np.unique(b[ok & np.asarray(steady, dtype=bool)], return_counts=True)
    return np.asarray(values[counts >= min_steady], dtype=np.float64)
