r"""The estimator of ``friction_estimator``: measured friction from motor current (pure: no rclpy, no I/O).

One implementation, fed with batches of messages in arrival order (:meth:`EstimatorLogic.feed`): the node feeds the
messages it received since its last timer tick, the offline replay a whole bag; the state carried between batches
makes the result the same however the messages are batched (tested), so live and offline give the same numbers.

**Eq. (23)** of Yu & Shang (2017), the electrical measurement: the motor torque balances friction and inertia,

.. math:: T_f = K_T\,(I - d\,I_0) - J\,\hat\alpha,\qquad d = \operatorname{sign}(\omega)

with the armature current ``I`` [A], the torque constant ``K_T`` [N·m/A], the no-load current ``I_0`` [A] and, for
the observer, the axis inertia ``J`` [kg·m²] (``inertia_kg_m2`` of the axis) and the filtered acceleration
``α̂`` [rad/s²]. ``T_f`` is signed like the motion (docs/ros.md). Friction alone never has the opposite sign, but a
torque that does not depend on the direction of motion (an unbalance under gravity, a cable) can outweigh it in one
direction: such a sample is kept while it opposes the motion by at most ``max_opposing_torque_nm`` (it is what the
motor must supply, and a learned correction needs both directions to tell that torque from friction); beyond, it is
refused (``'friction opposes motion'``; 0 refuses every one).

Two methods (``method`` setting: ``steady_state``, ``observer`` or ``both``):

The acceleration ``α̂`` of a joint state (both methods) is the least-squares slope of the joint velocity over the
accepted joint states of the last ``acceleration_window_s`` (at least the last three; unknown when those span more
than ten windows and 0.25 s, i.e. a gap in the data): at 1 kHz the difference of two successive velocities is
mostly noise.

- **steady_state** — the paper's chamber protocol: a sample counts only at the commanded constant speed, inside
  the position window, with ``|α̂| ≤ max_accel_rad_s2`` (known), after a dwell (in this order, the first failing
  check is the reason: ``'outside position window'``, ``'speed off command'``, ``'acceleration'``, ``'dwell'``);
  J·α̂ is not subtracted (it is small by this rule).
- **observer** — friction while the gimbal works: a sample counts when the speed is away from zero
  (``'observer: speed near zero'``), α̂ is known (``'observer: window'``),
  ``|α̂| ≤ observer_max_accel_rad_s2`` (``'observer: acceleration'``) and the standard error of α̂ is at most
  ``observer_max_accel_noise_rad_s2`` (``'observer: acceleration noise'``).
- **both** — a steady-state sample where the steady-state rules hold, else an observer sample where the observer
  rules hold (the observer's reason is counted otherwise).

Every sample carries its method (:class:`~gimbal_friction.streams.measurement.MeasurementArrays`).

Input rules (rejections counted in ``counters.rejected[joint][reason]``; ``'*'`` = no configured joint):

- joint states: the time of a joint state is its stamp, or its arrival time if the stamp is zero
  (:func:`~gimbal_friction.streams.inputs.effective_time`); NaN/inf position or velocity → ``'non-finite joint
  state'``; a stamp not later than the last accepted one → ``'stamp not increasing'``, unless it is earlier by more
  than ``stamp_reset_s``: then the time source jumped back (a bag played in a loop, simulated time restarted, or
  one sample stamped far in the future before) and the joint's stream restarts from it
  (``'stream restarted (stamp jumped back)'``; currents waiting for a joint state are dropped as ``'unpaired'``).
- currents: NaN/inf → ``'non-finite'``; ``|I| > max_current_a`` → ``'over current rating'``.
- pairing: a current of time ``c`` pairs with the accepted joint state of its joint nearest to ``c`` within
  ``pairing_tolerance_s`` (the earlier one on a tie), decided once a joint state later than ``c + tolerance`` has
  arrived (so arrival order does not matter); none in the window → ``'unpaired'``. A current arriving after
  more than :data:`HISTORY_LENGTH` newer joint states, or pushed out of the :data:`WAIT_LENGTH` buffer of currents
  waiting for their joint state, is ``'unpaired'`` too.
- temperature: the one in force at the sample's stamp (the joint state's): the latest valid temperature (finite,
  in ``[temperature_min_c, temperature_max_c]``) stamped at or before it, whatever the order the messages arrived
  in (:mod:`gimbal_friction.estimation.temperatures`). A paired sample waits until a temperature stamped at or
  after it has arrived, at most ``temperature_wait_s`` of its joint's stamps and
  :data:`~gimbal_friction.estimation.gating.TEMPERATURE_WAIT_STATES` joint states (``feed(..., final=True)`` or
  :meth:`EstimatorLogic.flush` at the end of the input); then it takes the latest of those arrived. Fresh if its
  time and the joint state's differ by at most ``temperature_timeout_s``. The statistics plateau is
  ``round(t / temperature_bin_c) · temperature_bin_c`` when fresh, else unknown.

Statistics (:meth:`EstimatorLogic.statistics`, steady-state samples only, the paper's per-plateau means): per
(joint, direction, plateau) count, mean, sample standard deviation, ripple (peak-to-peak of the mean friction in
``ripple_bins`` position bins across the window) and position range.

>>> logic = EstimatorLogic({'elevation': AxisParams(no_load_current_a=0.01)}, EstimatorSettings(min_dwell_s=0.0))
>>> v = EstimatorSettings().commanded_speed_rad_s
>>> _ = logic.on_temperature(-40.0, stamp_ns=10**9)
>>> for k in range(3):                          # three joint states at 100 Hz: the acceleration is known
...     _ = logic.on_joint_state(10**9 + k * 10**7, ['elevation'], [0.0], [-v])
>>> logic.on_current(10**9 + 2 * 10**7, ['elevation'], [-0.05])
[]
>>> logic.on_joint_state(10**9 + 3 * 10**7, ['elevation'], [0.0], [-v])   # paired: waits for its temperature
[]
>>> (m,) = logic.on_temperature(-39.9, stamp_ns=10**9 + 10**8)    # stamped after the sample: -40.0 was in force
>>> round(m.friction_nm, 6), m.direction, m.temperature_c   # 0.05 N*m/A * (-0.05 A + 0.01 A)
(-0.002, -1, -40.0)

One job in one module: :class:`EstimatorLogic` (its per-message and batch paths share one state and must stay
side by side to stay equal); the rules as data are in :mod:`gimbal_friction.estimation.gating`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import NS_PER_S, ns_from_seconds
from gimbal_friction.common.xp import ARRAY
from gimbal_friction.estimation.gating import (
    _I64_MAX,
    HISTORY_LENGTH,
    INPUT_REASONS,
    MAX_GAP_NS,
    METHODS,
    OBSERVER_MAX_SAMPLES,
    OBSERVER_REASONS,
    R_ACCEL,
    R_DUPLICATE,
    R_DWELL,
    R_LENGTH,
    R_NON_FINITE,
    R_NON_FINITE_JS,
    R_OBS_ACCEL,
    R_OBS_NOISE,
    R_OBS_SPEED,
    R_OBS_WINDOW,
    R_OPPOSES,
    R_OVER_CURRENT,
    R_RESET,
    R_SPEED,
    R_STAMP,
    R_UNKNOWN,
    R_UNPAIRED,
    R_WINDOW,
    STEADY_STATE_REASONS,
    TEMPERATURE_WAIT_STATES,
    UNKNOWN_JOINT,
    WAIT_LENGTH,
    EstimatorCounters,
    EstimatorSettings,
)
from gimbal_friction.estimation.kt import friction_from_current_Eq23
from gimbal_friction.estimation.plateaus import plateau_of
from gimbal_friction.estimation.statistics import GroupStatistics
from gimbal_friction.estimation.temperatures import TemperatureHistory
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.arrays import (
    ChamberArrays,
    JointStateArrays,
    MessageCounts,
    chamber_arrays,
    single_message_arrays,
)
from gimbal_friction.streams.inputs import effective_time, is_fresh, temperature_valid
from gimbal_friction.streams.measurement import METHOD_OBSERVER, METHOD_STEADY_STATE, Measurement, MeasurementArrays

#: the rules as data live in :mod:`gimbal_friction.estimation.gating`; importable from here as before
__all__ = [
    'HISTORY_LENGTH',
    'INPUT_REASONS',
    'MAX_GAP_NS',
    'METHODS',
    'OBSERVER_MAX_SAMPLES',
    'OBSERVER_REASONS',
    'R_ACCEL',
    'R_DUPLICATE',
    'R_DWELL',
    'R_LENGTH',
    'R_NON_FINITE',
    'R_NON_FINITE_JS',
    'R_OBS_ACCEL',
    'R_OBS_NOISE',
    'R_OBS_SPEED',
    'R_OBS_WINDOW',
    'R_OPPOSES',
    'R_OVER_CURRENT',
    'R_RESET',
    'R_SPEED',
    'R_STAMP',
    'R_UNKNOWN',
    'R_UNPAIRED',
    'R_WINDOW',
    'STEADY_STATE_REASONS',
    'UNKNOWN_JOINT',
    'WAIT_LENGTH',
    'EstimatorCounters',
    'EstimatorLogic',
    'EstimatorSettings',
]

class _History(NamedTuple):
    """Accepted joint states of one joint's stream (carried between batches): times [ns], values, verdicts."""

    stamp: NDArray[np.int64]
    pos: NDArray[np.int64]          #: global arrival position
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    code: NDArray[np.int8]          #: steady-state verdict (0 = steady)
    alpha: NDArray[np.float64]      #: observer acceleration [rad/s^2] (NaN: window too short)
    alpha_se: NDArray[np.float64]   #: its standard error [rad/s^2]
    serial: NDArray[np.int64]       #: count of the joint's accepted joint states before this one [-]

    @staticmethod
    def empty() -> _History:
        i, f = np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float64)
        return _History(i, i, f, f, np.empty(0, dtype=np.int8), f, f, i)

    def concat(self, other: _History) -> _History:
        return _History._make(np.concatenate([a, b]) for a, b in zip(self, other, strict=True))

    def tail(self, n: int) -> _History:
        return _History._make(a[-n:] if a.shape[0] > n else a for a in self)


class _Waiting(NamedTuple):
    """Currents waiting for their joint state: time [ns], current [A], global arrival position."""

    stamp: NDArray[np.int64]
    current: NDArray[np.float64]
    pos: NDArray[np.int64]

    @staticmethod
    def empty() -> _Waiting:
        i, f = np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float64)
        return _Waiting(i, f, i)


class _Held(NamedTuple):
    """Friction samples waiting for the temperature at their stamp: the arrival position that paired each, its
    current's arrival position, the serial of its joint state, and the sample (temperature not yet set)."""

    emit: NDArray[np.int64]
    entry: NDArray[np.int64]
    serial: NDArray[np.int64]
    m: MeasurementArrays

    @staticmethod
    def empty() -> _Held:
        i = np.empty(0, dtype=np.int64)
        return _Held(i, i, i, MeasurementArrays.empty())

    def concat(self, other: _Held) -> _Held:
        return _Held(np.concatenate([self.emit, other.emit]), np.concatenate([self.entry, other.entry]),
                     np.concatenate([self.serial, other.serial]), MeasurementArrays.concatenate([self.m, other.m]))

    def select(self, mask: NDArray[np.bool_]) -> _Held:
        return _Held(self.emit[mask], self.entry[mask], self.serial[mask], self.m.select(mask))


@dataclass
class _JointState:
    """Streaming state of one configured joint."""

    kt: float
    i0: float
    inertia: float
    last_stamp: int | None = None          #: last accepted joint-state time [ns]
    run_sign: int = 0                      #: sign of the current constant-speed run (0: none)
    run_start: int = 0                     #: its first stamp [ns]
    speed_ok_last: bool = False
    history: _History = field(default_factory=_History.empty)
    waiting: _Waiting = field(default_factory=_Waiting.empty)
    held: _Held = field(default_factory=_Held.empty)
    serial_next: int = 0                   #: serial of the next accepted joint state [-]

    def restart(self) -> None:
        self.last_stamp = None
        self.run_sign = 0
        self.speed_ok_last = False
        self.history = _History.empty()


class _Emitted(NamedTuple):
    """Measurements of one joint in one batch, with the arrival position that completed each."""

    emit: NDArray[np.int64]
    entry: NDArray[np.int64]
    m: MeasurementArrays


class EstimatorLogic:
    """Turns motor current, joint states and temperature into friction samples and statistics.

    Parameters
    ----------
    axes : Mapping[str, AxisParams]
        Configured joints (in order); ``torque_constant_nm_per_a`` (K_T), ``no_load_current_a`` (I_0) and
        ``inertia_kg_m2`` (J, observer) are used.
    settings : EstimatorSettings
        Validated settings.
    """

    def __init__(self, axes: dict[str, AxisParams], settings: EstimatorSettings) -> None:
        settings.validate()
        if not axes:
            raise ConfigError('axes', 'must name at least one joint')
        self.axes = dict(axes)
        self.order = list(self.axes)
        self.settings = settings
        self.joints = {name: _JointState(float(p.torque_constant_nm_per_a), float(p.no_load_current_a),
                                         float(p.inertia_kg_m2)) for name, p in self.axes.items()}
        self.counters = EstimatorCounters(accepted=dict.fromkeys(self.axes, 0))
        self.last_temperature_c = math.nan       #: latest valid temperature received [°C]
        self.last_temperature_time_s = math.nan  #: its time [s]
        self._temperatures = TemperatureHistory(ns_from_seconds(settings.stamp_reset_s))
        self._seq = 0                            #: global arrival position of the next message
        self._last_log_ns = 0                    #: arrival (log) time of the last message [ns]
        self._stats = self._new_stats()
        self.last: dict[str, MeasurementArrays] = {}

    def _new_stats(self) -> GroupStatistics:
        s = self.settings
        return GroupStatistics(s.ripple_bins, s.position_min_rad, s.position_max_rad)

    # ------------------------------------------------------------------ configuration
    def update_settings(self, settings: EstimatorSettings) -> None:
        """Replace the settings (validated). Steady-state detection and pairing restart (waiting currents are
        dropped uncounted); the statistics are reset when their layout (window, bins) changes."""
        settings.validate()
        old = self.settings
        self.settings = settings
        for j in self.joints.values():
            j.restart()
            j.waiting = _Waiting.empty()
            j.held = _Held.empty()
        self._temperatures.reset_ns = ns_from_seconds(settings.stamp_reset_s)
        t = self._temperatures.value
        self._temperatures.keep((settings.temperature_min_c <= t) & (t <= settings.temperature_max_c))
        layout = ('position_min_rad', 'position_max_rad', 'ripple_bins', 'temperature_bin_c')
        if any(getattr(old, n) != getattr(settings, n) for n in layout):
            self._stats = self._new_stats()
        if not (settings.temperature_min_c <= self.last_temperature_c <= settings.temperature_max_c):
            self.last_temperature_c = self.last_temperature_time_s = math.nan

    def set_axis_params(self, name: str, params: AxisParams) -> None:
        """Replace K_T, I_0 and J of one joint; its statistics restart if K_T or I_0 changed."""
        joint = self.joints[name]
        self.axes[name] = params
        kt, i0 = float(params.torque_constant_nm_per_a), float(params.no_load_current_a)
        joint.inertia = float(params.inertia_kg_m2)
        if (kt, i0) != (joint.kt, joint.i0):
            joint.kt, joint.i0 = kt, i0
            self._stats.drop(lambda key: key[0] == name)

    def reset_statistics(self) -> None:
        self._stats = self._new_stats()

    def pending(self, joint: str) -> int:
        """Currents of ``joint`` waiting for their joint state [-]."""
        return int(self.joints[joint].waiting.stamp.shape[0])

    def held(self, joint: str) -> int:
        """Friction samples of ``joint`` waiting for the temperature at their stamp [-]."""
        return len(self.joints[joint].held.m)

    # ------------------------------------------------------------------ one message at a time (examples, tests)
    def _arrival(self, stamp_ns: int, arrival_ns: int | None) -> int:
        if arrival_ns is not None:
            return int(arrival_ns)
        return int(stamp_ns) if stamp_ns else self._seq

    def on_temperature(self, temperature_c: float, stamp_ns: int = 0, arrival_ns: int | None = None
                       ) -> list[Measurement]:
        """One ``/gimbal/temperature`` message, as a batch of one (see :meth:`feed`)."""
        log = self._arrival(stamp_ns, arrival_ns)
        return self.feed(single_message_arrays('temperature', log, stamp_ns, temperature_c=temperature_c)).records()

    def on_joint_state(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float],
                       velocities: Sequence[float], arrival_ns: int | None = None) -> list[Measurement]:
        """One ``/joint_states`` message (position [rad], velocity [rad/s]), as a batch of one."""
        batch, counts, _ = chamber_arrays(joint_states=[(self._arrival(stamp_ns, arrival_ns), stamp_ns,
                                                         list(names), list(positions), list(velocities), [])],
                                          configured=self.order)
        self.count_messages(counts, None)
        return self.feed(batch).records()

    def on_current(self, stamp_ns: int, names: Sequence[str], currents: Sequence[float],
                   arrival_ns: int | None = None) -> list[Measurement]:
        """One ``/gimbal/motor_current`` message (current [A]), as a batch of one."""
        batch, _, counts = chamber_arrays(currents=[(self._arrival(stamp_ns, arrival_ns), stamp_ns, list(names),
                                                     [], [], list(currents))], configured=self.order)
        self.count_messages(None, counts)
        return self.feed(batch).records()

    def count_messages(self, joint_states: MessageCounts | None, currents: MessageCounts | None) -> None:
        """Count what :func:`~gimbal_friction.streams.arrays.chamber_arrays` found odd in a node's messages (a NaN
        current or an all-NaN joint state is absent from the arrays, so it is counted here)."""
        for counts, nan_reason in ((joint_states, R_NON_FINITE_JS), (currents, R_NON_FINITE)):
            if counts is None:
                continue
            for joint, n in counts.mismatch.items():
                self.counters.reject(joint if joint in self.axes else UNKNOWN_JOINT, R_LENGTH, n)
            for joint, n in counts.duplicate.items():
                self.counters.reject(joint if joint in self.axes else UNKNOWN_JOINT, R_DUPLICATE, n)
            for joint, n in counts.not_a_number.items():
                if joint in self.axes:
                    self.counters.reject(joint, nan_reason, n)

    # ------------------------------------------------------------------ the batch
    def feed(self, batch: ChamberArrays, final: bool = False) -> MeasurementArrays:
        """Process a batch of messages (arrival order = ``log_time_ns`` order; on equal times temperature, then
        joint states, then currents). Returns the samples accepted, in the order they were completed.

        ``final``: the input ends with this batch (a bag, a simulated run): the samples still waiting for the
        temperature at their stamp are given the one known at the end (see ``temperature_wait_s``)."""
        return self.feed_timed(batch, final)[0]

    def flush(self) -> MeasurementArrays:
        """The samples still waiting for their temperature, given the one known now (the input has ended)."""
        return self.feed(chamber_arrays(configured=self.order)[0], final=True)

    # absurd finite inputs (a velocity of 1e308) give NaN or inf verdicts, which refuse the sample; no warnings
    @np.errstate(over='ignore', invalid='ignore', divide='ignore')
    def feed_timed(self, batch: ChamberArrays, final: bool = False) -> tuple[MeasurementArrays, NDArray[np.int64]]:
        """:meth:`feed`, and the arrival (log) time [ns] of the message that completed each sample."""
        t_arr, js, cur = batch.temperature, batch.joint_states, batch.motor_current
        nT, nJ, nC = len(t_arr.log_time_ns), len(js), len(cur)
        n = nT + nJ + nC
        none = np.empty(0, dtype=np.int64)
        if n == 0 and not (final and any(len(j.held.m) for j in self.joints.values())):
            return MeasurementArrays.empty(), none
        logs = np.concatenate([np.asarray(x, dtype=np.int64) for x in (t_arr.log_time_ns, js.log_time_ns,
                                                                         cur.log_time_ns)])
        # by log time, ties in the order of the concatenation (temperature, joint states, currents; each in its
        # own order): a stable sort of the times alone
        order = np.argsort(logs, kind='stable')
        rank = np.empty(n, dtype=np.int64)
        base = self._seq
        rank[order] = np.arange(n, dtype=np.int64) + base
        self._seq += n
        logs_sorted = logs[order]
        if n:
            self._last_log_ns = int(logs_sorted[-1])
        last_pos = self._seq - 1 if final else _I64_MAX
        posT, posJ, posC = rank[:nT], rank[nT:nT + nJ], rank[nT + nJ:]

        # temperatures: the latest valid one before each position
        s = self.settings
        valid, rejected = temperature_valid(t_arr.temperature_c, s.temperature_min_c, s.temperature_max_c)
        for reason, count in rejected.items():
            self.counters.temperature_rejected[reason] = self.counters.temperature_rejected.get(reason, 0) + count
        t_pos = posT[valid]
        t_val = np.asarray(t_arr.temperature_c, dtype=np.float64)[valid]
        t_ns = effective_time(np.asarray(t_arr.stamp_ns, dtype=np.int64)[valid],
                              np.asarray(t_arr.log_time_ns, dtype=np.int64)[valid])
        t_order = np.argsort(t_pos, kind='stable')
        t_pos, t_val, t_ns = t_pos[t_order], t_val[t_order], t_ns[t_order]
        if t_pos.size:
            self.last_temperature_c, self.last_temperature_time_s = float(t_val[-1]), float(t_ns[-1]) / NS_PER_S
        self._temperatures.extend(t_pos, t_ns, t_val)

        for name in js.names:
            if name not in self.axes:
                present = ~(np.isnan(js.position[name]) & np.isnan(js.velocity[name]))
                self.counters.reject(UNKNOWN_JOINT, R_UNKNOWN, int(np.count_nonzero(present)))
        for name in cur.names:
            if name not in self.axes:
                self.counters.reject(UNKNOWN_JOINT, R_UNKNOWN, int(np.count_nonzero(~np.isnan(cur.effort[name]))))

        parts: list[_Emitted] = []
        for name in self.order:
            emitted = self._joint(name, js, cur, posJ, posC, last_pos)
            if emitted is not None and len(emitted.m):
                parts.append(emitted)
            state = self.joints[name]
            if emitted is None and len(state.held.m):   # no message of the joint: a temperature may release some
                rest = self._release(state, _Held.empty(), state.history, last_pos)
                if len(rest.m):
                    parts.append(rest)
        self._temperatures.trim()
        if not parts:
            return MeasurementArrays.empty(), none
        joint_rank = {name: i for i, name in enumerate(self.order)}
        emit = np.concatenate([p.emit for p in parts])
        entry = np.concatenate([p.entry for p in parts])
        jr = np.concatenate([np.full(len(p.m), joint_rank[str(p.m.joint[0])]) for p in parts])
        out = MeasurementArrays.concatenate([p.m for p in parts])
        order_out = np.lexsort((entry, jr, emit))
        if not _is_identity(order_out):   # (one joint: usually already in order; a take copies every column)
            out, emit, jr = out.select(order_out), emit[order_out], jr[order_out]
        emit_log = np.where(emit >= base, logs_sorted[np.clip(emit - base, 0, max(n - 1, 0))]
                            if n else self._last_log_ns, self._last_log_ns).astype(np.int64)
        for rank_j, name in enumerate(self.order):
            sel = jr == rank_j
            count = int(np.count_nonzero(sel))
            if count:
                self.counters.accepted[name] = self.counters.accepted.get(name, 0) + count
                self.last[name] = out.select(np.flatnonzero(sel)[-1:])
        steady = np.flatnonzero(out.method == METHOD_STEADY_STATE)
        if steady.size:
            fresh = out.temperature_fresh[steady]
            plateau = np.where(fresh, plateau_of(out.temperature_c[steady], s.temperature_bin_c), np.nan)
            keys, gid = _statistics_groups(out.joint[steady], jr[steady], out.velocity_rad_s[steady], plateau)
            self._stats.add_groups(keys, gid, out.friction_nm[steady], out.position_rad[steady])
        return out, emit_log

    # ------------------------------------------------------------------ one joint
    def _joint(self, name: str, js: JointStateArrays, cur: JointStateArrays, posJ: NDArray[np.int64],
               posC: NDArray[np.int64], last_pos: int) -> _Emitted | None:
        s = self.settings
        state = self.joints[name]
        counters = self.counters
        # ---- joint states of this joint, in arrival order
        if name in js.position:
            pj = np.asarray(js.position[name], dtype=np.float64)
            vj = np.asarray(js.velocity[name], dtype=np.float64)
            present = ~(np.isnan(pj) & np.isnan(vj))
            finite = np.isfinite(pj) & np.isfinite(vj)
            counters.reject(name, R_NON_FINITE_JS, int(np.count_nonzero(present & ~finite)))
            sel = np.flatnonzero(finite)
            sel = sel[np.argsort(posJ[sel], kind='stable')]
            stamp = effective_time(np.asarray(js.stamp_ns, dtype=np.int64)[sel],
                                   np.asarray(js.log_time_ns, dtype=np.int64)[sel])
            J_pos, J_p, J_v = posJ[sel], pj[sel], vj[sel]
        else:
            stamp = J_pos = np.empty(0, dtype=np.int64)
            J_p = J_v = np.empty(0, dtype=np.float64)
        # ---- currents of this joint, in arrival order
        if name in cur.effort:
            cj = np.asarray(cur.effort[name], dtype=np.float64)
            present_c = ~np.isnan(cj)
            finite_c = np.isfinite(cj)
            counters.reject(name, R_NON_FINITE, int(np.count_nonzero(present_c & ~finite_c)))
            over = finite_c & (np.abs(np.where(finite_c, cj, 0.0)) > s.max_current_a)
            counters.reject(name, R_OVER_CURRENT, int(np.count_nonzero(over)))
            csel = np.flatnonzero(finite_c & ~over)
            csel = csel[np.argsort(posC[csel], kind='stable')]
            C_stamp = effective_time(np.asarray(cur.stamp_ns, dtype=np.int64)[csel],
                                     np.asarray(cur.log_time_ns, dtype=np.int64)[csel])
            C_cur, C_pos = cj[csel], posC[csel]
        else:
            C_stamp = C_pos = np.empty(0, dtype=np.int64)
            C_cur = np.empty(0, dtype=np.float64)
        if stamp.size == 0 and C_stamp.size == 0:
            return None
        # ---- accepted joint states, split where the stream restarts
        accepted, resets = _accept_stamps(state.last_stamp, stamp, ns_from_seconds(s.stamp_reset_s))
        counters.reject(name, R_STAMP, int(np.count_nonzero(~accepted)))
        counters.reject(name, R_RESET, len(resets))
        bounds = [0, *resets, stamp.size]
        parts: list[_Emitted] = []
        for k in range(len(bounds) - 1):
            lo, hi = bounds[k], bounds[k + 1]
            if k > 0:  # the stream restarts at joint state `lo`
                counters.reject(name, R_UNPAIRED, int(state.waiting.stamp.shape[0]))
                state.waiting = _Waiting.empty()
                state.restart()
            ok = accepted[lo:hi]
            seg_end = J_pos[hi] if hi < stamp.size else _I64_MAX
            seg_start = J_pos[lo] if k > 0 else -1
            in_seg = (C_pos >= seg_start) & (C_pos < seg_end)
            parts.append(self._segment(name, state, stamp[lo:hi][ok], J_pos[lo:hi][ok], J_p[lo:hi][ok],
                                       J_v[lo:hi][ok], C_stamp[in_seg], C_cur[in_seg], C_pos[in_seg],
                                       last_pos))
        emit = np.concatenate([p.emit for p in parts])
        entry = np.concatenate([p.entry for p in parts])
        return _Emitted(emit, entry, MeasurementArrays.concatenate([p.m for p in parts]))

    def _segment(self, name: str, state: _JointState, S: NDArray[np.int64], A: NDArray[np.int64],
                 P: NDArray[np.float64], V: NDArray[np.float64], C_stamp: NDArray[np.int64],
                 C_cur: NDArray[np.float64], C_pos: NDArray[np.int64], last_pos: int) -> _Emitted:
        s = self.settings
        counters = self.counters
        new = self._verdicts(state, S, A, P, V)
        full = state.history.concat(new)
        if S.size:
            state.last_stamp = int(S[-1])
        # ---- currents: the carried waiting ones first
        w = state.waiting
        c_stamp = np.concatenate([w.stamp, C_stamp])
        c_cur = np.concatenate([w.current, C_cur])
        c_pos = np.concatenate([w.pos, C_pos])
        tol = ns_from_seconds(s.pairing_tolerance_s)
        FS, FA = full.stamp, full.pos
        nF = FS.shape[0]
        r = np.searchsorted(FS, c_stamp + tol, side='right')          # first joint state beyond the window
        decided = r < nF
        decide_pos = np.where(decided, np.maximum(c_pos, FA[np.minimum(r, max(nF - 1, 0))] if nF else 0), _I64_MAX)
        # waiting buffer: currents undecided at their arrival occupy it until decided (FIFO, WAIT_LENGTH)
        waits = decide_pos > c_pos
        alive = np.ones(c_stamp.shape[0], dtype=bool)
        wi = np.flatnonzero(waits)
        if wi.size > WAIT_LENGTH:
            # the buffer overflows only if more than WAIT_LENGTH wait at once: occupancy at each arrival
            entry, leave = c_pos[wi], _sorted(decide_pos[wi])
            occupancy = np.arange(wi.size) - np.searchsorted(leave, entry, side='left')
            if int(occupancy.max()) >= WAIT_LENGTH:
                alive[wi] = _simulate_wait_buffer(entry, decide_pos[wi])
                counters.reject(name, R_UNPAIRED, int(np.count_nonzero(~alive)))
        pending = alive & ~decided
        state.waiting = _Waiting(c_stamp[pending], c_cur[pending], c_pos[pending])
        go = np.flatnonzero(alive & decided)
        c_stamp, c_cur, c_pos, r, decide_pos = c_stamp[go], c_cur[go], c_pos[go], r[go], decide_pos[go]
        # the nearest joint state within the window, still in the history when the current arrived
        lo = np.searchsorted(FS, c_stamp - tol, side='left')
        j = np.searchsorted(FS, c_stamp, side='left')
        before = np.clip(j - 1, 0, max(nF - 1, 0))
        after = np.clip(j, 0, max(nF - 1, 0))
        d_before = np.where((j - 1 >= lo) & (j - 1 < r), np.abs(c_stamp - FS[before]) if nF else 0, _I64_MAX)
        d_after = np.where((j >= lo) & (j < r), np.abs(FS[after] - c_stamp) if nF else 0, _I64_MAX)
        idx = np.where(d_before <= d_after, before, after)
        found = np.minimum(d_before, d_after) < _I64_MAX
        arrived_before = np.searchsorted(FA, c_pos, side='left')
        found &= idx >= arrived_before - HISTORY_LENGTH
        counters.reject(name, R_UNPAIRED, int(np.count_nonzero(~found)))
        c_cur, c_pos, idx, decide_pos = c_cur[found], c_pos[found], idx[found], decide_pos[found]
        # ---- verdicts and friction
        direction = np.where(full.velocity[idx] > 0.0, 1.0, -1.0)
        base = friction_from_current_Eq23(c_cur, state.kt, state.i0, direction)
        steady_ok = full.code[idx] == 0
        obs_code = self._observer_code(full, idx)
        method = s.method
        if method == 'steady_state':
            use_steady, use_obs = steady_ok, np.zeros_like(steady_ok)
            for code, reason in enumerate(STEADY_STATE_REASONS, start=1):
                counters.reject(name, reason, int(np.count_nonzero(full.code[idx] == code)))
        elif method == 'observer':
            use_steady, use_obs = np.zeros_like(steady_ok), obs_code == 0
            for code, reason in enumerate(OBSERVER_REASONS, start=1):
                counters.reject(name, reason, int(np.count_nonzero(obs_code == code)))
        else:
            use_steady = steady_ok
            use_obs = ~steady_ok & (obs_code == 0)
            for code, reason in enumerate(OBSERVER_REASONS, start=1):
                counters.reject(name, reason, int(np.count_nonzero(~steady_ok & (obs_code == code))))
        alpha = np.where(use_obs, full.alpha[idx], 0.0)
        inertia = np.where(use_obs, state.inertia, 0.0)
        friction = base - inertia * alpha
        take = (use_steady | use_obs)
        opposing = s.max_opposing_torque_nm
        opposes = take & ~((friction * direction > 0.0) if opposing <= 0.0 else (friction * direction >= -opposing))
        counters.reject(name, R_OPPOSES, int(np.count_nonzero(opposes)))
        take &= ~opposes
        k = np.flatnonzero(take)
        idx_k = idx[k]
        nk = k.shape[0]
        m = MeasurementArrays(
            np.full(nk, name), full.stamp[idx_k].astype(np.int64), full.position[idx_k],
            full.velocity[idx_k], alpha[k], c_cur[k], np.full(nk, np.nan), np.zeros(nk, dtype=bool),
            friction[k], np.full(nk, state.kt), np.full(nk, state.i0), inertia[k],
            np.where(use_obs[k], METHOD_OBSERVER, METHOD_STEADY_STATE).astype(np.int8))
        # ---- the temperature at the sample's stamp (waiting for it, bounded), then carry the history
        out = self._release(state, _Held(decide_pos[k], c_pos[k], full.serial[idx_k], m), full, last_pos)
        state.history = full.tail(max(HISTORY_LENGTH, OBSERVER_MAX_SAMPLES))
        return out

    def _release(self, state: _JointState, new: _Held, full: _History, last_pos: int) -> _Emitted:
        """The samples (held ones first, then ``new``) whose temperature is known: a temperature stamped at or after
        the sample has arrived, or the wait is over (``temperature_wait_s`` of the joint's stamps, or
        TEMPERATURE_WAIT_STATES of its joint states, or the input ended at ``last_pos``). Each is given the latest
        temperature stamped at or before it among those arrived by then; the others stay held."""
        s = self.settings
        held = state.held.concat(new) if len(state.held.m) else new
        ts = held.m.stamp_ns
        if s.temperature_wait_s > 0.0:
            ready = self._temperatures.ready_position(ts)
            FS, FA, nF = full.stamp, full.pos, full.stamp.shape[0]
            i_time = np.searchsorted(FS, ts + ns_from_seconds(s.temperature_wait_s), side='right')
            i_count = np.searchsorted(full.serial, held.serial + TEMPERATURE_WAIT_STATES, side='left')
            i = np.minimum(i_time, i_count)
            timeout = np.where(i < nF, FA[np.minimum(i, nF - 1)], _I64_MAX) if nF else np.full(ts.shape, _I64_MAX)
            release = np.maximum(held.emit, np.minimum(np.minimum(ready, timeout), last_pos))
        else:
            release = held.emit
        go = release < _I64_MAX
        state.held = held.select(~go)
        out = held if bool(go.all()) else held.select(go)   # (all released: no copy)
        at = release[go]
        value, time_s = self._temperatures.at(out.m.stamp_ns, at)
        fresh = is_fresh(out.m.stamp_ns / NS_PER_S, time_s, s.temperature_timeout_s, ARRAY) & np.isfinite(value)
        cols: dict[str, Any] = dict(zip(MeasurementArrays._fields, out.m, strict=True))
        cols.update(temperature_c=value, temperature_fresh=np.asarray(fresh, dtype=bool))
        return _Emitted(at, out.entry, MeasurementArrays(**cols))

    def _verdicts(self, state: _JointState, S: NDArray[np.int64], A: NDArray[np.int64], P: NDArray[np.float64],
                  V: NDArray[np.float64]) -> _History:
        """Steady-state verdicts and observer accelerations of newly accepted joint states (carry included)."""
        s = self.settings
        n = S.shape[0]
        if n == 0:
            return _History.empty()
        hist = state.history
        band = s.speed_tolerance * s.commanded_speed_rad_s
        in_win = (s.position_min_rad <= P) & (s.position_max_rad >= P)
        speed_ok = np.abs(np.abs(V) - s.commanded_speed_rad_s) <= band
        sign = np.where(V > 0.0, 1, -1)
        # acceleration: one estimate for both methods, the least-squares slope over the acceleration window
        alpha, alpha_se = _window_slope(np.concatenate([hist.stamp, S]), np.concatenate([hist.velocity, V]),
                                        hist.stamp.shape[0], ns_from_seconds(s.acceleration_window_s))
        acc_bad = ~(np.abs(alpha) <= s.max_accel_rad_s2)   # unknown (fewer than 3 joint states yet): not steady
        # dwell: constant-speed runs (same sign, speed within tolerance)
        prev_ok = np.concatenate([[state.speed_ok_last], speed_ok[:-1]])
        prev_sign = np.concatenate([[state.run_sign or 0], sign[:-1]])
        start = speed_ok & ~(prev_ok & (sign == prev_sign))
        idx = np.where(start, np.arange(n), -1)
        last_start = np.maximum.accumulate(idx)
        run_start = np.where(last_start >= 0, S[np.maximum(last_start, 0)], state.run_start)
        dwell_bad = (S - run_start) < ns_from_seconds(s.min_dwell_s)
        code = np.where(~in_win, 1, np.where(~speed_ok, 2, np.where(acc_bad, 3, np.where(dwell_bad, 4, 0))))
        state.speed_ok_last = bool(speed_ok[-1])
        state.run_sign = int(sign[-1]) if speed_ok[-1] else 0
        state.run_start = int(run_start[-1])
        serial = state.serial_next + np.arange(n, dtype=np.int64)
        state.serial_next += n
        return _History(S, A, P, V, code.astype(np.int8), alpha, alpha_se, serial)

    def _observer_code(self, full: _History, idx: NDArray[np.intp]) -> NDArray[np.int64]:
        s = self.settings
        v, a, se = full.velocity[idx], full.alpha[idx], full.alpha_se[idx]
        return np.where(np.abs(v) < s.observer_min_speed_rad_s, 1,
                        np.where(~np.isfinite(a), 2,
                                 np.where(np.abs(a) > s.observer_max_accel_rad_s2, 3,
                                          np.where(~(se <= s.observer_max_accel_noise_rad_s2), 4, 0))))

    # ------------------------------------------------------------------ statistics
    def statistics(self) -> list[dict[str, Any]]:
        """Running statistics of the steady-state samples, one record per (joint, direction, plateau), sorted by
        configured joint order, direction (−1 first) and plateau (unknown last).

        Record fields: ``joint``, ``direction`` (+1/-1), ``plateau_c`` (°C or None = no fresh temperature),
        ``count``, ``mean_nm``, ``std_nm`` (sample std, 0 below 2 samples), ``ripple_nm``, ``min_position``,
        ``max_position`` [rad].
        """
        rank = {name: i for i, name in enumerate(self.order)}
        out = []
        for r in self._stats.records():
            joint, direction, plateau = r['key']
            out.append({'joint': joint, 'direction': int(direction), 'plateau_c': plateau, 'count': r['count'],
                        'mean_nm': r['mean'], 'std_nm': r['std'], 'ripple_nm': r['ripple'],
                        'min_position': r['min_position'], 'max_position': r['max_position']})
        out.sort(key=lambda x: (rank.get(x['joint'], len(rank)), x['direction'],
                                math.inf if x['plateau_c'] is None else x['plateau_c']))
        return out


# ====================================================================================================== helpers
def _is_identity(index: NDArray[np.intp]) -> bool:
    """``index`` is ``0, 1, ..., n-1`` (taking it would copy the arrays unchanged)."""
    return bool(index.shape[0] == 0 or (index[0] == 0 and np.all(np.diff(index) == 1)))


def _sorted(a: NDArray[np.int64]) -> NDArray[np.int64]:
    """``np.sort(a)``, without sorting when ``a`` is already in order (currents arriving in stamp order)."""
    return a if a.shape[0] < 2 or bool(np.all(a[1:] >= a[:-1])) else np.sort(a)


def _statistics_groups(joint: NDArray[np.str_], rank: NDArray[np.int64], velocity: NDArray[np.float64],
                       plateau: NDArray[np.float64]) -> tuple[list[tuple[str, int, float | None]],
                                                              NDArray[np.int64]]:
    """The statistics' key of each sample, ``(joint, direction, plateau)`` (plateau NaN: None), as the distinct
    keys in the order each first occurs and the index of each sample's key among them: the keys a per-sample loop
    would build (the first occurrence's values), as arrays. ``rank``: the joint's configured rank."""
    direction = np.where(velocity > 0.0, 1, -1)
    rank = np.asarray(rank, dtype=np.int64)
    unknown = np.isnan(plateau)
    filled = np.where(unknown, 0.0, plateau)
    n = direction.shape[0]
    # runs of equal keys (a plateau and a direction last many samples), then the distinct keys among the runs
    change = np.ones(n, dtype=bool)
    change[1:] = ((rank[1:] != rank[:-1]) | (direction[1:] != direction[:-1]) | (unknown[1:] != unknown[:-1])
                  | (filled[1:] != filled[:-1]))
    starts = np.flatnonzero(change)
    values, p_code = np.unique(filled[starts], return_inverse=True)
    p_code = np.where(unknown[starts], values.shape[0], p_code.reshape(-1))
    code = (rank[starts] * 2 + (direction[starts] > 0)) * (values.shape[0] + 1) + p_code
    _, first_run, inverse_run = np.unique(code, return_index=True, return_inverse=True)
    seen = np.argsort(first_run, kind='stable')        # the groups in the order they first occur
    renumber = np.empty(seen.shape[0], dtype=np.int64)
    renumber[seen] = np.arange(seen.shape[0], dtype=np.int64)
    keys = [(str(joint[i]), int(direction[i]), None if unknown[i] else float(plateau[i]))
            for i in starts[first_run[seen]].tolist()]
    return keys, np.repeat(renumber[inverse_run.reshape(-1)], np.diff(np.append(starts, n)))


def _accept_stamps(last: int | None, stamps: NDArray[np.int64], reset_ns: int) -> tuple[NDArray[np.bool_],
                                                                                          list[int]]:
    """Which joint-state times are accepted (later than every accepted one before), and where the stream
    restarts (a time earlier than the last accepted one by more than ``reset_ns``; accepted as a new start)."""
    n = stamps.shape[0]
    accepted = np.zeros(n, dtype=bool)
    resets: list[int] = []
    prev_max = -_I64_MAX if last is None else int(last)
    start = 0
    while start < n:
        window = 256
        while True:  # look ahead in growing windows: cheap when restarts are frequent, O(n) when rare
            seg = stamps[start:start + window]
            running = np.maximum.accumulate(np.concatenate([[prev_max], seg]))[:-1]
            jump = (seg < running - reset_ns) & (running > -_I64_MAX)
            hit = np.flatnonzero(jump)
            if hit.size or start + window >= n:
                break
            window *= 4
        stop = int(hit[0]) if hit.size else seg.shape[0]
        accepted[start:start + stop] = seg[:stop] > running[:stop]
        if not hit.size:
            if start + seg.shape[0] >= n:
                break
            prev_max = int(max(prev_max, int(seg.max())))
            start += seg.shape[0]
            continue
        at = start + stop
        resets.append(at)
        accepted[at] = True
        prev_max = int(stamps[at])
        start = at + 1
    return accepted, resets


def _window_slope(stamp: NDArray[np.int64], velocity: NDArray[np.float64], first: int, window_ns: int
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares slope of velocity over time [rad/s²] and its standard error, for each sample from ``first``
    on, over the samples of the last ``window_ns`` — at least the last 3, at most OBSERVER_MAX_SAMPLES; NaN where
    there are fewer than 3 or they span more than 10 windows and MAX_GAP_NS (a gap in the data)."""
    n = stamp.shape[0]
    m = np.arange(first, n)
    if m.size == 0:
        return np.empty(0), np.empty(0)
    sm = stamp[first:]
    lo = np.searchsorted(stamp, sm - window_ns, side='right')
    count = np.minimum(np.maximum(m - lo + 1, np.minimum(m + 1, 3)), OBSERVER_MAX_SAMPLES)
    kmax = int(count.max())
    every = int(count.min())   # the terms k < every exist for every sample: no mask (adding 0.0 changes nothing)
    sum_t = np.zeros(m.size)
    sum_v = np.zeros(m.size)
    for k in range(kmax):
        if k < every:
            sum_t += (stamp[first - k:n - k] - sm) / NS_PER_S
            sum_v += velocity[first - k:n - k]
            continue
        use = k < count
        i = np.where(use, m - k, m)
        sum_t += np.where(use, (stamp[i] - sm) / NS_PER_S, 0.0)
        sum_v += np.where(use, velocity[i], 0.0)
    mean_t, mean_v = sum_t / count, sum_v / count
    stt = np.zeros(m.size)
    stv = np.zeros(m.size)
    svv = np.zeros(m.size)
    for k in range(kmax):
        if k < every:
            dt = (stamp[first - k:n - k] - sm) / NS_PER_S - mean_t
            dv = velocity[first - k:n - k] - mean_v
        else:
            use = k < count
            i = np.where(use, m - k, m)
            dt = np.where(use, (stamp[i] - sm) / NS_PER_S - mean_t, 0.0)
            dv = np.where(use, velocity[i] - mean_v, 0.0)
        stt += dt * dt
        stv += dt * dv
        svv += dv * dv
    span = sm - stamp[m - count + 1]
    usable = (count >= 3) & (stt > 0.0) & (span <= max(10 * window_ns, MAX_GAP_NS))
    slope = np.where(usable, stv / stt, np.nan)   # (feed_timed sets np.errstate for the division)
    resid = np.maximum(svv - slope * stv, 0.0)
    se = np.where(count >= 3, np.sqrt(resid / np.maximum(count - 2, 1) / stt), np.nan)
    return slope, se


def _simulate_wait_buffer(entry: NDArray[np.int64], exit_pos: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Which waiting currents survive the FIFO buffer of WAIT_LENGTH (False = dropped as unpaired).

    ``entry``: arrival positions (increasing); ``exit_pos``: position at which each is decided (int64 max if not
    yet). Exact replay of a FIFO that holds at most WAIT_LENGTH currents and drops the oldest on overflow.
    """
    import heapq
    state = [0] * entry.size          # 0 waiting, 1 decided, 2 dropped
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
