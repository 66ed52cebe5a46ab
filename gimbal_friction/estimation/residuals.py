"""Model-versus-measured residuals (pure: no rclpy): pairing, running RMS, and the per-plateau summary.

A measured sample (stamped with the joint-state stamp of its sample) pairs with the feedforward published for the
same joint and the same joint-state stamp (:func:`match_predictions`); the row itself is
:func:`gimbal_friction.streams.residual_row.residual_rows`. One pairing, in two forms: :func:`pair_residuals` over
a whole input at once (``gimbal-friction replay`` over a bag, the loop study over a simulated run) and
:class:`ResidualPairing`, the same rule as a buffer fed a few messages at a time (``residual_logger``: a
measurement waits for its feedforward at most a timeout). All torques in [N·m].
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.units import nmm_from_nm
from gimbal_friction.estimation.plateaus import plateau_bins, plateau_of, steady_samples, usable_samples
from gimbal_friction.estimation.statistics import GroupStatistics
from gimbal_friction.streams.measurement import MeasurementArrays
from gimbal_friction.streams.residual_row import ResidualRows, residual_rows

#: residual or torque magnitudes above this are not credible for a gimbal bearing and are not logged [N·m]
MAX_CREDIBLE_TORQUE_NM = 100.0
#: bearing temperatures above this are not credible [°C]
MAX_CREDIBLE_TEMPERATURE_C = 1000.0
#: feedforward entries a :class:`ResidualPairing` keeps [-] (several seconds at 1 kHz with two joints)
FEEDFORWARD_HORIZON = 16384


def match_predictions(joint: NDArray[np.str_], stamp_ns: NDArray[np.int64], ff_joint: NDArray[np.str_],
                      ff_stamp_ns: NDArray[np.int64], ff_torque_nm: NDArray[np.float64]) -> NDArray[np.float64]:
    """The feedforward [N·m] published for each measured sample's joint and stamp [ns] (NaN where none; the last
    one where a stamp was published twice).

    >>> match_predictions(np.array(['a', 'a']), np.array([5, 6]), np.array(['a', 'b']), np.array([5, 6]),
    ...                   np.array([0.1, 0.2])).tolist()
    [0.1, nan]
    """
    out = np.full(np.asarray(stamp_ns).shape[0], np.nan)
    fj = np.asarray(ff_joint)
    for name in np.unique(np.asarray(joint)).tolist():
        rows = np.flatnonzero(np.asarray(joint) == name)
        cand = np.flatnonzero(fj == name)
        if cand.size == 0:
            continue
        stamps = np.asarray(ff_stamp_ns, dtype=np.int64)[cand]
        order = np.lexsort((np.arange(cand.size), stamps))
        stamps, cand = stamps[order], cand[order]
        want = np.asarray(stamp_ns, dtype=np.int64)[rows]
        k = np.searchsorted(stamps, want, side='right') - 1
        hit = (k >= 0) & (stamps[np.maximum(k, 0)] == want)
        out[rows[hit]] = np.asarray(ff_torque_nm, dtype=np.float64)[cand[k[hit]]]
    return out


def pair_residuals(measured: MeasurementArrays, ff_joint: ArrayLike, ff_stamp_ns: ArrayLike,
                   ff_torque_nm: ArrayLike) -> ResidualRows:
    """The residual row of every measurement of ``measured``, paired with the feedforward [N·m] published for its
    joint and joint-state stamp [ns] among ``(ff_joint, ff_stamp_ns, ff_torque_nm)`` (the prediction NaN where
    none was). Rows are not checked for credibility (:func:`credible_rows`: the caller counts what it refuses)."""
    predicted = match_predictions(measured.joint, np.asarray(measured.stamp_ns, dtype=np.int64),
                                  np.asarray(ff_joint, dtype=str), np.asarray(ff_stamp_ns, dtype=np.int64),
                                  np.asarray(ff_torque_nm, dtype=np.float64))
    with np.errstate(invalid='ignore', over='ignore'):  # non-finite rows: credible_rows refuses them
        return residual_rows(measured, predicted)


class ResidualPairing:
    """:func:`pair_residuals` as a buffer fed a few messages at a time (``residual_logger``): the last ``horizon``
    feedforward entries (one per joint of each message) are kept, and a measurement waits until the feedforward
    of its joint and stamp has arrived, or at most ``timeout_s`` [s] of the caller's clock (then its row has the
    prediction NaN), or until the input ends (``final``)."""

    def __init__(self, horizon: int = FEEDFORWARD_HORIZON) -> None:
        self._joint = np.full(horizon, '', dtype=object)
        self._stamp = np.zeros(horizon, dtype=np.int64)
        self._torque = np.full(horizon, np.nan)
        self._next = 0
        #: measurements waiting, each with the time it arrived [s, the caller's clock]
        self._waiting: list[tuple[NDArray[np.float64], MeasurementArrays]] = []

    @property
    def waiting(self) -> int:
        """Measurements waiting for their feedforward [-]."""
        return sum(len(m) for _, m in self._waiting)

    def add_feedforward(self, joint: str, stamp_ns: int, torque_nm: float) -> None:
        """One joint's entry of a feedforward message (effective stamp [ns], torque [N·m]); the oldest entry goes
        once ``horizon`` are kept."""
        k = self._next % self._joint.shape[0]
        self._joint[k], self._stamp[k], self._torque[k] = joint, int(stamp_ns), float(torque_nm)
        self._next += 1

    def add_measurement(self, measured: MeasurementArrays, now_s: float) -> None:
        """Measurements received at ``now_s`` [s, the caller's clock], to be paired."""
        if len(measured):
            self._waiting.append((np.full(len(measured), float(now_s)), measured))

    def take(self, now_s: float, timeout_s: float, final: bool = False) -> ResidualRows:
        """The rows of the measurements whose feedforward has arrived, that have waited ``timeout_s`` [s] or more
        by ``now_s``, or all of them (``final``), in the order they arrived; the others keep waiting."""
        if not self._waiting:
            return ResidualRows.concatenate([])
        batch = MeasurementArrays.concatenate([m for _, m in self._waiting])
        since = np.concatenate([t for t, _ in self._waiting])
        predicted = match_predictions(batch.joint, batch.stamp_ns, self._joint.astype(str), self._stamp,
                                      self._torque)
        done = ~np.isnan(predicted) | (now_s - since >= timeout_s) | final
        self._waiting = [(since[~done], batch.select(~done))] if not done.all() else []
        with np.errstate(invalid='ignore', over='ignore'):  # non-finite rows: credible_rows refuses them
            return residual_rows(batch.select(done), predicted[done])


def credible_torque(torque_nm: ArrayLike) -> NDArray[np.bool_]:
    """Torques [N·m] that are finite and at most :data:`MAX_CREDIBLE_TORQUE_NM` in magnitude.

    >>> credible_torque([0.003, -1e154, float('nan'), float('inf')]).tolist()
    [True, False, False, False]
    """
    t = np.asarray(torque_nm, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        return np.isfinite(t) & (np.abs(t) <= MAX_CREDIBLE_TORQUE_NM)


def credible_rows(rows: ResidualRows) -> NDArray[np.bool_]:
    """Rows whose measured value is finite and credible, whose prediction is NaN (none arrived) or finite and
    credible, whose temperature is NaN (none) or inside [-273.15, :data:`MAX_CREDIBLE_TEMPERATURE_C`] °C and whose
    position and velocity are finite (a hostile or corrupted input must not reach the log or poison its statistics:
    each distinct absurd temperature would open a statistics bin of its own)."""
    pred = np.asarray(rows.predicted_nm, dtype=np.float64)
    t = np.asarray(rows.temperature_c, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        t_ok = np.isnan(t) | ((t >= -273.15) & (t <= MAX_CREDIBLE_TEMPERATURE_C))
    kinematics = np.isfinite(np.asarray(rows.position_rad, dtype=np.float64)) & np.isfinite(
        np.asarray(rows.velocity_rad_s, dtype=np.float64))
    return credible_torque(rows.measured_nm) & (np.isnan(pred) | credible_torque(pred)) & t_ok & kinematics


class ResidualStats:
    """Running RMS of the residual per (joint, temperature bin), for diagnostics (NaN residuals are skipped)."""

    def __init__(self, bin_c: float = 5.0) -> None:
        self.bin_c = bin_c
        self._stats = GroupStatistics(1, 0.0, 1.0)

    def add(self, rows: ResidualRows) -> None:
        r = np.asarray(rows.residual_nm, dtype=np.float64)
        bins = temperature_bins(rows.temperature_c, self.bin_c)
        keys = [(j, None if math.isnan(b) else b) for j, b in zip(rows.joint.tolist(), bins.tolist())]
        self._stats.add(keys, r, np.zeros(r.shape[0]))

    def rms(self) -> dict[tuple[str, float | None], tuple[int, float]]:
        """(joint, bin [°C] or None) -> (count, RMS residual [N·m])."""
        out = {}
        for rec in self._stats.records():
            n = rec['count']
            var = rec['std'] ** 2 * (n - 1) / n if n > 1 else 0.0
            out[rec['key']] = (n, math.sqrt(rec['mean'] ** 2 + var))
        return out


def temperature_bins(t_c: ArrayLike, bin_c: float) -> NDArray[np.float64]:
    """Centre of the temperature bin of each temperature [°C] (NaN stays NaN): :func:`plateau_of`."""
    return np.asarray(plateau_of(t_c, bin_c), dtype=np.float64)


def plateau_summary(temperature_c: ArrayLike, velocity_rad_s: ArrayLike, measured_nm: ArrayLike,
                    predicted_nm: ArrayLike, *, bin_c: float = 5.0, min_samples: int = 10,
                    joint: Iterable[str] | None = None, steady: ArrayLike | None = None,
                    stamp_s: ArrayLike | None = None,
                    temperature_stream: tuple[ArrayLike, ArrayLike] | None = None,
                    compare: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]] | None = None
                    ) -> list[dict[str, Any]]:
    """One record per temperature plateau and direction: the paper's per-temperature means (Fig. 13).

    Samples are assigned to plateaus by the one rule of :mod:`gimbal_friction.estimation.plateaus` (the refit's and
    the estimator's statistics'): bins of width ``bin_c`` [°C], every usable sample of a bin counted; a record needs
    ``min_samples`` per direction. Only bins holding at least ``min_samples`` samples taken while the temperature
    held are plateaus, so the ramps between the chamber's set points do not make plateaus of their own (this decides
    which bins are listed, not which samples they count): with the samples' times ``stamp_s`` [s], judged by
    :func:`~gimbal_friction.estimation.plateaus.steady_samples` on ``temperature_stream`` (times [s], temperatures
    [°C]; what ``replay`` and ``report`` pass), or, without one, on each joint's samples' own temperatures; or
    given as the mask ``steady``; with none of them every bin is a plateau. Direction ``cw`` is positive motion
    (the paper's clockwise), ``ccw`` negative; means are signed [N·mm]. A NaN prediction (no feedforward) leaves
    ``predicted_nmm`` and ``residual_nmm`` NaN for the samples that lack it. With ``compare`` (a function of a
    record's samples' temperatures [°C] and velocities [rad/s] giving a signed torque [N·mm] per sample, e.g. a
    refitted model) each record also has ``compare_nmm``, its mean over the same samples.
    """
    t = np.asarray(temperature_c, dtype=float)
    v = np.asarray(velocity_rad_s, dtype=float)
    meas = np.asarray(measured_nm, dtype=float)
    pred = np.asarray(predicted_nm, dtype=float)
    joints = np.asarray(list(joint) if joint is not None else ['axis'] * len(t))
    ok = usable_samples(t, v, meas)
    bins = np.where(ok, plateau_of(t, bin_c), np.nan)
    mask = None if steady is None else np.asarray(steady, dtype=bool)
    if mask is None and stamp_s is not None:
        mask = np.zeros(t.shape, dtype=bool)
        mask[ok] = steady_samples(np.asarray(stamp_s, dtype=float)[ok], stream=temperature_stream,
                                  temperature_c=t[ok], joint=joints[ok])
    out: list[dict[str, Any]] = []
    for j in sorted(set(joints[ok].tolist())):
        mine = ok & (joints == j)
        for b in plateau_bins(bins[mine], None if mask is None else mask[mine], min_steady=min_samples):
            for name, sign in (('cw', 1.0), ('ccw', -1.0)):
                sel = mine & (bins == b) & (np.sign(v) == sign)
                n = int(sel.sum())
                if n < min_samples:
                    continue
                m_mean = nmm_from_nm(float(meas[sel].mean()))
                p_sel = pred[sel]
                p_mean = nmm_from_nm(float(np.nanmean(p_sel))) if np.any(np.isfinite(p_sel)) else math.nan
                out.append({'joint': j, 'temperature_c': round(float(t[sel].mean()), 3), 'direction': name,
                            'sign': int(sign), 'measured_mean_nmm': m_mean,
                            'measured_std_nmm': nmm_from_nm(float(meas[sel].std(ddof=1))) if n > 1 else 0.0,
                            'predicted_nmm': p_mean, 'residual_nmm': m_mean - p_mean, 'samples': n,
                            'plateau_c': float(b)})
                if compare is not None:
                    out[-1]['compare_nmm'] = float(np.mean(compare(t[sel], v[sel])))
    return out
