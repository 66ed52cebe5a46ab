"""Which samples belong to which temperature plateau, and which bins are plateaus: the one rule of the replay
summary, the report, the refit's groups and the estimator's statistics.

A sample belongs to the temperature bin ``plateau_of(t, bin_c) = round(t / bin_c) · bin_c`` [°C] (bins of width
``bin_c`` centred on its multiples; half to even), whatever else it is used for: the estimator's running
statistics, the refit's groups (:mod:`gimbal_friction.refit.fit`) and the per-plateau summary of ``replay`` and
``report`` (:func:`gimbal_friction.estimation.residuals.plateau_summary`) all bin with it, and count every usable
sample of a bin (finite temperature, velocity and measurement; moving). So the summary's ``samples`` of a plateau and
direction equal the refit's count of the same bin and direction (same bin width), and the estimator's count there
when its samples are all steady-state ones with a fresh temperature (the statistics count only those).

A bin is listed as a *plateau* in a summary when at least ``min_steady`` of its samples were taken while the
bearing temperature held steady (:func:`steady_temperature`): the temperature *stream* changed by at most
:data:`STEADY_MAX_RATE_C_PER_MIN` over the :data:`STEADY_WINDOW_S` before the sample (:func:`steady_samples`). It
is judged on the stream, not on the temperatures of the samples themselves, so a plateau whose temperature held
counts however short its sweeps (the paper's protocol: a soak, then one sweep each way), and a ramp the chamber only
passed through is not a plateau of its own. That choice decides which bins are shown, never which samples a shown
bin counts. Without a stream (a residual log written without its inputs) the samples' own temperatures stand in for
it, per joint: then a plateau needs sweeps that together span the window.

>>> plateau_of([-39.2, -37.6, 2.4, float('nan')], 5.0).tolist()
[-40.0, -40.0, 0.0, nan]
>>> usable_samples([1.0, float('nan'), 2.0, 3.0], [0.1, 0.1, 0.0, -0.2], [1e-3, 1e-3, 1e-3, 1e-3]).tolist()
[True, False, False, True]
>>> plateau_bins(np.array([-40.0, -40.0, 0.0]), np.array([True, True, False]), min_steady=2).tolist()
[-40.0]
>>> stream = (np.arange(0.0, 100.0, 0.5), np.full(200, -40.0))          # held at -40 degC for 100 s
>>> steady_samples([20.0, 35.0, 99.0], stream=stream).tolist()          # the first has no 30 s before it
[False, True, True]
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.streams.inputs import temperature_valid

#: the span of the temperature stream before a sample over which it must have held [s]
STEADY_WINDOW_S = 30.0
#: the largest change of the temperature over that span, as a rate [°C/min]
STEADY_MAX_RATE_C_PER_MIN = 1.0


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


def temperature_stream(time_s: ArrayLike, temperature_c: ArrayLike, t_min_c: float, t_max_c: float
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The temperature stream plateaus are judged on: the valid readings (finite, in ``[t_min_c, t_max_c]`` [°C]:
    the estimator's rule, so one absurd reading does not break a plateau) with finite times [s], sorted by time."""
    ts = np.asarray(time_s, dtype=np.float64).reshape(-1)
    tv = np.asarray(temperature_c, dtype=np.float64).reshape(-1)
    keep = temperature_valid(tv, t_min_c, t_max_c)[0] & np.isfinite(ts)
    order = np.argsort(ts[keep], kind='stable')
    return ts[keep][order], tv[keep][order]


def steady_temperature(sample_time_s: ArrayLike, temperature_time_s: ArrayLike, temperature_c: ArrayLike, *,
                       window_s: float = STEADY_WINDOW_S,
                       max_rate_c_per_min: float = STEADY_MAX_RATE_C_PER_MIN) -> NDArray[np.bool_]:
    """True for each sample time [s] at which the bearing temperature stream (times [s], values [°C]) changed by
    at most ``max_rate_c_per_min`` [°C/min] over the last ``window_s`` [s] (and covers that window): a temperature
    plateau, not a ramp between the chamber's set points."""
    ts = np.asarray(temperature_time_s, dtype=np.float64)
    tv = np.asarray(temperature_c, dtype=np.float64)
    ok = np.isfinite(ts) & np.isfinite(tv)
    ts, tv = ts[ok], tv[ok]
    st = np.asarray(sample_time_s, dtype=np.float64)
    if ts.size < 2:
        return np.zeros(st.shape, dtype=bool)
    order = np.argsort(ts, kind='stable')
    ts, tv = ts[order], tv[order]
    now = np.interp(st, ts, tv)
    back = st - window_s
    earlier = np.interp(back, ts, tv)
    # the largest excursion inside the window, approximated by the ends and three interior points
    lo_i = np.searchsorted(ts, back, side='left')
    hi_i = np.searchsorted(ts, st, side='right')
    running_max = np.abs(now - earlier)
    for k in range(3):  # also look at a few interior points: a ramp that turned round inside the window
        mid = np.interp(back + (k + 1) * window_s / 4.0, ts, tv)
        running_max = np.maximum(running_max, np.abs(mid - earlier))
    rate = running_max / window_s * 60.0
    covered = (back >= ts[0]) & (st <= ts[-1]) & (hi_i - lo_i >= 2)
    return covered & (rate <= max_rate_c_per_min)


def steady_samples(sample_time_s: ArrayLike, *, stream: tuple[ArrayLike, ArrayLike] | None = None,
                   temperature_c: ArrayLike | None = None, joint: Iterable[str] | None = None) -> NDArray[np.bool_]:
    """Which samples (times [s]) were taken while the bearing temperature held (:func:`steady_temperature`).

    Judged on ``stream`` (times [s], temperatures [°C], e.g. :func:`temperature_stream`) when it has at least two
    readings; else on the samples' own ``temperature_c`` [°C], per ``joint`` (a log without its inputs)."""
    st = np.asarray(sample_time_s, dtype=np.float64)
    if stream is not None and np.asarray(stream[0]).size >= 2:
        return steady_temperature(st, stream[0], stream[1])
    mask = np.zeros(st.shape, dtype=bool)
    if temperature_c is None:
        return mask
    t = np.asarray(temperature_c, dtype=np.float64)
    joints = np.asarray(list(joint) if joint is not None else [''] * st.shape[0])
    for j in set(joints.tolist()):
        mine = joints == j
        mask[mine] = steady_temperature(st[mine], st[mine], t[mine])
    return mask
