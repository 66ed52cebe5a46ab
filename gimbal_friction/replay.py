"""Offline replay of a chamber-test bag through the three nodes' logic (no rclpy), in log-time order.

Feedforward (:class:`~gimbal_friction.core.feedforward.FeedforwardLogic`'s table, smooth sign, direction factor
and clamp), estimator (:func:`~gimbal_friction.core.estimator.estimate_arrays`, bit-identical to the streaming
logic of ``friction_estimator``) and the residual records of ``residual_logger`` are computed per bag, vectorised
with numpy where that keeps the numbers equal to the per-message code of the live nodes. Timing: the nodes judge
temperature staleness by arrival time, the replay by log time (the arrival time of a recording).
"""

from __future__ import annotations

import heapq
import math
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.config import all_axis_params, load_parameters
from gimbal_friction.core.estimator import EstimateResult, EstimatorSettings, estimate_arrays
from gimbal_friction.core.feedforward import FeedforwardLogic, FeedforwardSettings
from gimbal_friction.core.params import AxisParams
from gimbal_friction.core.residuals import plateau_summary
from gimbal_friction.core.settings import settings_from_parameters
from gimbal_friction.core.table import RPM_PER_RAD_S
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import ChamberArrays, default_typestore, make_float64_multi_array, \
    make_joint_state, open_chamber_bag
from gimbal_friction.recording.residual_log import ResidualLogWriter

Progress = Callable[[str, float], None]


class FeedforwardArrays(NamedTuple):
    """Feedforward of every (joint-state message, configured joint present in it), in message order."""

    msg_index: NDArray[np.int64]      #: index of the joint-state message
    joint: NDArray[np.str_]
    stamp_ns: NDArray[np.int64]
    log_time_ns: NDArray[np.int64]
    temperature_c: NDArray[np.float64]  #: temperature used (NaN: zero policy)
    velocity_rad_s: NDArray[np.float64]
    torque_nm: NDArray[np.float64]      #: signed feedforward [N·m]
    m_rolling_nm: NDArray[np.float64]
    m_sliding_nm: NDArray[np.float64]
    m_viscous_nm: NDArray[np.float64]
    saturated: NDArray[np.bool_]


class ReplayResult(NamedTuple):
    """What :func:`replay_bag` computed and wrote."""

    feedforward: FeedforwardArrays
    estimate: EstimateResult
    predicted_nm: NDArray[np.float64]   #: feedforward paired with each accepted measurement [N·m]
    prediction_temperature_c: NDArray[np.float64]
    m_components_nm: NDArray[np.float64]  #: (n, 3): M_R, M_S, M_L of each measurement [N·m]
    summary: list[dict[str, Any]]
    residual_dir: Path | None
    messages_in: int
    messages_out: int


def node_settings(config_paths: list[Path] | tuple[Path, ...] = ()) -> tuple[dict[str, AxisParams],
                                                                             FeedforwardSettings, EstimatorSettings]:
    """The axes and the settings the three nodes would load from the same parameter files."""
    axes = all_axis_params(load_parameters(config_paths))
    ff = settings_from_parameters(FeedforwardSettings, load_parameters(config_paths, node_name='friction_feedforward'))
    est = settings_from_parameters(EstimatorSettings, load_parameters(config_paths, node_name='friction_estimator'))
    return axes, ff, est


def feedforward_arrays(logic: FeedforwardLogic, arrays: ChamberArrays) -> FeedforwardArrays:
    """The feedforward node's output for every joint-state message of ``arrays`` (vectorised; same numbers)."""
    s = logic.settings
    temp = arrays.temperature
    t_val = np.asarray(temp.temperature_c, dtype=float)
    valid = np.isfinite(t_val) & (t_val >= s.temperature_min_c) & (t_val <= s.temperature_max_c)
    for reason, mask in (('non-finite temperature', ~np.isfinite(t_val)),
                         ('temperature out of range', np.isfinite(t_val) & ~valid)):
        if mask.any():
            logic.counters.temperature_rejected[reason] = logic.counters.temperature_rejected.get(reason, 0) + \
                int(mask.sum())
    t_log = np.asarray(temp.log_time_ns, dtype=np.int64)[valid]
    t_val = t_val[valid]
    js = arrays.joint_states
    js_log = np.asarray(js.log_time_ns, dtype=np.int64)
    # last valid temperature received at or before each joint state (ties: temperature first, as recorded)
    idx = np.searchsorted(t_log, js_log, side='right') - 1
    have = idx >= 0
    age_s = np.where(have, (js_log - t_log[np.maximum(idx, 0)]) * 1e-9, np.inf)
    t_last = np.where(have, t_val[np.maximum(idx, 0)], np.nan)
    fresh = age_s <= s.temperature_timeout_s
    if s.stale_policy == 'hold_last':
        t_used = np.where(fresh | have, t_last, s.fallback_temperature_c)
    elif s.stale_policy == 'zero':
        t_used = np.where(fresh, t_last, np.nan)
    else:
        t_used = np.where(fresh, t_last, s.fallback_temperature_c)
    parts = []
    unknown = [n for n in js.names if n not in logic.axes]
    if unknown:
        present_unknown = np.zeros(len(js), dtype=bool)
        for n in unknown:
            present_unknown |= ~np.isnan(js.velocity[n]) | ~np.isnan(js.position[n])
        logic.counters.joint_state_rejected['unknown joint name'] = \
            logic.counters.joint_state_rejected.get('unknown joint name', 0) + int(present_unknown.sum())
    for name, params in logic.axes.items():
        if name not in js.velocity:
            continue
        v = np.asarray(js.velocity[name], dtype=float)
        sel = ~np.isnan(v) | ~np.isnan(np.asarray(js.position.get(name, v), dtype=float))
        sel &= np.isfinite(v)
        rows = np.flatnonzero(sel)
        vv = v[rows]
        tt = t_used[rows]
        table = logic.tables[name]
        zero = np.isnan(tt)
        m_rs, m_l, _ = table.evaluate(np.where(zero, 20.0, tt), vv * RPM_PER_RAD_S)
        m_r = np.interp(np.clip(np.where(zero, 20.0, tt), table.t_min, table.t_max), table.grid, table._m_r)
        m_s = m_rs - m_r
        magnitude = 1e-3 * (m_rs + m_l)
        k_dir = np.where(vv >= 0.0, params.scale_positive, params.scale_negative)
        torque = np.tanh(vv / s.velocity_threshold_rad_s) * k_dir * magnitude
        sat = np.abs(torque) > s.max_torque_nm
        torque = np.where(sat, np.copysign(s.max_torque_nm, torque), torque)
        torque = np.where(zero, 0.0, torque)
        comps = [np.where(zero, 0.0, 1e-3 * x) for x in (m_r, m_s, m_l)]
        parts.append((rows, np.full(len(rows), name), vv, tt, torque, *comps, sat & ~zero))
    if not parts:
        empty = np.zeros(0)
        return FeedforwardArrays(np.zeros(0, np.int64), np.zeros(0, str), np.zeros(0, np.int64),
                                 np.zeros(0, np.int64), empty, empty, empty, empty, empty, empty,
                                 np.zeros(0, bool))
    cols = [np.concatenate(c) for c in zip(*parts)]
    order = np.lexsort((np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(parts)]), cols[0]))
    rows, joint, vv, tt, torque, m_r, m_s, m_l, sat = (c[order] for c in cols)
    for name in logic.axes:
        n_sat = int(sat[joint == name].sum())
        if n_sat:
            logic.counters.saturated[name] = logic.counters.saturated.get(name, 0) + n_sat
    logic.counters.published += int(len(np.unique(rows)))
    stamps = np.asarray(js.stamp_ns, dtype=np.int64)
    return FeedforwardArrays(rows.astype(np.int64), joint, stamps[rows], js_log[rows], tt, vv, torque, m_r, m_s,
                             m_l, sat)


def pair_predictions(ff: FeedforwardArrays, est: EstimateResult) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                           NDArray[np.float64], NDArray[np.int64]]:
    """For each accepted measurement: the feedforward with the same joint and stamp (its joint state).

    Returns predicted torque [N·m], the temperature it used [°C], components (n, 3) [N·m] and the index into
    ``ff`` (−1 where no feedforward exists; then NaN).
    """
    n = len(est)
    pred = np.full(n, np.nan)
    temp = np.full(n, np.nan)
    comps = np.full((n, 3), np.nan)
    where = np.full(n, -1, dtype=np.int64)
    for name in np.unique(est.joint):
        m_sel = np.flatnonzero(est.joint == name)
        f_sel = np.flatnonzero(ff.joint == name)
        if not len(f_sel):
            continue
        f_stamps = ff.stamp_ns[f_sel]
        order = np.argsort(f_stamps, kind='stable')
        sorted_stamps = f_stamps[order]
        pos = np.searchsorted(sorted_stamps, est.stamp_ns[m_sel])
        pos = np.clip(pos, 0, len(sorted_stamps) - 1)
        hit = sorted_stamps[pos] == est.stamp_ns[m_sel]
        k = f_sel[order[pos[hit]]]
        rows = m_sel[hit]
        where[rows] = k
        pred[rows] = ff.torque_nm[k]
        temp[rows] = ff.temperature_c[k]
        comps[rows] = np.column_stack([ff.m_rolling_nm[k], ff.m_sliding_nm[k], ff.m_viscous_nm[k]])
    return pred, temp, comps, where


def _generated_messages(ff: FeedforwardArrays, est: EstimateResult, pred: NDArray[np.float64],
                        temp: NDArray[np.float64], comps: NDArray[np.float64], est_log_ns: NDArray[np.int64],
                        ) -> Iterator[tuple[int, str, str, object]]:
    """Feedforward, measured, residual and residual_detail messages, each at the log time of its input."""
    js_type, fa_type = topics.JOINT_STATE_TYPE, topics.FLOAT64_MULTI_ARRAY_TYPE
    ff_iter = ((int(ff.log_time_ns[i]), topics.FEEDFORWARD, js_type,
                make_joint_state(int(ff.stamp_ns[i]), [str(ff.joint[i])], effort=[float(ff.torque_nm[i])]))
               for i in range(len(ff.torque_nm)))

    def measured_iter() -> Iterator[tuple[int, str, str, object]]:
        for i in range(len(est)):
            if not math.isfinite(pred[i]):
                continue
            j, stamp, log = str(est.joint[i]), int(est.stamp_ns[i]), int(est_log_ns[i])
            pos, vel, meas = float(est.position_rad[i]), float(est.velocity_rad_s[i]), float(est.friction_nm[i])
            yield log, topics.MEASURED, js_type, make_joint_state(stamp, [j], [pos], [vel], [meas])
            res = meas - float(pred[i])
            yield log, topics.RESIDUAL, js_type, make_joint_state(stamp, [j], [pos], [vel], [res])
            detail = [stamp * 1e-9, float(temp[i]), pos, vel, float(est.current_a[i]), meas, float(pred[i]),
                      float(comps[i, 0]), float(comps[i, 1]), float(comps[i, 2]), res]
            yield log, topics.RESIDUAL_DETAIL, fa_type, make_float64_multi_array(detail, j)

    return heapq.merge(ff_iter, measured_iter(), key=lambda m: m[0])


def replay_bag(bag_path: str | Path, out_dir: str | Path | None, *, config_paths: list[Path] | tuple[Path, ...] = (),
               topic_map: Mapping[str, str] | None = None, log_inputs: bool = True,
               progress: Progress | None = None) -> ReplayResult:
    """Run the three nodes' logic over a chamber-test bag; write ``out_dir/residuals/`` (if given).

    Raises:
        RecordingError: the bag is missing, not a bag, lacks a contract topic or has a wrong type (named).
        ConfigError: a bad parameter file.
    """
    def report(stage: str, frac: float) -> None:
        if progress is not None:
            progress(stage, frac)

    axes, ff_settings, est_settings = node_settings(list(config_paths))
    bag = open_chamber_bag(bag_path, topic_map)
    report('reading bag', 0.0)
    arrays = bag.read_arrays()
    report('reading bag', 1.0)
    logic = FeedforwardLogic(axes, ff_settings)
    ff = feedforward_arrays(logic, arrays)
    est = estimate_arrays(axes, est_settings, arrays)
    pred, temp, comps, where = pair_predictions(ff, est)
    # a measurement is logged when both its joint state and its current have arrived (log time)
    js_log = dict(zip(np.asarray(arrays.joint_states.stamp_ns).tolist(), arrays.joint_states.log_time_ns.tolist()))
    est_log = np.array([js_log.get(int(s), 0) for s in est.stamp_ns.tolist()], dtype=np.int64)
    ok = np.isfinite(pred)
    summary = plateau_summary(est.temperature_c[ok], est.velocity_rad_s[ok], est.friction_nm[ok], pred[ok],
                              joint=est.joint[ok].tolist(), bin_c=est_settings.temperature_bin_c,
                              stamp_s=est.stamp_ns[ok] * 1e-9)
    messages_out = 0
    residual_dir = None
    if out_dir is not None:
        residual_dir = Path(out_dir) / 'residuals'
        total = len(ff.torque_nm) + 3 * int(ok.sum()) + (bag.message_count if log_inputs else 0)
        ts = default_typestore()
        with ResidualLogWriter(residual_dir, flush_interval_s=None, chunk_size=1 << 20, typestore=ts) as writer:
            generated = _generated_messages(ff, est, pred, temp, comps, est_log)
            streams: list[Iterator[tuple[int, str, str, object]]] = [generated]
            if log_inputs:
                streams.append((r.log_time_ns, r.topic, r.msgtype, r.data) for r in bag.iter_raw())
            for log_ns, topic, msgtype, msg in heapq.merge(*streams, key=lambda m: m[0]):
                if isinstance(msg, (bytes, bytearray, memoryview)):
                    writer.write_raw(topic, msgtype, log_ns, msg)
                else:
                    writer.write(topic, msgtype, log_ns, msg)
                messages_out += 1
                if messages_out % 20000 == 0:
                    report('writing residual log', messages_out / max(total, 1))
        report('writing residual log', 1.0)
    del where
    return ReplayResult(ff, est, pred, temp, comps, summary, residual_dir, bag.message_count, messages_out)
