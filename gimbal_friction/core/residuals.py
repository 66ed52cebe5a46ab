"""Model-versus-measured residuals (pure: no rclpy), shared by ``residual_logger`` and the offline ``replay``.

A residual record pairs one accepted measurement of the estimator (stamped with the joint-state stamp of its
sample) with the feedforward published for the same joint-state stamp, and adds the model components M_R, M_S,
M_L at the temperature and speed of the sample for the refit. All torques in [N·m], SI on every interface.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from gimbal_friction.core.feedforward import FeedforwardLogic


class ResidualRecord(NamedTuple):
    """One paired sample; field order matches ``recording.topics.RESIDUAL_FIELDS`` after ``joint``."""

    joint: str
    stamp_ns: int            #: joint-state stamp of the sample [ns]
    temperature_c: float     #: bearing temperature used for the prediction [°C] (NaN: none)
    position_rad: float      #: [rad]
    velocity_rad_s: float    #: [rad/s]
    current_a: float         #: motor current [A]
    measured_nm: float       #: measured friction, signed [N·m]
    predicted_nm: float      #: feedforward, signed [N·m]
    m_rolling_nm: float      #: model M_R magnitude [N·m]
    m_sliding_nm: float      #: model M_S magnitude [N·m]
    m_viscous_nm: float      #: model M_L magnitude [N·m]
    residual_nm: float       #: measured − predicted [N·m]

    def detail_values(self) -> list[float]:
        """The ``residual_detail`` data array (RESIDUAL_FIELDS order)."""
        return [self.stamp_ns * 1e-9, self.temperature_c, self.position_rad, self.velocity_rad_s, self.current_a,
                self.measured_nm, self.predicted_nm, self.m_rolling_nm, self.m_sliding_nm, self.m_viscous_nm,
                self.residual_nm]


def current_from_friction(friction_nm: float, K_T: float, I_0: float, direction: float) -> float:
    """Inverse of Eq. (23) ``T_f = K_T (I − d I_0)``: motor current [A] from measured friction [N·m]."""
    return friction_nm / K_T + direction * I_0


def make_record(ff: FeedforwardLogic, joint: str, stamp_ns: int, temperature_c: float | None, position: float,
                velocity: float, measured_nm: float, predicted_nm: float | None) -> ResidualRecord:
    """A residual record; the components (and the prediction when ``predicted_nm`` is None) come from ``ff``."""
    jt = ff.joint_torque(joint, velocity, temperature_c)
    predicted = jt.torque_nm if predicted_nm is None else predicted_nm
    p = ff.axes[joint]
    direction = 1.0 if velocity >= 0.0 else -1.0
    current = current_from_friction(measured_nm, p.torque_constant_nm_per_a, p.no_load_current_a, direction)
    t = math.nan if temperature_c is None else float(temperature_c)
    return ResidualRecord(joint, int(stamp_ns), t, float(position), float(velocity), current, float(measured_nm),
                          float(predicted), jt.m_rolling_nm, jt.m_sliding_nm, jt.m_viscous_nm,
                          float(measured_nm) - float(predicted))


class ResidualPairing:
    """Pairs measured samples with the feedforward of the same stamp (the live ``residual_logger``).

    Feedforward predictions are kept per (joint, stamp) for ``horizon`` entries; a measured sample whose
    feedforward has not arrived waits up to ``timeout_s`` and then uses the logger's own prediction (same code
    as the feedforward node) — counted as ``own_prediction``.
    """

    def __init__(self, ff: FeedforwardLogic, *, timeout_s: float = 1.0, horizon: int = 20000) -> None:
        self.ff = ff
        self.timeout_s = timeout_s
        self.horizon = horizon
        self._pred: OrderedDict[tuple[str, int], float] = OrderedDict()
        self._waiting: OrderedDict[tuple[str, int], tuple[float, float, float, float, float | None]] = \
            OrderedDict()
        self.paired = 0
        self.own_prediction = 0

    def on_feedforward(self, stamp_ns: int, names: Sequence[str], efforts: Sequence[float]) -> list[ResidualRecord]:
        """Store predictions; returns records of measured samples that were waiting for them."""
        out = []
        for name, effort in zip(names, efforts):
            key = (name, int(stamp_ns))
            waiting = self._waiting.pop(key, None)
            if waiting is not None and name in self.ff.axes:
                _, pos, vel, meas, temp = waiting
                out.append(make_record(self.ff, name, stamp_ns, temp, pos, vel, meas, float(effort)))
                self.paired += 1
                continue
            self._pred[key] = float(effort)
            if len(self._pred) > self.horizon:
                self._pred.popitem(last=False)
        return out

    def on_measured(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float],
                    velocities: Sequence[float], efforts: Sequence[float], now_s: float) -> list[ResidualRecord]:
        """A measured sample: a record now if its feedforward is known, else it waits (see :meth:`expire`)."""
        temperature, _ = self.ff.effective_temperature(now_s)
        out = []
        for i, name in enumerate(names):
            if name not in self.ff.axes or i >= len(efforts):
                continue
            pos = float(positions[i]) if i < len(positions) else math.nan
            vel = float(velocities[i]) if i < len(velocities) else math.nan
            meas = float(efforts[i])
            if not (math.isfinite(vel) and math.isfinite(meas)):
                continue
            key = (name, int(stamp_ns))
            pred = self._pred.pop(key, None)
            if pred is not None:
                out.append(make_record(self.ff, name, stamp_ns, temperature, pos, vel, meas, pred))
                self.paired += 1
            else:
                self._waiting[key] = (now_s, pos, vel, meas, temperature)
        return out

    def expire(self, now_s: float) -> list[ResidualRecord]:
        """Records for measured samples that waited longer than ``timeout_s`` (own prediction)."""
        out = []
        while self._waiting:
            key, (t0, pos, vel, meas, temp) = next(iter(self._waiting.items()))
            if now_s - t0 < self.timeout_s:
                break
            self._waiting.popitem(last=False)
            out.append(make_record(self.ff, key[0], key[1], temp, pos, vel, meas, None))
            self.own_prediction += 1
        return out


class ResidualStats:
    """Running RMS of the residual per (joint, temperature bin) for diagnostics."""

    def __init__(self, bin_c: float = 5.0) -> None:
        self.bin_c = bin_c
        self._acc: dict[tuple[str, float], list[float]] = {}

    def add(self, rec: ResidualRecord) -> None:
        key = (rec.joint, temperature_bin(rec.temperature_c, self.bin_c))
        acc = self._acc.setdefault(key, [0, 0.0])
        acc[0] += 1
        acc[1] += rec.residual_nm**2

    def rms(self) -> dict[tuple[str, float], tuple[int, float]]:
        """(joint, bin) -> (count, RMS residual [N·m])."""
        return {k: (int(n), math.sqrt(s / n)) for k, (n, s) in self._acc.items() if n}


def temperature_bin(t_c: float, bin_c: float) -> float:
    """Centre of the temperature bin of ``t_c`` [°C] (NaN stays NaN)."""
    if not math.isfinite(t_c):
        return math.nan
    return round(t_c / bin_c) * bin_c + 0.0


def steady_temperature(stamp_s: ArrayLike, temperature_c: ArrayLike, joint: ArrayLike | None = None, *,
                       window_s: float = 30.0, max_rate_c_per_min: float = 1.0) -> np.ndarray:
    """True where the temperature changed by at most ``max_rate_c_per_min`` [°C/min] over the last ``window_s``
    [s] of samples (of the same joint): a temperature plateau, not a ramp between plateaus."""
    st = np.asarray(stamp_s, dtype=float)
    t = np.asarray(temperature_c, dtype=float)
    joints = np.asarray(joint) if joint is not None else np.zeros(len(t), dtype=int)
    out = np.zeros(len(t), dtype=bool)
    for j in np.unique(joints):
        idx = np.flatnonzero((joints == j) & np.isfinite(st) & np.isfinite(t))
        if len(idx) < 2:
            continue
        idx = idx[np.argsort(st[idx], kind='stable')]
        s_j, t_j = st[idx], t[idx]
        back = s_j - window_s
        earlier = np.interp(back, s_j, t_j)
        rate = np.abs(t_j - earlier) / window_s * 60.0
        out[idx] = (back >= s_j[0]) & (rate <= max_rate_c_per_min)
    return out


def plateau_summary(temperature_c: ArrayLike, velocity_rad_s: ArrayLike, measured_nm: ArrayLike,
                    predicted_nm: ArrayLike, *, bin_c: float = 5.0, min_samples: int = 10,
                    joint: Iterable[str] | None = None, stamp_s: ArrayLike | None = None) -> list[dict[str, object]]:
    """One record per temperature plateau and direction: the paper's per-temperature means (Fig. 13).

    Plateaus are temperature bins of width ``bin_c`` [°C] holding at least ``min_samples`` samples per direction;
    with ``stamp_s`` [s] only samples at a steady temperature count (:func:`steady_temperature`), so the ramps
    between the chamber's set points do not make plateaus of their own. Direction ``cw`` is positive motion (the
    paper's clockwise), ``ccw`` negative; means are signed [N·mm].
    """
    t = np.asarray(temperature_c, dtype=float)
    v = np.asarray(velocity_rad_s, dtype=float)
    meas = np.asarray(measured_nm, dtype=float)
    pred = np.asarray(predicted_nm, dtype=float)
    joints = np.asarray(list(joint) if joint is not None else ['axis'] * len(t))
    ok = np.isfinite(t) & np.isfinite(v) & np.isfinite(meas) & np.isfinite(pred)
    if stamp_s is not None:
        ok &= steady_temperature(stamp_s, t, joints)
    bins = np.full(t.shape, np.nan)
    bins[ok] = np.round(t[ok] / bin_c) * bin_c + 0.0
    out: list[dict[str, object]] = []
    for j in sorted(set(joints[ok].tolist())):
        for b in np.unique(bins[ok & (joints == j)]):
            for name, sign in (('cw', 1.0), ('ccw', -1.0)):
                sel = ok & (joints == j) & (bins == b) & (np.sign(v) == sign)
                n = int(sel.sum())
                if n < min_samples:
                    continue
                m_mean = float(meas[sel].mean()) * 1e3
                p_mean = float(pred[sel].mean()) * 1e3
                out.append({'joint': j, 'temperature_c': round(float(t[sel].mean()), 3), 'direction': name,
                            'sign': int(sign), 'measured_mean_nmm': m_mean,
                            'measured_std_nmm': float(meas[sel].std(ddof=1)) * 1e3 if n > 1 else 0.0,
                            'predicted_nmm': p_mean, 'residual_nmm': m_mean - p_mean, 'samples': n})
    return out
