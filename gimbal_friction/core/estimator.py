r"""Estimator logic of ``friction_estimator`` (pure: no rclpy), shared by the node and the offline replay.

The electrical measurement of the paper (Yu & Shang 2017, Sec. 6): in steady state the motor torque balances the
friction, so the measured friction torque of a joint is, Eq. (23),

.. math:: T_f = K_T\,(I - d\,I_0),\qquad d = \operatorname{sign}(\omega)

with the armature current ``I`` [A], the calibrated torque constant ``K_T`` [N·m/A] and no-load current ``I_0``
[A] of that joint (:func:`~gimbal_friction.core.kt.friction_from_current_Eq23`). ``T_f`` is signed like the
motion (CONTRACT.md). Eq. (23) holds only in steady state, so a sample is accepted only where the paper took its
data: at the commanded constant speed (1/3 rpm), away from the reversals and the speed-up phase (the paper swept
−6…+11° and kept −5…+10°).

Streaming API (:class:`EstimatorLogic`), fed in arrival (log-time) order:

``on_temperature(t_c)``
    bearing temperature [°C]; kept if finite and physically possible (else counted under
    ``counters.temperature_rejected``).
``on_joint_state(stamp_ns, names, positions, velocities)``
    ``/joint_states``: position [rad], velocity [rad/s] per joint.
``on_current(stamp_ns, names, currents)``
    ``/gimbal/motor_current``: current [A] per joint (JointState effort).

Each returns the :class:`Measurement` records accepted by that call (``on_temperature`` returns the rejection
reason or None).

Input checks (counted in ``counters.rejected[joint][reason]``; inputs that cannot be attributed to a configured
joint are counted under the joint key ``'*'``):

- ``'length mismatch'``: a message whose value array is not as long as its name array (the whole message is
  dropped; counted once for each configured joint it names, or under ``'*'``);
- ``'unknown joint'``: a name that is not a configured axis (per occurrence, under ``'*'``);
- ``'non-finite joint state'``: NaN/inf position or velocity; ``'stamp not increasing'``: a joint state whose
  stamp is not later than the last accepted joint state of that joint (both are dropped and never paired);
- ``'non-finite'``: NaN/inf current; ``'over current rating'``: ``|I| > max_current_a``.

Pairing (deterministic, identical online and offline). The accepted joint states of a joint have strictly
increasing stamps; the last :data:`HISTORY_LENGTH` of them are kept. A valid current sample with stamp ``c``
pairs with the most recent joint state whose ``|stamp − c| ≤ pairing_tolerance_s``. If there is none and the
newest joint state is already later than ``c + tolerance``, the current is rejected as ``'unpaired'`` at once.
Otherwise it waits (FIFO, at most :data:`WAIT_LENGTH` per joint; the oldest is dropped as ``'unpaired'`` on
overflow) and pairs with the first later joint state within the tolerance; the first later joint state beyond
``c + tolerance`` rejects it as ``'unpaired'``.

Steady state is judged on the joint state of the pair, in this order (the first failing check is the reason):

1. ``'outside position window'``: position outside ``[position_min_rad, position_max_rad]``;
2. ``'speed off command'``: ``| |v| − commanded_speed_rad_s | > speed_tolerance · commanded_speed_rad_s``;
3. ``'acceleration'``: ``|Δv/Δt| > max_accel_rad_s2`` against the previous accepted joint state of that joint;
4. ``'dwell'``: the speed has not been within tolerance, with the same sign, for ``min_dwell_s`` of stamps
   (counted from the first joint state of the current run).

Temperature: a measurement carries the latest valid temperature received before it (NaN if none). For the
statistics, its plateau is ``round(t / temperature_bin_c) · temperature_bin_c`` while the temperature is fresh,
else ``None`` (shown as ``'unknown'``). Temperatures carry no usable time of their own here, so a temperature is
timed by the latest joint-state/current stamp received before it (by the first one after it if none came
before), and it is fresh for a measurement if ``measurement stamp − that time ≤ temperature_timeout_s``. This
uses arrival order only, so it is the same live and offline.

Statistics (:meth:`EstimatorLogic.statistics`): per (joint, direction, plateau) the count, Welford running mean
and sample standard deviation of the friction [N·m], the position ripple (peak-to-peak of the mean friction in
``ripple_bins`` equal position bins across the window; 0 with fewer than two non-empty bins) and the position
range. Sorted by configured joint order, direction (−1 first) and plateau (unknown last).

Offline (:func:`estimate_arrays`): the same logic over the decoded arrays of a whole bag, vectorised with numpy.
It gives exactly the accepted samples (stamps, values, order) and counters that feeding the messages one by one
to :class:`EstimatorLogic` in log-time order gives (ties in log time: temperature, joint states, current); the
statistics agree to rounding (vectorised sums instead of Welford). :func:`feed_arrays` is that one-by-one
reference. In :class:`~gimbal_friction.recording.bag.ChamberArrays` a NaN means "joint not in that message", so a
message carrying NaN for a joint is treated as not carrying the joint when fed from arrays (it is counted as
non-finite live); length mismatches cannot be represented in the arrays at all.

>>> from gimbal_friction.core.params import AxisParams
>>> logic = EstimatorLogic({'elevation': AxisParams(no_load_current_a=0.01)},
...                        EstimatorSettings(min_dwell_s=0.0))
>>> v = EstimatorSettings().commanded_speed_rad_s
>>> logic.on_joint_state(1_000_000_000, ['elevation'], [0.0], [-v])
[]
>>> m = logic.on_current(1_000_000_000, ['elevation'], [-0.05])[0]
>>> round(m.friction_nm, 6), m.direction   # 0.05 N*m/A * (-0.05 A + 0.01 A)
(-0.002, -1)
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from gimbal_friction.core.errors import ConfigError
from gimbal_friction.core.feedforward import setting
from gimbal_friction.core.kt import friction_from_current_Eq23
from gimbal_friction.core.params import AxisParams

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from gimbal_friction.core.arrays import ChamberArrays

#: accepted joint states kept per joint for pairing [-]
HISTORY_LENGTH = 64
#: currents waiting for their joint state, per joint [-]
WAIT_LENGTH = 64
#: joint key of rejections that belong to no configured joint (unknown names)
UNKNOWN_JOINT = '*'
#: plausible bearing temperatures [degC]
TEMPERATURE_RANGE_C = (-273.15, 1000.0)

R_LENGTH = 'length mismatch'
R_UNKNOWN = 'unknown joint'
R_NON_FINITE_JS = 'non-finite joint state'
R_STAMP = 'stamp not increasing'
R_NON_FINITE = 'non-finite'
R_OVER_CURRENT = 'over current rating'
R_UNPAIRED = 'unpaired'
R_WINDOW = 'outside position window'
R_SPEED = 'speed off command'
R_ACCEL = 'acceleration'
R_DWELL = 'dwell'
#: steady-state verdict codes 1..4 (0 = steady)
STEADY_STATE_REASONS = (R_WINDOW, R_SPEED, R_ACCEL, R_DWELL)
#: reasons that mean a bad or unusable input (as opposed to "not in steady state")
INPUT_REASONS = (R_LENGTH, R_UNKNOWN, R_NON_FINITE_JS, R_STAMP, R_NON_FINITE, R_OVER_CURRENT, R_UNPAIRED)
T_NON_FINITE = 'non-finite temperature'
T_RANGE = 'temperature out of range'

_INT64_MIN = np.iinfo(np.int64).min


def _ns(seconds: float) -> int:
    return int(round(seconds * 1e9))


@dataclass(frozen=True)
class EstimatorSettings:
    """Settings of the estimator (ROS parameters of ``friction_estimator``; units in the names)."""

    commanded_speed_rad_s: float = setting(2.0 * math.pi / 180.0, 'rad/s', 'commanded constant test speed '
                                           "(paper: 1/3 rpm = 0.0349 rad/s); samples must move at this speed")
    speed_tolerance: float = setting(0.1, '-', 'accepted relative deviation of |velocity| from the commanded '
                                     'speed')
    min_dwell_s: float = setting(0.5, 's', 'speed continuously within tolerance, same sign, for at least this '
                                 'long (joint-state stamps) before a sample is accepted')
    position_min_rad: float = setting(math.radians(-5.0), 'rad', 'lower end of the accepted position window '
                                      '(paper: swept from -6 deg, kept from -5 deg)')
    position_max_rad: float = setting(math.radians(10.0), 'rad', 'upper end of the accepted position window '
                                      '(paper: swept to +11 deg, kept to +10 deg)')
    max_accel_rad_s2: float = setting(0.1, 'rad/s^2', 'largest |dv/dt| between successive joint states of a '
                                      'joint for a sample to count as steady')
    pairing_tolerance_s: float = setting(0.005, 's', 'a current pairs with a joint state whose stamp is within '
                                         'this of its own')
    max_current_a: float = setting(2.0, 'A', 'motor current rating; larger |current| is rejected as bad input')
    temperature_bin_c: float = setting(5.0, 'degC', 'width of the temperature plateau bins of the statistics '
                                       '(plateau = round(t/bin)*bin)')
    temperature_timeout_s: float = setting(5.0, 's', 'older temperature: sample kept, plateau "unknown"')
    ripple_bins: int = setting(15, '-', 'position bins across the window for the ripple statistic')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        for name in ('commanded_speed_rad_s', 'speed_tolerance', 'min_dwell_s', 'position_min_rad',
                     'position_max_rad', 'max_accel_rad_s2', 'pairing_tolerance_s', 'max_current_a',
                     'temperature_bin_c', 'temperature_timeout_s'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(name, 'must be a finite number', value)
        bins = self.ripple_bins
        checks = [
            ('commanded_speed_rad_s', self.commanded_speed_rad_s > 0.0, 'must be > 0 [rad/s]'),
            ('speed_tolerance', 0.0 < self.speed_tolerance < 1.0, 'must lie in (0, 1) [-]'),
            ('min_dwell_s', 0.0 <= self.min_dwell_s <= 3600.0, 'must lie in [0, 3600] [s]'),
            ('position_max_rad', self.position_max_rad > self.position_min_rad,
             'must exceed position_min_rad [rad]'),
            ('max_accel_rad_s2', self.max_accel_rad_s2 > 0.0, 'must be > 0 [rad/s^2]'),
            ('pairing_tolerance_s', 0.0 <= self.pairing_tolerance_s <= 10.0, 'must lie in [0, 10] [s]'),
            ('max_current_a', self.max_current_a > 0.0, 'must be > 0 [A]'),
            ('temperature_bin_c', 0.001 <= self.temperature_bin_c <= 1000.0, 'must lie in [0.001, 1000] [degC]'),
            ('temperature_timeout_s', self.temperature_timeout_s > 0.0, 'must be > 0 [s]'),
            ('ripple_bins', isinstance(bins, int) and not isinstance(bins, bool) and 1 <= bins <= 10000,
             'must be an integer in [1, 10000]'),
        ]
        for name, ok, rule in checks:
            if not ok:
                raise ConfigError(name, rule, getattr(self, name))


class Measurement(NamedTuple):
    """One accepted steady-state friction sample."""

    joint: str
    stamp_ns: int           #: stamp of the joint state of the pair [ns] (pairs with that joint state's feedforward)
    position_rad: float     #: joint position of the pair [rad]
    velocity_rad_s: float   #: joint velocity of the pair [rad/s]
    current_a: float        #: motor current [A]
    temperature_c: float    #: latest valid temperature received before this sample [degC] (NaN if none)
    friction_nm: float      #: measured friction, signed like the motion, K_T (I - d I_0) [N*m]
    direction: int          #: sign of the velocity, +1 or -1


@dataclass
class EstimatorCounters:
    """What happened to the inputs. ``rejected[joint][reason]``; joint ``'*'`` = not a configured joint."""

    accepted: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    temperature_rejected: dict[str, int] = field(default_factory=dict)

    def reject(self, joint: str, reason: str, n: int = 1) -> None:
        if n:
            bucket = self.rejected.setdefault(joint, {})
            bucket[reason] = bucket.get(reason, 0) + n

    def rejected_count(self, joint: str, reason: str) -> int:
        return self.rejected.get(joint, {}).get(reason, 0)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready copy."""
        return {'accepted': dict(self.accepted),
                'rejected': {j: dict(r) for j, r in self.rejected.items()},
                'temperature_rejected': dict(self.temperature_rejected)}


def plateau_of(temperature_c: float, bin_c: float) -> float:
    """Statistics plateau of a temperature: ``round(t / bin) * bin`` [degC] (half to even)."""
    return round(temperature_c / bin_c) * bin_c + 0.0


def _direction_sort(record: Mapping[str, Any]) -> tuple[int, float]:
    p = record['plateau_c']
    return record['direction'], math.inf if p is None else p


class _Stat:
    __slots__ = ('bin_n', 'bin_sum', 'm2', 'max_pos', 'mean', 'min_pos', 'n')

    def __init__(self, bins: int) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0
        self.min_pos = math.inf
        self.max_pos = -math.inf
        self.bin_sum = [0.0] * bins
        self.bin_n = [0] * bins

    def add(self, x: float, pos: float, b: int) -> None:
        self.n += 1
        delta = x - self.mean
        self.mean += delta / self.n
        self.m2 += delta * (x - self.mean)
        self.min_pos = min(self.min_pos, pos)
        self.max_pos = max(self.max_pos, pos)
        self.bin_sum[b] += x
        self.bin_n[b] += 1

    def ripple(self) -> float:
        means = [s / n for s, n in zip(self.bin_sum, self.bin_n) if n]
        return max(means) - min(means) if len(means) >= 2 else 0.0


def _record(joint: str, direction: int, plateau: float | None, count: int, mean: float, std: float,
            ripple: float, min_pos: float, max_pos: float) -> dict[str, Any]:
    return {'joint': joint, 'direction': int(direction), 'plateau_c': plateau, 'count': int(count),
            'mean_nm': float(mean), 'std_nm': float(std), 'ripple_nm': float(ripple),
            'min_position': float(min_pos), 'max_position': float(max_pos)}


class _Joint:
    """Streaming state of one configured joint."""

    __slots__ = ('history', 'i0', 'kt', 'last', 'run_sign', 'run_start', 'waiting')

    def __init__(self, params: AxisParams) -> None:
        self.kt = float(params.torque_constant_nm_per_a)
        self.i0 = float(params.no_load_current_a)
        self.history: deque[tuple[int, float, float, int]] = deque(maxlen=HISTORY_LENGTH)
        self.waiting: deque[tuple[int, float]] = deque()
        self.run_sign = 0
        self.run_start = 0
        self.last: Measurement | None = None

    def reset_stream(self) -> None:
        self.history.clear()
        self.waiting.clear()
        self.run_sign = 0
        self.run_start = 0


class EstimatorLogic:
    """Turns motor current, joint states and temperature into steady-state friction samples and statistics.

    Parameters
    ----------
    axes : Mapping[str, AxisParams]
        Configured joints (in order); only ``torque_constant_nm_per_a`` (K_T) and ``no_load_current_a`` (I_0)
        are used.
    settings : EstimatorSettings
        Validated settings.
    """

    def __init__(self, axes: Mapping[str, AxisParams], settings: EstimatorSettings) -> None:
        settings.validate()
        self.axes = dict(axes)
        self.order = list(self.axes)
        self.joints = {name: _Joint(p) for name, p in self.axes.items()}
        self.counters = EstimatorCounters(accepted=dict.fromkeys(self.axes, 0))
        self.settings = settings
        self._derive()
        self.clock_ns: int | None = None
        self.last_temperature_c: float | None = None
        self.temperature_time_ns: int | None = None
        self._stats: dict[tuple[str, int, float | None], _Stat] = {}
        #: plateau of every accepted measurement, in order, when set to a list (used by the offline reference)
        self.plateau_log: list[float] | None = None

    def _derive(self) -> None:
        s = self.settings
        self._tol_ns = _ns(s.pairing_tolerance_s)
        self._dwell_ns = _ns(s.min_dwell_s)
        self._timeout_ns = _ns(s.temperature_timeout_s)
        self._band = s.speed_tolerance * s.commanded_speed_rad_s
        self._span = s.position_max_rad - s.position_min_rad

    # ------------------------------------------------------------------ configuration
    def update_settings(self, settings: EstimatorSettings) -> None:
        """Replace the settings (validated). Steady-state detection and pairing restart (waiting currents are
        dropped uncounted); the statistics are reset when their layout (window, bins) changes."""
        settings.validate()
        old = self.settings
        self.settings = settings
        self._derive()
        for j in self.joints.values():
            j.reset_stream()
        layout = ('position_min_rad', 'position_max_rad', 'ripple_bins', 'temperature_bin_c')
        if any(getattr(old, n) != getattr(settings, n) for n in layout):
            self._stats.clear()

    def set_axis_params(self, name: str, params: AxisParams) -> None:
        """Replace K_T and I_0 of one joint; its statistics restart if they changed."""
        joint = self.joints[name]
        self.axes[name] = params
        kt, i0 = float(params.torque_constant_nm_per_a), float(params.no_load_current_a)
        if (kt, i0) != (joint.kt, joint.i0):
            joint.kt, joint.i0 = kt, i0
            for key in [k for k in self._stats if k[0] == name]:
                del self._stats[key]

    def reset_statistics(self) -> None:
        self._stats.clear()

    # ------------------------------------------------------------------ helpers
    def pending(self, joint: str) -> int:
        """Currents of ``joint`` waiting for their joint state [-]."""
        return len(self.joints[joint].waiting)

    def last_measurement(self, joint: str) -> Measurement | None:
        return self.joints[joint].last

    def _tick(self, stamp_ns: int) -> None:
        if self.clock_ns is None or stamp_ns > self.clock_ns:
            self.clock_ns = stamp_ns
        if self.temperature_time_ns is None and self.last_temperature_c is not None:
            self.temperature_time_ns = self.clock_ns

    def _split(self, names: Sequence[str], n_values: Sequence[int]) -> dict[str, int] | None:
        """Index of each configured joint in the message; counts unknown names and length mismatches."""
        n = len(names)
        if any(k != n for k in n_values):
            named = [j for j in self.order if j in set(names)]
            for joint in named or [UNKNOWN_JOINT]:
                self.counters.reject(joint, R_LENGTH)
            return None
        index: dict[str, int] = {}
        for i, name in enumerate(names):
            if name in self.joints:
                index.setdefault(name, i)
            else:
                self.counters.reject(UNKNOWN_JOINT, R_UNKNOWN)
        return index

    # ------------------------------------------------------------------ inputs
    def on_temperature(self, temperature_c: float) -> str | None:
        """Accept a bearing temperature [degC]; returns the rejection reason or None."""
        t = float(temperature_c)
        reason = None
        if not math.isfinite(t):
            reason = T_NON_FINITE
        elif not TEMPERATURE_RANGE_C[0] <= t <= TEMPERATURE_RANGE_C[1]:
            reason = T_RANGE
        if reason is not None:
            bucket = self.counters.temperature_rejected
            bucket[reason] = bucket.get(reason, 0) + 1
            return reason
        self.last_temperature_c = t
        self.temperature_time_ns = self.clock_ns
        return None

    def on_joint_state(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float],
                       velocities: Sequence[float]) -> list[Measurement]:
        """A ``/joint_states`` message: ``positions`` [rad], ``velocities`` [rad/s]; returns the samples it
        completes (currents that were waiting for it)."""
        stamp_ns = int(stamp_ns)
        self._tick(stamp_ns)
        index = self._split(names, (len(positions), len(velocities)))
        if not index:
            return []
        s = self.settings
        out: list[Measurement] = []
        for name in self.order:
            i = index.get(name)
            if i is None:
                continue
            p, v = float(positions[i]), float(velocities[i])
            if not (math.isfinite(p) and math.isfinite(v)):
                self.counters.reject(name, R_NON_FINITE_JS)
                continue
            joint = self.joints[name]
            hist = joint.history
            prev = hist[-1] if hist else None
            if prev is not None and stamp_ns <= prev[0]:
                self.counters.reject(name, R_STAMP)
                continue
            # steady-state verdict of this joint state
            speed_ok = abs(abs(v) - s.commanded_speed_rad_s) <= self._band
            sign = 1 if v > 0.0 else -1
            if speed_ok:
                if joint.run_sign != sign:
                    joint.run_sign = sign
                    joint.run_start = stamp_ns
            else:
                joint.run_sign = 0
            if not s.position_min_rad <= p <= s.position_max_rad:
                code = 1
            elif not speed_ok:
                code = 2
            elif prev is not None and abs(v - prev[2]) / ((stamp_ns - prev[0]) * 1e-9) > s.max_accel_rad_s2:
                code = 3
            elif stamp_ns - joint.run_start < self._dwell_ns:
                code = 4
            else:
                code = 0
            entry = (stamp_ns, p, v, code)
            hist.append(entry)
            # currents waiting for this joint state
            if joint.waiting:
                keep: deque[tuple[int, float]] = deque()
                tol = self._tol_ns
                for c_stamp, current in joint.waiting:
                    if abs(stamp_ns - c_stamp) <= tol:
                        m = self._judge(name, joint, entry, current)
                        if m is not None:
                            out.append(m)
                    elif stamp_ns - c_stamp > tol:
                        self.counters.reject(name, R_UNPAIRED)
                    else:
                        keep.append((c_stamp, current))
                joint.waiting = keep
        return out

    def on_current(self, stamp_ns: int, names: Sequence[str], currents: Sequence[float]) -> list[Measurement]:
        """A ``/gimbal/motor_current`` message: ``currents`` [A]; returns the samples it completes."""
        stamp_ns = int(stamp_ns)
        self._tick(stamp_ns)
        index = self._split(names, (len(currents),))
        if not index:
            return []
        limit = self.settings.max_current_a
        tol = self._tol_ns
        out: list[Measurement] = []
        for name in self.order:
            i = index.get(name)
            if i is None:
                continue
            current = float(currents[i])
            if not math.isfinite(current):
                self.counters.reject(name, R_NON_FINITE)
                continue
            if abs(current) > limit:
                self.counters.reject(name, R_OVER_CURRENT)
                continue
            joint = self.joints[name]
            hist = joint.history
            match = None
            for entry in reversed(hist):
                if entry[0] <= stamp_ns + tol:
                    if entry[0] >= stamp_ns - tol:
                        match = entry
                    break
            if match is not None:
                m = self._judge(name, joint, match, current)
                if m is not None:
                    out.append(m)
            elif hist and hist[-1][0] > stamp_ns + tol:
                self.counters.reject(name, R_UNPAIRED)
            else:
                if len(joint.waiting) >= WAIT_LENGTH:
                    joint.waiting.popleft()
                    self.counters.reject(name, R_UNPAIRED)
                joint.waiting.append((stamp_ns, current))
        return out

    def _judge(self, name: str, joint: _Joint, entry: tuple[int, float, float, int],
               current: float) -> Measurement | None:
        stamp, p, v, code = entry
        if code:
            self.counters.reject(name, STEADY_STATE_REASONS[code - 1])
            return None
        s = self.settings
        direction = 1 if v > 0.0 else -1
        friction = float(friction_from_current_Eq23(current, joint.kt, joint.i0, float(direction)))
        t = self.last_temperature_c
        plateau = None
        if t is not None and self.temperature_time_ns is not None and \
                stamp - self.temperature_time_ns <= self._timeout_ns:
            plateau = plateau_of(t, s.temperature_bin_c)
        m = Measurement(name, stamp, p, v, current, math.nan if t is None else t, friction, direction)
        self.counters.accepted[name] = self.counters.accepted.get(name, 0) + 1
        joint.last = m
        key = (name, direction, plateau)
        stat = self._stats.get(key)
        if stat is None:
            stat = self._stats[key] = _Stat(s.ripple_bins)
        b = min(max(int((p - s.position_min_rad) / self._span * s.ripple_bins), 0), s.ripple_bins - 1)
        stat.add(friction, p, b)
        if self.plateau_log is not None:
            self.plateau_log.append(math.nan if plateau is None else plateau)
        return m

    # ------------------------------------------------------------------ statistics
    def statistics(self) -> list[dict[str, Any]]:
        """Running statistics, one record per (joint, direction, plateau); see the module docstring.

        Record fields: ``joint``, ``direction`` (+1/-1), ``plateau_c`` (degC or None = no fresh temperature),
        ``count``, ``mean_nm``, ``std_nm`` (sample std, 0 below 2 samples), ``ripple_nm``, ``min_position``,
        ``max_position`` [rad].
        """
        out = []
        for name in self.order:
            records = []
            for (joint, direction, plateau), st in self._stats.items():
                if joint != name:
                    continue
                std = math.sqrt(st.m2 / (st.n - 1)) if st.n >= 2 else 0.0
                records.append(_record(joint, direction, plateau, st.n, st.mean, std, st.ripple(), st.min_pos,
                                       st.max_pos))
            out.extend(sorted(records, key=_direction_sort))
        return out


# ====================================================================================================== offline
@dataclass(frozen=True)
class EstimateResult:
    """Every accepted sample of a bag as arrays (fields of :class:`Measurement`), plus counters and statistics.

    ``plateau_c`` is the statistics plateau of each sample [degC] (NaN: no fresh temperature); ``pending`` the
    currents per joint still waiting for a joint state at the end; ``method`` how it was computed.
    """

    joint: NDArray[np.str_]
    stamp_ns: NDArray[np.int64]
    position_rad: NDArray[np.float64]
    velocity_rad_s: NDArray[np.float64]
    current_a: NDArray[np.float64]
    temperature_c: NDArray[np.float64]
    friction_nm: NDArray[np.float64]
    direction: NDArray[np.int8]
    plateau_c: NDArray[np.float64]
    counters: EstimatorCounters
    statistics: list[dict[str, Any]]
    pending: dict[str, int]
    method: str

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])

    def measurements(self) -> list[Measurement]:
        """The samples as :class:`Measurement` records."""
        return [Measurement(j, s, p, v, c, t, f, d) for j, s, p, v, c, t, f, d in zip(
            self.joint.tolist(), self.stamp_ns.tolist(), self.position_rad.tolist(), self.velocity_rad_s.tolist(),
            self.current_a.tolist(), self.temperature_c.tolist(), self.friction_nm.tolist(),
            self.direction.tolist())]


def merge_order(arrays: ChamberArrays) -> tuple[NDArray[np.int64], NDArray[np.int8], NDArray[np.int64]]:
    """Arrival order of the messages of ``arrays``: (merged position of every temperature, joint-state and
    current message concatenated; kind 0/1/2; index within its stream), sorted by log time, ties temperature <
    joint states < current, then stream order."""
    logs = [arrays.temperature.log_time_ns, arrays.joint_states.log_time_ns, arrays.motor_current.log_time_ns]
    log = np.concatenate([np.asarray(x, dtype=np.int64) for x in logs])
    kind = np.concatenate([np.full(len(x), k, dtype=np.int8) for k, x in enumerate(logs)])
    index = np.concatenate([np.arange(len(x), dtype=np.int64) for x in logs])
    order = np.lexsort((index, kind, log))
    return order, kind[order], index[order]


def feed_arrays(logic: EstimatorLogic, arrays: ChamberArrays) -> list[Measurement]:
    """Feed every message of ``arrays`` to ``logic`` one by one in arrival order (the streaming reference of
    :func:`estimate_arrays`); a joint whose values are all NaN in a message is taken as absent from it."""
    temp = arrays.temperature.temperature_c.tolist()
    js, mc = arrays.joint_states, arrays.motor_current
    js_stamp, mc_stamp = js.stamp_ns.tolist(), mc.stamp_ns.tolist()
    js_cols = [(n, js.position[n].tolist(), js.velocity[n].tolist()) for n in js.names]
    mc_cols = [(n, mc.effort[n].tolist()) for n in mc.names]
    _, kinds, indices = merge_order(arrays)
    out: list[Measurement] = []
    isnan = math.isnan
    for k, i in zip(kinds.tolist(), indices.tolist()):
        if k == 0:
            logic.on_temperature(temp[i])
        elif k == 1:
            names, pos, vel = [], [], []
            for n, p_col, v_col in js_cols:
                p, v = p_col[i], v_col[i]
                if not (isnan(p) and isnan(v)):
                    names.append(n)
                    pos.append(p)
                    vel.append(v)
            out.extend(logic.on_joint_state(js_stamp[i], names, pos, vel))
        else:
            names, cur = [], []
            for n, c_col in mc_cols:
                c = c_col[i]
                if not isnan(c):
                    names.append(n)
                    cur.append(c)
            out.extend(logic.on_current(mc_stamp[i], names, cur))
    return out


def _result_from(measurements: Sequence[Measurement], plateaus: Sequence[float], logic: EstimatorLogic,
                 method: str) -> EstimateResult:
    cols = list(zip(*measurements)) if measurements else [()] * 8
    return EstimateResult(
        joint=np.array(cols[0], dtype=str), stamp_ns=np.array(cols[1], dtype=np.int64),
        position_rad=np.array(cols[2], dtype=np.float64), velocity_rad_s=np.array(cols[3], dtype=np.float64),
        current_a=np.array(cols[4], dtype=np.float64), temperature_c=np.array(cols[5], dtype=np.float64),
        friction_nm=np.array(cols[6], dtype=np.float64), direction=np.array(cols[7], dtype=np.int8),
        plateau_c=np.array(plateaus, dtype=np.float64), counters=logic.counters,
        statistics=logic.statistics(), pending={j: logic.pending(j) for j in logic.order}, method=method)


def estimate_streaming(axes: Mapping[str, AxisParams], settings: EstimatorSettings,
                       arrays: ChamberArrays) -> EstimateResult:
    """:func:`estimate_arrays` by feeding :class:`EstimatorLogic` message by message (the reference)."""
    logic = EstimatorLogic(axes, settings)
    logic.plateau_log = []
    measurements = feed_arrays(logic, arrays)
    return _result_from(measurements, logic.plateau_log, logic, 'streaming')


def estimate_arrays(axes: Mapping[str, AxisParams], settings: EstimatorSettings, arrays: ChamberArrays, *,
                    method: str = 'vectorized') -> EstimateResult:
    """The estimator over a whole bag's arrays (``open_chamber_bag(path).read_arrays()``).

    Gives exactly what :func:`feed_arrays` into a fresh :class:`EstimatorLogic` gives (accepted samples in the
    same order with the same values, the same counters and pending counts); statistics agree to rounding.
    ``method='vectorized'`` (default) uses numpy throughout, with an exact per-current simulation of the waiting
    buffer only for joints where it would overflow; ``'streaming'`` is the message-by-message reference.
    """
    if method == 'streaming':
        return estimate_streaming(axes, settings, arrays)
    if method != 'vectorized':
        raise ConfigError('method', 'must be vectorized or streaming', method)
    return _Vectorized(axes, settings, arrays).run()


class _Vectorized:
    """The vectorised twin of EstimatorLogic over ChamberArrays (same rules, same floating-point operations)."""

    def __init__(self, axes: Mapping[str, AxisParams], settings: EstimatorSettings, arrays: ChamberArrays) -> None:
        settings.validate()
        self.axes = dict(axes)
        self.settings = settings
        self.arrays = arrays
        self.ref = EstimatorLogic(self.axes, settings)   # derived constants and the counters object

    def run(self) -> EstimateResult:
        a = self.arrays
        s = self.settings
        ref = self.ref
        counters = ref.counters
        T, J, C = a.temperature, a.joint_states, a.motor_current
        nT, nJ, nC = len(T.log_time_ns), len(J), len(C)
        n = nT + nJ + nC
        order, kinds, _ = merge_order(a)
        rank = np.empty(n, dtype=np.int64)
        rank[order] = np.arange(n, dtype=np.int64)
        posT, posJ, posC = rank[:nT], rank[nT:nT + nJ], rank[nT + nJ:]

        # arrival clock: latest joint-state/current stamp so far
        stamp_m = np.full(n, _INT64_MIN, dtype=np.int64)
        stamp_m[posJ] = J.stamp_ns
        stamp_m[posC] = C.stamp_ns
        clock_m = np.maximum.accumulate(stamp_m) if n else stamp_m
        first_stamped = np.flatnonzero(kinds != 0)

        # temperatures
        tv = np.asarray(T.temperature_c, dtype=np.float64)
        finite_t = np.isfinite(tv)
        in_range = finite_t & (tv >= TEMPERATURE_RANGE_C[0]) & (tv <= TEMPERATURE_RANGE_C[1])
        for reason, cnt in ((T_NON_FINITE, int(np.count_nonzero(~finite_t))),
                            (T_RANGE, int(np.count_nonzero(finite_t & ~in_range)))):
            if cnt:
                counters.temperature_rejected[reason] = cnt
        t_value_m = np.full(n, np.nan)
        t_value_m[posT] = tv
        t_time_m = np.full(n, _INT64_MIN, dtype=np.int64)
        t_time = clock_m[posT].copy()
        if first_stamped.size:
            t_time[t_time == _INT64_MIN] = stamp_m[first_stamped[0]]
        t_time_m[posT] = t_time
        mark = np.full(n, -1, dtype=np.int64)
        valid_pos = posT[in_range]
        mark[valid_pos] = valid_pos
        last_t_m = np.maximum.accumulate(mark) if n else mark

        # unknown joints
        for name in J.names:
            if name not in self.axes:
                present = ~(np.isnan(J.position[name]) & np.isnan(J.velocity[name]))
                counters.reject(UNKNOWN_JOINT, R_UNKNOWN, int(np.count_nonzero(present)))
        for name in C.names:
            if name not in self.axes:
                counters.reject(UNKNOWN_JOINT, R_UNKNOWN, int(np.count_nonzero(~np.isnan(C.effort[name]))))

        jorder = np.argsort(posJ, kind='stable')
        corder = np.argsort(posC, kind='stable')
        parts = []
        pending: dict[str, int] = {}
        for j_index, name in enumerate(ref.order):
            part, pend = self._joint(name, j_index, J, C, posJ, posC, jorder, corder)
            pending[name] = pend
            if part is not None:
                parts.append(part)

        if parts:
            cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
            key = np.lexsort((cat['entry'], cat['jidx'], cat['emit']))
            cat = {k: v[key] for k, v in cat.items()}
        else:
            cat = {k: np.empty(0, dtype=dt) for k, dt in (
                ('jidx', np.int64), ('stamp', np.int64), ('pos', np.float64), ('vel', np.float64),
                ('cur', np.float64), ('emit', np.int64), ('friction', np.float64), ('direction', np.int8))}

        # temperature at emission and plateau
        emit = cat['emit']
        lt = last_t_m[emit] if emit.size else np.empty(0, dtype=np.int64)
        has_t = lt >= 0
        lt_c = np.where(has_t, lt, 0)
        temperature = np.where(has_t, t_value_m[lt_c] if n else 0.0, np.nan)
        t_age = cat['stamp'] - np.where(has_t, t_time_m[lt_c] if n else 0, 0)
        fresh = has_t & (t_age <= ref._timeout_ns)
        with np.errstate(invalid='ignore'):
            plateau = np.where(fresh, np.round(temperature / s.temperature_bin_c) * s.temperature_bin_c + 0.0,
                               np.nan)
        names = np.array(ref.order, dtype=str)
        joint = names[cat['jidx']] if cat['jidx'].size else np.empty(0, dtype=str)
        counters.accepted = {name: int(np.count_nonzero(cat['jidx'] == i)) for i, name in enumerate(ref.order)}
        result = EstimateResult(
            joint=joint, stamp_ns=cat['stamp'], position_rad=cat['pos'], velocity_rad_s=cat['vel'],
            current_a=cat['cur'], temperature_c=temperature, friction_nm=cat['friction'],
            direction=cat['direction'].astype(np.int8), plateau_c=plateau, counters=counters,
            statistics=[], pending=pending, method='vectorized')
        return dataclasses.replace(result, statistics=statistics_of(result, ref.order, s))

    def _joint(self, name: str, j_index: int, J: Any, C: Any, posJ: NDArray[np.int64], posC: NDArray[np.int64],
               jorder: NDArray[np.int64], corder: NDArray[np.int64]) -> tuple[dict[str, Any] | None, int]:
        s = self.settings
        ref = self.ref
        counters = ref.counters
        params = ref.joints[name]
        # ---- accepted joint states (strictly increasing stamps)
        if name in J.position:
            pj = np.asarray(J.position[name], dtype=np.float64)[jorder]
            vj = np.asarray(J.velocity[name], dtype=np.float64)[jorder]
            finite = np.isfinite(pj) & np.isfinite(vj)
            present = ~(np.isnan(pj) & np.isnan(vj))
            counters.reject(name, R_NON_FINITE_JS, int(np.count_nonzero(present & ~finite)))
            f = np.flatnonzero(finite)
            S = np.asarray(J.stamp_ns, dtype=np.int64)[jorder][f]
            P, V, M = pj[f], vj[f], posJ[jorder][f]
            if S.size > 1:
                ok = np.empty(S.size, dtype=bool)
                ok[0] = True
                ok[1:] = S[1:] > np.maximum.accumulate(S)[:-1]
                counters.reject(name, R_STAMP, int(np.count_nonzero(~ok)))
                S, P, V, M = S[ok], P[ok], V[ok], M[ok]
        else:
            S = np.empty(0, dtype=np.int64)
            P = V = np.empty(0)
            M = np.empty(0, dtype=np.int64)
        nS = S.size
        # ---- steady-state verdicts
        in_win = (s.position_min_rad <= P) & (s.position_max_rad >= P)
        speed_ok = np.abs(np.abs(V) - s.commanded_speed_rad_s) <= ref._band
        acc_bad = np.zeros(nS, dtype=bool)
        if nS > 1:
            dt = (S[1:] - S[:-1]).astype(np.float64) * 1e-9
            acc_bad[1:] = np.abs(V[1:] - V[:-1]) / dt > s.max_accel_rad_s2
        sign = np.where(V > 0.0, 1, -1)
        start = speed_ok.copy()
        if nS > 1:
            start[1:] &= ~(speed_ok[:-1] & (sign[1:] == sign[:-1]))
        start_idx = np.maximum.accumulate(np.where(start, np.arange(nS), 0)) if nS else np.empty(0, np.int64)
        dwell_bad = (S - S[start_idx]) < ref._dwell_ns if nS else np.empty(0, dtype=bool)
        code = np.where(~in_win, 1, np.where(~speed_ok, 2, np.where(acc_bad, 3, np.where(dwell_bad, 4, 0))))

        # ---- currents
        if name not in C.effort:
            return None, 0
        cur = np.asarray(C.effort[name], dtype=np.float64)[corder]
        cs_all = np.asarray(C.stamp_ns, dtype=np.int64)[corder]
        cm_all = posC[corder]
        finite_c = np.isfinite(cur)
        counters.reject(name, R_NON_FINITE, int(np.count_nonzero(~finite_c & ~np.isnan(cur))))
        over = finite_c & (np.abs(np.where(finite_c, cur, 0.0)) > s.max_current_a)
        counters.reject(name, R_OVER_CURRENT, int(np.count_nonzero(over)))
        valid = finite_c & ~over
        Ci, Cs, Cm = cur[valid], cs_all[valid], cm_all[valid]
        tol = ref._tol_ns
        k = np.searchsorted(M, Cm)
        if nS:
            i = np.minimum(np.searchsorted(S, Cs + tol, side='right') - 1, k - 1)
            ic = np.clip(i, 0, nS - 1)
            match = (i >= 0) & (i >= k - HISTORY_LENGTH) & (S[ic] >= Cs - tol)
            newest = S[np.clip(k - 1, 0, nS - 1)]
            late_now = ~match & (k > 0) & (newest > Cs + tol)
            r = np.searchsorted(S, Cs - tol, side='left')
        else:
            i = ic = np.zeros(Cs.size, dtype=np.int64)
            match = late_now = np.zeros(Cs.size, dtype=bool)
            r = np.zeros(Cs.size, dtype=np.int64)
        counters.reject(name, R_UNPAIRED, int(np.count_nonzero(late_now)))
        wait = ~match & ~late_now
        w = np.flatnonzero(wait)
        rw = r[w]
        resolved = rw < nS
        rw_c = np.clip(rw, 0, max(nS - 1, 0))
        exit_pos = np.where(resolved, M[rw_c] if nS else 0, np.iinfo(np.int64).max)
        # occupancy of the waiting buffer just before each entry (exits happen at joint-state positions)
        occupancy = np.arange(w.size) - np.searchsorted(np.sort(exit_pos), Cm[w], side='left')
        alive = np.ones(w.size, dtype=bool)
        if w.size and int(occupancy.max()) >= WAIT_LENGTH:
            alive = _simulate_wait_buffer(Cm[w], exit_pos)
            counters.reject(name, R_UNPAIRED, int(np.count_nonzero(~alive)))
        paired_late = alive & resolved & (S[rw_c] <= Cs[w] + tol if nS else False)
        counters.reject(name, R_UNPAIRED, int(np.count_nonzero(alive & resolved & ~paired_late)))
        pend = int(np.count_nonzero(alive & ~resolved))
        # ---- pairs and verdicts
        pi = np.concatenate([np.flatnonzero(match), w[paired_late]])
        js = np.concatenate([i[match], rw[paired_late]]).astype(np.int64)
        emit = np.concatenate([Cm[match], M[rw[paired_late]] if nS else np.empty(0, np.int64)]).astype(np.int64)
        codes = code[js] if js.size else np.empty(0, dtype=np.int64)
        for c, reason in enumerate(STEADY_STATE_REASONS, start=1):
            counters.reject(name, reason, int(np.count_nonzero(codes == c)))
        ok = codes == 0
        pi, js, emit = pi[ok], js[ok], emit[ok]
        vel = V[js]
        direction = np.where(vel > 0.0, 1, -1)
        friction = friction_from_current_Eq23(Ci[pi], params.kt, params.i0, direction.astype(np.float64))
        part = {'jidx': np.full(pi.size, j_index, dtype=np.int64), 'stamp': S[js], 'pos': P[js], 'vel': vel,
                'cur': Ci[pi], 'emit': emit, 'entry': Cm[pi], 'friction': np.asarray(friction, dtype=np.float64),
                'direction': direction.astype(np.int8)}
        return part, pend


def _simulate_wait_buffer(entry: NDArray[np.int64], exit_pos: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Which waiting currents survive the FIFO buffer of WAIT_LENGTH (False = dropped as unpaired).

    ``entry``: arrival positions (increasing); ``exit_pos``: position of the joint state that resolves each one
    (int64 max if none). Exact replay of EstimatorLogic.on_current's buffer, one waiting current at a time.
    """
    state = [0] * entry.size          # 0 waiting, 1 resolved, 2 dropped
    fifo: deque[int] = deque()
    heap: list[tuple[int, int]] = []
    live = 0
    exits = exit_pos.tolist()
    for w, e in enumerate(entry.tolist()):
        while heap and heap[0][0] < e:
            _, x = heapq.heappop(heap)
            if state[x] == 0:
                state[x] = 1
                live -= 1
        if live >= WAIT_LENGTH:
            x = fifo.popleft()
            while state[x] != 0:
                x = fifo.popleft()
            state[x] = 2
            live -= 1
        fifo.append(w)
        heapq.heappush(heap, (exits[w], w))
        live += 1
    return np.array(state, dtype=np.int8) != 2


def statistics_of(result: EstimateResult, order: Sequence[str], settings: EstimatorSettings) -> list[dict[str, Any]]:
    """Statistics records (as :meth:`EstimatorLogic.statistics`) of the accepted samples of ``result``."""
    out = []
    bins = settings.ripple_bins
    span = settings.position_max_rad - settings.position_min_rad
    for name in order:
        sel = result.joint == name
        if not np.any(sel):
            continue
        f = result.friction_nm[sel]
        p = result.position_rad[sel]
        d = result.direction[sel].astype(np.int64)
        pl = result.plateau_c[sel]
        pl_key = np.where(np.isnan(pl), np.inf, pl)
        b = np.clip(((p - settings.position_min_rad) / span * bins).astype(np.int64), 0, bins - 1)
        keys = np.unique(np.stack([d.astype(np.float64), pl_key]), axis=1)
        for direction, plateau in zip(keys[0].tolist(), keys[1].tolist()):
            g = (d == direction) & (pl_key == plateau)
            x = f[g]
            cnt = np.bincount(b[g], minlength=bins)
            sums = np.bincount(b[g], weights=x, minlength=bins)
            means = sums[cnt > 0] / cnt[cnt > 0]
            ripple = float(means.max() - means.min()) if means.size >= 2 else 0.0
            std = float(np.std(x, ddof=1)) if x.size >= 2 else 0.0
            out.append(_record(name, int(direction), None if math.isinf(plateau) else plateau, x.size,
                               float(np.mean(x)), std, ripple, float(p[g].min()), float(p[g].max())))
    return out
