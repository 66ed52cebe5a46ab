"""Offline replay of a chamber-test bag through the three nodes' logic (no rclpy), in log-time order.

Feedforward (:class:`~gimbal_friction.core.feedforward.FeedforwardLogic`'s table, smooth sign, direction factor
and clamp), estimator (:func:`~gimbal_friction.core.estimator.estimate_arrays`, bit-identical to the streaming
logic of ``friction_estimator``) and the residual records of ``residual_logger`` are computed per bag, vectorised
with numpy where that keeps the numbers equal to the per-message code of the live nodes. Timing: the nodes judge
temperature staleness by arrival time, the replay by log time (the arrival time of a recording).

The residual log is built in bulk: the generated messages are serialized per joint with
:mod:`~gimbal_friction.recording.cdr`, put in log-time order with a stable sort (the order ``heapq.merge`` of the
per-message streams gives) and written with ``ResidualLogWriter.write_raw_many``, so the files are byte for byte
those of writing message by message (``test/tools/test_replay_log.py``); throughput: ``bench/REPLAY.md``.
"""

from __future__ import annotations

import heapq
import itertools
import operator
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, NamedTuple, Sequence

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
from gimbal_friction.core.arrays import ChamberArrays
from gimbal_friction.recording.bag import ChamberBag, default_typestore, open_chamber_bag
from gimbal_friction.recording.cdr import float64_multi_array_cdr_rows, joint_state_cdr_rows, split_rows
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


class _Stream(NamedTuple):
    """Messages to log, in the order they are produced: topic (index into a topic list), log time, CDR bytes."""

    topic_ids: NDArray[np.int64]
    log_time_ns: NDArray[np.int64]
    datas: list[bytes]


#: topics of the generated messages, in the order of the ids of :func:`_generated_streams`
_GENERATED_TOPICS = [(topics.FEEDFORWARD, topics.JOINT_STATE_TYPE), (topics.MEASURED, topics.JOINT_STATE_TYPE),
                     (topics.RESIDUAL, topics.JOINT_STATE_TYPE),
                     (topics.RESIDUAL_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE)]
_LOG_BATCH = 20000  # messages per write_raw_many call (one progress report each)


def _by_joint(joints: NDArray[np.str_], serialize: Callable[[NDArray[np.int64], str], list[bytes]]
              ) -> list[bytes]:
    """``serialize(rows, joint)`` per joint (one CDR layout each), put back in the order of ``joints``."""
    if len(joints) == 0:
        return []
    names = np.unique(joints)
    if len(names) == 1:
        return serialize(np.arange(len(joints)), str(names[0]))
    out: list[bytes] = [b''] * len(joints)
    for name in names.tolist():
        rows = np.flatnonzero(joints == name)
        for k, data in zip(rows.tolist(), serialize(rows, name)):
            out[k] = data
    return out


def _generated_streams(ff: FeedforwardArrays, est: EstimateResult, pred: NDArray[np.float64],
                       temp: NDArray[np.float64], comps: NDArray[np.float64], est_log_ns: NDArray[np.int64],
                       ) -> tuple[_Stream, _Stream]:
    """The feedforward stream, and the measured / residual / residual_detail stream, each at its input's log time.

    Per joint state: a feedforward JointState (the joint, ``effort`` = feedforward). Per accepted measurement with
    a paired feedforward, in estimator order: measured and residual JointStates (position, velocity and the
    measured friction or the residual as ``effort``) and the residual_detail row of :data:`~.topics.RESIDUAL_FIELDS`
    labelled with the joint. The messages of a joint share one CDR layout and are serialized in bulk.
    """
    ff_datas = _by_joint(ff.joint, lambda r, j: split_rows(joint_state_cdr_rows(ff.stamp_ns[r], [j],
                                                                                effort=ff.torque_nm[r])))
    ff_stream = _Stream(np.zeros(len(ff_datas), dtype=np.int64), np.asarray(ff.log_time_ns, dtype=np.int64),
                        ff_datas)
    ok = np.flatnonzero(np.isfinite(pred))
    stamp = np.asarray(est.stamp_ns, dtype=np.int64)[ok]
    pos, vel = est.position_rad[ok], est.velocity_rad_s[ok]
    meas, pre = est.friction_nm[ok], pred[ok]
    res = meas - pre
    detail = np.column_stack([stamp * 1e-9, temp[ok], pos, vel, est.current_a[ok], meas, pre, comps[ok, 0],
                              comps[ok, 1], comps[ok, 2], res])

    def measured(r: NDArray[np.int64], j: str) -> list[bytes]:
        out: list[bytes] = [b''] * (3 * len(r))
        out[0::3] = split_rows(joint_state_cdr_rows(stamp[r], [j], pos[r], vel[r], meas[r]))
        out[1::3] = split_rows(joint_state_cdr_rows(stamp[r], [j], pos[r], vel[r], res[r]))
        out[2::3] = split_rows(float64_multi_array_cdr_rows(detail[r], j))
        return out

    joints = est.joint[ok]
    names = np.unique(joints).tolist()
    if len(names) <= 1:
        m_datas = measured(np.arange(len(ok)), str(names[0]) if names else '')
    else:  # serialized per joint, put back in measurement order
        m_datas = [b''] * (3 * len(ok))
        for name in names:
            rows = np.flatnonzero(joints == name)
            datas = measured(rows, str(name))
            for q, k in enumerate(rows.tolist()):
                m_datas[3 * k: 3 * k + 3] = datas[3 * q: 3 * q + 3]
    m_stream = _Stream(np.tile(np.arange(1, 4, dtype=np.int64), len(ok)), np.repeat(est_log_ns[ok], 3), m_datas)
    return ff_stream, m_stream


def _merge_order(keys: Sequence[NDArray[np.int64]]) -> NDArray[np.int64]:
    """The order in which ``heapq.merge`` (key = log time, ties: earlier stream first) yields the streams.

    Returns indexes into the concatenated streams. Streams sorted by log time (the usual case): a stable sort.
    Otherwise ``heapq.merge`` itself is run on the keys, so the order is the same as that of the per-message code
    for any input.
    """
    offsets = np.cumsum([0] + [len(k) for k in keys])
    flat = np.concatenate([np.asarray(k, dtype=np.int64) for k in keys]) if keys else np.zeros(0, np.int64)
    if all(len(k) < 2 or bool(np.all(np.diff(k) >= 0)) for k in keys):
        return np.argsort(flat, kind='stable')
    streams = [zip(k.tolist(), range(int(o), int(o) + len(k))) for k, o in zip(keys, offsets)]
    return np.fromiter(map(operator.itemgetter(1), heapq.merge(*streams, key=operator.itemgetter(0))),
                       dtype=np.int64, count=len(flat))


class _RawInputs(NamedTuple):
    """The bag's messages as ``iter_raw`` yields them: topics, and a stream of ids into them."""

    topics: list[tuple[str, str]]
    stream: _Stream


def _read_inputs(bag: ChamberBag, log_inputs: bool) -> tuple[ChamberArrays, _RawInputs | None]:
    """``bag.read_arrays()`` and, for ``log_inputs``, every raw message (as ``bag.iter_raw()``) in the same pass."""
    if not log_inputs:
        return bag.read_arrays(), None
    # three flat lists (not a tuple per message): nothing new for the garbage collector to traverse
    ids: list[int] = []
    logs: list[int] = []
    datas: list[bytes] = []
    pairs: dict[tuple[str, str], int] = {}
    keys: dict[tuple[tuple[str, ...], str], list[int]] = {}

    def sink(contract_topics: Sequence[str], msgtype: str, log_time_ns: int, data: bytes) -> None:
        key = (tuple(contract_topics), msgtype)
        topic_ids = keys.get(key)
        if topic_ids is None:
            topic_ids = keys[key] = [pairs.setdefault((t, msgtype), len(pairs)) for t in contract_topics]
        for topic_id in topic_ids:  # a bag topic feeding several contract topics: once per contract topic
            ids.append(topic_id)
            logs.append(log_time_ns)
            datas.append(data)

    arrays = bag.read_arrays(raw_sink=sink)
    return arrays, _RawInputs(list(pairs), _Stream(np.asarray(ids, dtype=np.int64), np.asarray(logs, dtype=np.int64),
                                                   datas))


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
    arrays, raw = _read_inputs(bag, log_inputs and out_dir is not None)
    report('reading bag', 1.0)
    report('feedforward', 0.0)
    logic = FeedforwardLogic(axes, ff_settings)
    ff = feedforward_arrays(logic, arrays)
    report('feedforward', 1.0)
    report('estimator', 0.0)
    est = estimate_arrays(axes, est_settings, arrays)
    report('estimator', 1.0)
    report('pairing', 0.0)
    pred, temp, comps, where = pair_predictions(ff, est)
    # a measurement is logged when both its joint state and its current have arrived (log time)
    js_log = dict(zip(np.asarray(arrays.joint_states.stamp_ns).tolist(), arrays.joint_states.log_time_ns.tolist()))
    est_log = np.array([js_log.get(int(s), 0) for s in est.stamp_ns.tolist()], dtype=np.int64)
    ok = np.isfinite(pred)
    summary = plateau_summary(est.temperature_c[ok], est.velocity_rad_s[ok], est.friction_nm[ok], pred[ok],
                              joint=est.joint[ok].tolist(), bin_c=est_settings.temperature_bin_c,
                              stamp_s=est.stamp_ns[ok] * 1e-9)
    report('pairing', 1.0)
    messages_out = 0
    residual_dir = None
    if out_dir is not None:
        residual_dir = Path(out_dir) / 'residuals'
        ts = default_typestore()
        with ResidualLogWriter(residual_dir, flush_interval_s=None, chunk_size=1 << 20, typestore=ts) as writer:
            report('writing residual log', 0.0)
            ids, logs, datas, log_topics = _log_stream(ff, est, pred, temp, comps, est_log, raw)
            total = len(datas)
            for a in range(0, total, _LOG_BATCH):
                b = min(a + _LOG_BATCH, total)
                writer.write_raw_many(log_topics, ids[a:b], logs[a:b], datas[a:b])
                messages_out = b
                if b < total:
                    report('writing residual log', b / total)
        report('writing residual log', 1.0)
    del where
    return ReplayResult(ff, est, pred, temp, comps, summary, residual_dir, bag.message_count, messages_out)


def _log_stream(ff: FeedforwardArrays, est: EstimateResult, pred: NDArray[np.float64], temp: NDArray[np.float64],
                comps: NDArray[np.float64], est_log: NDArray[np.int64], raw: _RawInputs | None,
                ) -> tuple[NDArray[np.int64], NDArray[np.int64], list[bytes], list[tuple[str, str]]]:
    """Every message of the residual log in write order: topic ids, log times [ns], CDR bytes, topics.

    The order is that of ``heapq.merge(heapq.merge(feedforward, measured), inputs)`` keyed on log time (ties:
    feedforward, then measured/residual/detail, then inputs), as the live residual logger sees them arrive.
    """
    ff_stream, m_stream = _generated_streams(ff, est, pred, temp, comps, est_log)
    log_topics = list(_GENERATED_TOPICS)
    streams = [ff_stream, m_stream]
    if raw is not None:
        shift = len(log_topics)
        log_topics += raw.topics
        streams.append(raw.stream._replace(topic_ids=raw.stream.topic_ids + shift))
    ids = np.concatenate([x.topic_ids for x in streams])
    logs = np.concatenate([x.log_time_ns for x in streams])
    datas = list(itertools.chain.from_iterable(x.datas for x in streams))
    keys = [x.log_time_ns for x in streams]
    if all(len(k) < 2 or bool(np.all(np.diff(k) >= 0)) for k in keys):
        order = np.argsort(logs, kind='stable')
    else:  # as the nested merges would, even for streams out of log-time order
        inner = _merge_order(keys[:2])
        order = inner
        if len(keys) > 2:
            outer = _merge_order([logs[inner], keys[2]])
            order = np.concatenate([inner, np.arange(len(inner), len(logs))])[outer]
    order_list = order.tolist()
    return ids[order], logs[order], list(map(datas.__getitem__, order_list)), log_topics
