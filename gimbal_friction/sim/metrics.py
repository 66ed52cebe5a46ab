"""LOS error metrics of a simulated batch, per run.

Over the ticks after the initial transient (``t ≥ settle_s``):

- LOS rate error = true inertial LOS rate − target rate ω_T: RMS and peak |·| [rad/s];
- LOS position error = true inertial LOS angle − target angle θ_T: RMS and peak |·| [rad];
- reversal error = peak |position error| within ±``reversal_window_s`` of each reversal (zero crossing of the
  reference joint velocity ω_T − ω_B) after the transient [rad] (NaN when the profile has none);
- current margin = 1 − peak |motor current| / ``current_limit_a`` [-] (≤ 0: the drive saturated).

>>> import numpy as np
>>> rms_and_peak(np.array([3.0, -4.0]))
(3.5355339059327378, 4.0)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.sim.engine import BatchResult

Array = NDArray[np.float64]

__all__ = ['RunMetrics', 'batch_metrics', 'rms_and_peak']


class RunMetrics(NamedTuple):
    """Metrics of one run (field names are the loop-study record keys)."""

    rate_error_rms_rad_s: float
    rate_error_peak_rad_s: float
    position_error_rms_rad: float
    position_error_peak_rad: float
    reversal_error_peak_rad: float
    current_margin: float


def rms_and_peak(x: Array) -> tuple[float, float]:
    """(RMS, peak |x|) of ``x`` (NaN for an empty array)."""
    if x.size == 0:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(x * x))), float(np.max(np.abs(x)))


def batch_metrics(result: BatchResult) -> list[RunMetrics]:
    """Metrics of every run of ``result``, in run order."""
    cfg, prof, tr = result.config, result.profile, result.traces
    t = prof.time_s
    keep = t >= cfg.settle_s
    rate_err = tr.los_rate_rad_s - prof.target_rate_rad_s[:, None]
    pos_err = tr.los_angle_rad - prof.target_angle_rad[:, None]
    window = np.zeros(t.shape, dtype=bool)
    for t_rev in prof.reversal_times_s:
        if t_rev >= cfg.settle_s:
            window |= np.abs(t - t_rev) <= cfg.reversal_window_s
    window &= keep
    out = []
    for i in range(len(result.runs)):
        r_rms, r_peak = rms_and_peak(rate_err[keep, i])
        p_rms, p_peak = rms_and_peak(pos_err[keep, i])
        rev = float(np.max(np.abs(pos_err[window, i]))) if window.any() else math.nan
        i_peak = float(np.max(np.abs(tr.current_a[keep, i]))) if keep.any() else math.nan
        out.append(RunMetrics(r_rms, r_peak, p_rms, p_peak, rev, 1.0 - i_peak / cfg.current_limit_a))
    return out
