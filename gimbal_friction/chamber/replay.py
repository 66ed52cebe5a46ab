"""Offline replay of a chamber-test bag through the three nodes' logic (no rclpy), in log-time order.

The same objects and functions the live nodes run, fed with the whole bag at once instead of a message at a time:

- ``friction_feedforward``: :meth:`~gimbal_friction.feedforward.rule.Feedforward.bag_torques` (the rules of
  :meth:`~gimbal_friction.feedforward.rule.Feedforward.message`, evaluated on arrays), with the learned correction
  the node would load (:func:`replay_correction`: ``--correction``, else the node's ``correction_file``), held as
  it is in the file (the replay does not learn);
- ``friction_estimator``: :meth:`~gimbal_friction.estimation.estimator.EstimatorLogic.feed` (the node feeds the
messages of
  each timer tick; the result does not depend on the batching);
- ``residual_logger``: :func:`~gimbal_friction.estimation.residuals.pair_residuals` (the rule of its pairing
  buffer) and
  :func:`~gimbal_friction.streams.residual_row.residual_rows`.

Times follow the one rule of :mod:`gimbal_friction.streams.inputs`: message stamps, with the log time where a stamp is
zero. The residual log has the topics and layouts the live ``residual_logger`` writes (the feedforward as one
JointState per joint-state message with every configured joint present, the measurement, its detail, the residual
and its detail, and the three input topics as recorded); the generated messages are serialized in bulk
(:mod:`~gimbal_friction.recording.cdr`). Throughput: ``bench/REPLAY.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.chamber.summary import replay_summary
from gimbal_friction.common.settings import settings_from_parameters
from gimbal_friction.config.loader import all_axis_params, check_config_files, load_parameters
from gimbal_friction.estimation.estimator import EstimatorCounters, EstimatorLogic, EstimatorSettings
from gimbal_friction.estimation.residuals import pair_residuals
from gimbal_friction.feedforward.correction import Correction, model_identity
from gimbal_friction.feedforward.correction import load as load_correction
from gimbal_friction.feedforward.rule import (
    SOURCE_MEASURED,
    BagTorques,
    Feedforward,
    FeedforwardCounters,
    FeedforwardSettings,
)
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import ChamberBag, RawBatch, open_chamber_bag
from gimbal_friction.recording.cdr import float64_multi_array_cdr_rows, joint_state_cdr_rows, row_blobs
from gimbal_friction.recording.errors import EmptyInputError, RecordingError
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.streams.arrays import ChamberArrays
from gimbal_friction.streams.inputs import effective_time
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, MeasurementArrays, detail_matrix
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS, ResidualRows

Progress = Callable[[str, float], None]

#: the generated topics of the residual log, in id order
_GENERATED_TOPICS = [(topics.FEEDFORWARD, topics.JOINT_STATE_TYPE), (topics.MEASURED, topics.JOINT_STATE_TYPE),
                     (topics.MEASURED_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE),
                     (topics.RESIDUAL, topics.JOINT_STATE_TYPE),
                     (topics.RESIDUAL_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE)]
_LOG_BATCH = 200_000  # messages per write_raw_many call (one progress report each; the chunk compressed last waits)


class ReplayResult(NamedTuple):
    """What :func:`replay_bag` computed and wrote."""

    feedforward: BagTorques            #: what friction_feedforward would have published
    measurements: MeasurementArrays    #: what friction_estimator would have published
    rows: ResidualRows                 #: what residual_logger would have logged
    feedforward_counters: FeedforwardCounters
    estimator_counters: EstimatorCounters
    summary: list[dict[str, Any]]      #: per plateau and direction (replay_summary of chamber/summary.py)
    residual_dir: Path | None
    messages_in: int
    messages_out: int
    findings: list[str]                #: one line per reason the replay matched little or nothing
    correction: str | None = None      #: the learned correction file the feedforward added (None: pure model)

    @property
    def estimate(self) -> MeasurementArrays:
        """The accepted samples (old name of :attr:`measurements`)."""
        return self.measurements


def node_settings(config_paths: Sequence[Path] = ()) -> tuple[dict[str, AxisParams], FeedforwardSettings,
                                                               EstimatorSettings]:
    """The axes and the settings the three nodes would load from the same parameter files."""
    paths = list(config_paths)
    check_config_files(paths)   # a misspelt name is refused, not silently ignored
    axes = all_axis_params(load_parameters(paths))
    ff = settings_from_parameters(FeedforwardSettings, load_parameters(paths, node_name='friction_feedforward'))
    est = settings_from_parameters(EstimatorSettings, load_parameters(paths, node_name='friction_estimator'))
    return axes, ff, est


def replay_correction(axes: Mapping[str, AxisParams], config_paths: Sequence[Path] = (),
                      correction_path: str | Path | None = None) -> tuple[Correction | None, str | None]:
    """The learned correction the feedforward node would add, and where it came from: ``correction_path`` if given
    (it must exist), else the ``correction_file`` parameter of ``friction_feedforward`` in the parameter files
    (unless ``use_correction`` is false; a file that does not exist yet is no correction, as for a node that has
    not learned anything). Raises CorrectionError (one line): a corrupt file, or one learned against other joints
    or parameters than ``axes``."""
    if correction_path is None:
        params = load_parameters(list(config_paths), node_name='friction_feedforward')
        named = str(params.get('correction_file') or '')
        if not named or params.get('use_correction', True) is False or not Path(named).exists():
            return None, None
        correction_path = named
    return load_correction(correction_path, expected=model_identity(axes)), str(correction_path)


def replay_arrays(arrays: ChamberArrays, axes: dict[str, AxisParams], ff_settings: FeedforwardSettings,
                  est_settings: EstimatorSettings, correction: Correction | None = None
                  ) -> tuple[BagTorques, Feedforward, MeasurementArrays, NDArray[np.int64], EstimatorLogic,
                             ResidualRows]:
    """The three nodes' logic over a bag's arrays: the feedforward (with ``correction``, learned against
    ``axes``), the measurements with the log time that completed each, and the residual rows."""
    ff_logic = Feedforward(axes, ff_settings, correction=correction)
    ff = ff_logic.bag_torques(arrays)
    est_logic = EstimatorLogic(axes, est_settings)
    measured, measured_log = est_logic.feed_timed(arrays, final=True)   # the bag is the whole input
    ff_joint, ff_stamp, ff_torque = _flat_feedforward(ff)
    return ff, ff_logic, measured, measured_log, est_logic, pair_residuals(measured, ff_joint, ff_stamp, ff_torque)


def _flat_feedforward(ff: BagTorques) -> tuple[NDArray[np.str_], NDArray[np.int64], NDArray[np.float64]]:
    """(joint, effective stamp, torque) of every joint of every feedforward message."""
    rows, cols = np.nonzero(ff.present)
    joint = np.asarray(ff.joints, dtype=str)[cols] if rows.size else np.empty(0, dtype=str)
    stamp = effective_time(ff.stamp_ns, ff.log_time_ns)[rows]
    return joint, stamp, ff.commands_nm[rows, cols]


def replay_bag(bag_path: str | Path, out_dir: str | Path | None, *, config_paths: Sequence[Path] = (),
               topic_map: Mapping[str, str] | None = None, joint_map: Mapping[str, str] | None = None,
               log_inputs: bool = True, progress: Progress | None = None,
               correction_path: str | Path | None = None) -> ReplayResult:
    """Run the three nodes' logic over a chamber-test bag; write ``out_dir/residuals/`` (if given).

    The feedforward adds the learned correction of :func:`replay_correction` (``correction_path``, else the node's
    ``correction_file``); the residual log's feedforward and residuals are then against the corrected model.

    ``topic_map`` maps contract topics to the bag's (``{'/joint_states': '/robot/joint_states'}``), ``joint_map``
    recorded joint names to configured ones (``{'joint_2': 'elevation'}``). ``findings`` of the result says, one
    line each, why the bag matched little or nothing (an axis not in the bag, no velocity, zero stamps, the
    estimator's reasons, no temperature plateau).

    Raises:
        RecordingError: the bag is missing, not a bag, not CDR, lacks contract topics or has a wrong type (named).
        EmptyInputError: no configured axis in the bag (the joints present, the mapping, ``--joint``), or no
            friction sample accepted (the estimator's reasons); raised before anything is written.
        ConfigError: a bad parameter file.
        CorrectionError: a corrupt correction file, or one learned against other parameters (one line).
    """
    return _replay_bag(bag_path, out_dir, config_paths=config_paths, topic_map=topic_map, joint_map=joint_map,
                       log_inputs=log_inputs, progress=progress, correction_path=correction_path)


def _replay_bag(bag_path: str | Path, out_dir: str | Path | None, *, config_paths: Sequence[Path],
                topic_map: Mapping[str, str] | None, joint_map: Mapping[str, str] | None, log_inputs: bool,
                progress: Progress | None, correction_path: str | Path | None) -> ReplayResult:
    def report(stage: str, frac: float) -> None:
        if progress is not None:
            progress(stage, frac)

    axes, ff_settings, est_settings = node_settings(list(config_paths))
    correction, correction_from = replay_correction(axes, list(config_paths), correction_path)
    bag = open_chamber_bag(bag_path, dict(topic_map) if topic_map else None,
                           joint_map=dict(joint_map) if joint_map else None, axes=list(axes))
    report('reading bag', 0.0)
    arrays, raw = _read_inputs(bag, log_inputs and out_dir is not None)
    report('reading bag', 1.0)
    report('nodes', 0.0)
    ff, ff_logic, measured, measured_log, est_logic, rows = replay_arrays(arrays, axes, ff_settings, est_settings,
                                                                          correction)
    report('nodes', 1.0)
    if not len(measured):   # nothing usable: refuse before anything is written
        why = [f for f in bag.describe(arrays).findings(list(axes)) + _findings(ff, measured, est_logic, [])
               if not f.startswith('not read')]
        msg = f'bag {bag.path}: no friction sample was accepted, nothing written: {"; ".join(why)}'
        raise EmptyInputError(msg)
    report('summary', 0.0)
    summary = replay_summary(arrays, rows, est_settings)
    report('summary', 1.0)
    messages_out = 0
    residual_dir = None
    if out_dir is not None:
        residual_dir = Path(out_dir) / 'residuals'
        with ResidualLogWriter(residual_dir, flush_interval_s=None, chunk_size=1 << 20) as writer:
            report('serializing log', 0.0)
            log_topics, ids, logs, datas, lengths = _log_stream(ff, measured, measured_log, rows, raw)
            report('writing residual log', 0.0)
            total = len(datas)
            for a in range(0, total, _LOG_BATCH):
                b = min(a + _LOG_BATCH, total)
                writer.write_raw_many(log_topics, ids[a:b], logs[a:b], datas[a:b], lengths=lengths[a:b])
                messages_out = b
                report('writing residual log', b / total)
        report('writing residual log', 1.0)
    findings = bag.describe(arrays).findings(list(axes)) + _findings(ff, measured, est_logic, summary)
    return ReplayResult(ff, measured, rows, ff_logic.counters, est_logic.counters, summary, residual_dir,
                        bag.message_count, messages_out, findings, correction_from)


def _findings(ff: BagTorques, measured: MeasurementArrays, est: EstimatorLogic,
              summary: list[dict[str, Any]]) -> list[str]:
    """What the nodes' logic says about a bag that matched little: the estimator's reasons, the temperature."""
    out: list[str] = []
    if len(ff) and not np.any(ff.source == SOURCE_MEASURED):
        out.append('no joint state had a fresh valid temperature (|stamp difference| <= temperature_timeout_s): '
                   'the feedforward used its stale policy throughout')
    for joint in est.order:
        if est.counters.accepted.get(joint, 0):
            continue
        reasons = sorted(est.counters.rejected.get(joint, {}).items(), key=lambda kv: -kv[1])[:4]
        why = ', '.join(f'{r} {n}x' for r, n in reasons) or 'no current paired with a joint state'
        out.append(f'no friction sample of {joint!r} was accepted ({why}); the settings of friction_estimator '
                   f'(method, commanded_speed_rad_s, position window) must match the test')
    if len(measured) and not summary:
        out.append('samples were accepted but no temperature plateau qualified for the summary (the bearing '
                   'temperature stream never held within 1 degC/min over the 30 s before them, or its stamps are '
                   'on another clock than the joint states)')
    return out


class _RawInputs(NamedTuple):
    """The bag's input messages as recorded: (topic, msgtype) list, and per message its id, log time, bytes."""

    topics: list[tuple[str, str]]
    ids: NDArray[np.int64]
    log_time_ns: NDArray[np.int64]
    datas: list[bytes]
    lengths: NDArray[np.int64]   #: of each message's bytes [B]


def _read_inputs(bag: ChamberBag, log_inputs: bool) -> tuple[ChamberArrays, _RawInputs | None]:
    """``bag.read_arrays()`` and, for ``log_inputs``, the raw messages of the three input topics (only those: the
    live logger subscribes to nothing else) in the same pass."""
    if not log_inputs:
        return bag.read_arrays(), None
    ids: list[NDArray[np.int64]] = []
    logs: list[NDArray[np.int64]] = []
    datas: list[bytes] = []
    pairs: dict[tuple[str, str], int] = {}

    lengths: list[NDArray[np.int64]] = []

    def sink(batch: RawBatch) -> None:
        lut = np.array([pairs.setdefault(pair, len(pairs)) for pair in batch.topics] or [0], dtype=np.int64)
        ids.append(lut[batch.topic])
        logs.append(batch.log_time)
        _check_cdr_heads(batch)
        lengths.append(batch.length)
        datas.extend(batch.datas())

    arrays = bag.read_arrays(raw_sink=sink)
    none = np.zeros(0, dtype=np.int64)
    return arrays, _RawInputs(list(pairs), np.concatenate([none, *ids]), np.concatenate([none, *logs]), datas,
                              np.concatenate([none, *lengths]))


def _check_cdr_heads(batch: RawBatch) -> None:
    """Refuse a bag message that is not plain CDR (its first two bytes 0, 0 or 0, 1; 4 bytes at least), checked
    as arrays: the residual log copies the input messages in as they are.

    Raises:
        RecordingError: the first such message, named by topic.
    """
    if not batch.start.shape[0]:
        return
    u8 = np.frombuffer(batch.buffer, dtype=np.uint8)
    short = batch.length < 4
    first = u8[np.minimum(batch.start, max(u8.shape[0] - 2, 0))]
    second = u8[np.minimum(batch.start + 1, max(u8.shape[0] - 1, 0))]
    bad = short | (first != 0) | (second > 1)
    if bad.any():
        k = int(np.argmax(bad))
        topic = batch.topics[int(batch.topic[k])][0]
        head = bytes(u8[batch.start[k]: batch.start[k] + 4])
        msg = f'bag: a {topic} message is not plain CDR (encapsulation header {head!r}): cannot copy it into the log'
        raise RecordingError(msg)


def _by_layout(keys: NDArray[np.int64], serialize: Callable[[NDArray[np.int64], int], NDArray[np.uint8]],
               out: NDArray[np.object_]) -> NDArray[np.int64]:
    """``serialize(rows, key)`` per distinct key (one CDR layout each: an (n, L) matrix), put into ``out`` in the
    order of ``keys`` as one ``bytes`` each; their lengths [B]."""
    uniq = np.unique(keys)
    sizes = np.zeros(keys.shape[0], dtype=np.int64)
    if uniq.size == 1:
        matrix = serialize(np.arange(keys.shape[0], dtype=np.int64), int(uniq[0]))
        sizes[:] = matrix.shape[1]
        out[:] = row_blobs(matrix)
        return sizes
    for key in uniq.tolist():
        rows = np.flatnonzero(keys == key)
        matrix = serialize(rows, key)
        sizes[rows] = matrix.shape[1]
        out[rows] = row_blobs(matrix)
    return sizes


def _log_stream(ff: BagTorques, measured: MeasurementArrays, measured_log: NDArray[np.int64], rows: ResidualRows,
                raw: _RawInputs | None) -> tuple[list[tuple[str, str]], NDArray[np.int64], NDArray[np.int64],
                                                 list[bytes], NDArray[np.int64]]:
    """Every message of the residual log in log-time order (ties: feedforward, measurement, its detail, residual,
    its detail, then inputs): topics, topic ids, log times [ns], CDR bytes and their lengths [B].

    The serialized rows go straight into one object array (a ``bytes`` each, in the order feedforward,
    measurements' four messages, inputs), which one take puts in log-time order: no list per topic in between."""
    n_ff = len(ff)
    n = len(measured)
    n_raw = 0 if raw is None else len(raw.datas)
    pool = np.empty(n_ff + 4 * n + n_raw, dtype=object)
    joints = np.asarray(ff.joints)
    patterns = ff.present @ (1 << np.arange(len(ff.joints), dtype=np.int64)) if n_ff else np.empty(0, np.int64)
    ff_lengths = _by_layout(patterns, lambda r, _: joint_state_cdr_rows(
        ff.stamp_ns[r], joints[ff.present[r[0]]].tolist(), effort=ff.commands_nm[r][:, ff.present[r[0]]]),
        pool[:n_ff])
    stamps = np.asarray(measured.stamp_ns, dtype=np.int64)
    m_detail = detail_matrix(measured)
    r_detail = rows.matrix()
    m_pool = pool[n_ff: n_ff + 4 * n].reshape(n, 4)   # a view: row k holds measurement k's four messages
    m_sizes = np.zeros((n, 4), dtype=np.int64)        # [B]

    def measured_rows(r: NDArray[np.int64] | slice, joint: str) -> None:
        pos, vel = measured.position_rad[r], measured.velocity_rad_s[r]
        for q, matrix in enumerate((
                joint_state_cdr_rows(stamps[r], [joint], pos, vel, measured.friction_nm[r]),
                float64_multi_array_cdr_rows(m_detail[r], joint),
                joint_state_cdr_rows(stamps[r], [joint], pos, vel, rows.residual_nm[r]),
                float64_multi_array_cdr_rows(r_detail[r], joint))):
            m_pool[r, q] = row_blobs(matrix)
            m_sizes[r, q] = matrix.shape[1]

    names = sorted(set(measured.joint.tolist()))
    if len(names) == 1:
        measured_rows(slice(None), names[0])
    else:
        for joint in names:
            measured_rows(np.flatnonzero(measured.joint == joint), joint)
    log_topics = list(_GENERATED_TOPICS)
    ids = [np.zeros(n_ff, dtype=np.int64), np.tile(np.arange(1, 5, dtype=np.int64), n)]
    logs = [np.asarray(ff.log_time_ns, dtype=np.int64), np.repeat(measured_log, 4)]
    # the lengths of what this serialized (its rows; the bag's as recorded), so the writer need not measure them
    sizes = [ff_lengths, m_sizes.reshape(-1)]
    if raw is not None:
        shift = len(log_topics)
        log_topics += raw.topics
        ids.append(raw.ids + shift)
        logs.append(raw.log_time_ns)
        sizes.append(raw.lengths)
        pool[n_ff + 4 * n:] = raw.datas
    all_ids = np.concatenate(ids)
    all_logs = np.concatenate(logs)
    order = np.argsort(all_logs, kind='stable')
    return log_topics, all_ids[order], all_logs[order], pool[order].tolist(), np.concatenate(sizes)[order]


#: the measured_detail / residual_detail layouts, for readers of this module
__all__ = ['MEASUREMENT_FIELDS', 'RESIDUAL_FIELDS', 'ReplayResult', 'node_settings', 'replay_arrays', 'replay_bag']
