"""``residual_logger``: logs inputs, predictions, measurements and residuals to MCAP for the viscosity refit.

A lifecycle node (``/<node>/change_state``, ``get_state``; docs/ros.md, Lifecycle): ``autostart`` (default true)
configures and activates it at start-up; ``autostart:=false`` waits for a lifecycle manager.

Subscribes ``/gimbal/temperature``, ``/joint_states``, ``/gimbal/motor_current``, ``/gimbal/friction/feedforward``,
``/gimbal/friction/measured`` and ``/gimbal/friction/measured_detail``. Every received message is logged as it
arrived (raw CDR, log time = receive time; ``log_inputs``). What the estimator measured arrives complete on
``measured_detail`` (current, temperature, K_T and I_0 applied, method): nothing is reconstructed here. Each
measurement is paired with the feedforward published for the same joint and joint-state stamp
(:class:`gimbal_friction.estimation.residuals.ResidualPairing`, the rule ``replay`` and the loop study pair with)
and logged as a residual row
(:func:`gimbal_friction.streams.residual_row.residual_rows`):

- ``/gimbal/friction/residual`` (sensor_msgs/JointState): name = [joint], position [rad], velocity [rad/s],
  effort = [measured − predicted] [N·m], stamp = the sample's stamp;
- ``/gimbal/friction/residual_detail`` (std_msgs/Float64MultiArray): ``layout.dim[0].label`` = joint, data in the
  order of :data:`gimbal_friction.streams.residual_row.RESIDUAL_FIELDS`.

A measurement whose feedforward has not arrived after ``pairing_timeout_s`` is logged with the prediction NaN
(counted ``no_feedforward``: the sample is still good for the refit). A value that is not finite or not credible
(|torque| above 100 N·m) is not logged (counted ``refused``).

Files: ``output_dir/residuals_<n>.mcap`` (ROS 2 profile, CDR, standard types only), flushed every
``flush_period_s`` in small chunks, rotated by ``max_file_mb`` / ``max_file_duration_s``, closed with footer and
``metadata.yaml`` on SIGINT/SIGTERM. If ``output_dir`` already holds a log (an earlier run, or another logger
started with the same folder), this run writes beside it in ``<output_dir>_<UTC yyyymmdd_HHMMSS>``
(the log-folder policy: :mod:`gimbal_friction.recording.log_folder`). A write error (full disk, unwritable
folder) is reported on ``/diagnostics`` (ERROR) and retried every ``retry_period_s``; the node stays up.
``/diagnostics`` also carries messages logged, bytes, current file and the residual RMS per axis and temperature
bin.

Inputs: depth 1000 (the temperature keep-all: a full queue holds a reliable publisher back instead of losing
messages; ``temperature_qos`` on ``/diagnostics``), each following its publishers (:mod:`gimbal_friction.nodes._qos`):
reliable while every publisher is, best-effort as soon as one is not, which a reliable subscription would not hear;
an input that cannot deliver is named on ``/diagnostics``. What is lost on the
way is counted per topic from the publishers' sequence numbers (``lost: <topic>``, a WARN naming it), and, for a
publisher that says how many messages it sent (``chamber_replay``'s ``finished`` status on ``/diagnostics``), as
sent − arrived: also the messages lost before the first or after the last one that arrived, which no sequence gap
shows (``sent: <topic>``; :mod:`gimbal_friction.streams.delivery`). Such a count is taken one diagnostics period
after it arrived, so that the messages still queued have been received.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError
from gimbal_friction.common.settings import settings_from
from gimbal_friction.common.units import join_stamp
from gimbal_friction.config.node_settings import LoggerSettings
from gimbal_friction.estimation.residuals import ResidualPairing, ResidualStats, credible_rows, credible_torque
from gimbal_friction.nodes._common import (
    InputCounter,
    callback_error_values,
    check_changes,
    declare_axes,
    declare_settings,
    diagnostic_array,
    field_names,
    parameter_guard,
    retime,
    run_node,
    split_parameters,
    to_msg,
)
from gimbal_friction.nodes._lifecycle import ManagedNode
from gimbal_friction.nodes._qos import Inputs, create_publisher
from gimbal_friction.recording import topics
from gimbal_friction.recording.cdr import float64_multi_array_cdr_rows, joint_state_cdr_rows, split_rows
from gimbal_friction.recording.log_folder import open_own_folder, rotation_limits, wanted_folder
from gimbal_friction.recording.log_report import LoggerReport
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.streams.delivery import PUBLISHER_STATUS, STATE_FINISHED, Sent, read_publisher_values
from gimbal_friction.streams.inputs import effective_time
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, from_detail
from gimbal_friction.streams.residual_row import ResidualRows

#: subscription depth: a burst of this many messages is buffered, not dropped
DEPTH = 1000
#: the topics the logger subscribes (a publisher's count of what it sent is taken for these only)
SUBSCRIBED = frozenset((topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.MEASURED,
                        topics.FEEDFORWARD, topics.MEASURED_DETAIL))
#: publishers' counts waiting to be taken (a bound: they are untrusted input) [-]
MAX_PENDING_COUNTS = 1024


_SETTINGS = field_names(LoggerSettings)
_LIVE = {'pairing_timeout_s', 'residual_bin_c', 'diagnostics_period_s', 'flush_period_s', 'retry_period_s'}


class ResidualLogger(ManagedNode):
    """The residual logger node (adapter around the core's pairing and rows, and ResidualLogWriter), a lifecycle
    node (:mod:`gimbal_friction.nodes._lifecycle`): with ``autostart`` (the default) configured and active (logging)
    once built. Each activation writes one complete log (its own folder); deactivation closes it."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('residual_logger', **kwargs)

    def parameter_steps(self) -> list[Callable[[], object]]:
        """``axes`` and the logger's settings (declared at construction and by configure)."""
        return [lambda: declare_axes(self), lambda: declare_settings(self, LoggerSettings)]

    def configure_node(self) -> None:
        """The lifecycle's configure: parameters read and validated, subscriptions, publishers and timers made (the
        log is opened on activate)."""
        self.axes = declare_axes(self)
        self._axes_set = frozenset(self.axes)
        self.settings = declare_settings(self, LoggerSettings)
        self.inputs = InputCounter()
        self.report = LoggerReport()   #: the /diagnostics statuses, report after report
        self.stats = ResidualStats(self.settings.residual_bin_c)
        self.writer: ResidualLogWriter | None = None
        self.folder: Path | None = None
        self.error: str | None = None
        self.dropped = 0
        self.residuals_logged = 0
        self.paired = 0
        self.no_feedforward = 0
        self.refused: dict[str, int] = {}
        self._last_retry = -math.inf
        self.pairing = ResidualPairing()   #: the feedforwards kept, the measurements waiting for theirs
        self.pub_diag = create_publisher(self, DiagnosticArray, topics.DIAGNOSTICS, 10, managed=False)
        # every input follows its publishers' reliability (nodes/_qos.py)
        self.input_topics = ins = Inputs(self, self.inputs)
        for topic in (topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.MEASURED):
            ins.add(JointState, topic, self._raw_logger(topic, topics.JOINT_STATE_TYPE), DEPTH, raw=True)
        # the temperature: keep all while reliable (a full queue holds the publisher back: nothing lost); starts
        # best-effort (temperature sensors often are), which hears every publisher
        self._temperature = ins.add(Temperature, topics.TEMPERATURE,
                                    self._raw_logger(topics.TEMPERATURE, topics.TEMPERATURE_TYPE),
                                    QoSProfile(depth=DEPTH, history=HistoryPolicy.KEEP_ALL), raw=True,
                                    start_reliable=False)
        ins.add(JointState, topics.FEEDFORWARD, self.on_feedforward, DEPTH, raw=True)
        ins.add(Float64MultiArray, topics.MEASURED_DETAIL, self.on_measured_detail, DEPTH, raw=True)
        # what publishers say they sent (chamber_replay): counted against what arrived
        self._sent_counts: list[tuple[float, Sent]] = []
        ins.add(DiagnosticArray, topics.DIAGNOSTICS, self.on_diagnostics, 100)
        self._pair_timer = self.create_timer(0.05, self.on_pair_timer)
        self._flush_timer = self.create_timer(self.settings.flush_period_s, self.on_flush_timer)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        parameter_guard(self, self._validate_params, self._apply_params)

    # ------------------------------------------------------------------ log file lifecycle
    def _open_writer(self) -> None:
        s = self.settings
        wanted = wanted_folder(s.output_dir)
        max_bytes, max_duration_s = rotation_limits(s.max_file_mb, s.max_file_duration_s)
        try:
            folder, self.writer = open_own_folder(wanted, lambda f: ResidualLogWriter(
                f, chunk_size=s.chunk_kib * 1024, flush_interval_s=s.flush_period_s, max_bytes=max_bytes,
                max_duration_s=max_duration_s))
            self.folder = folder
            self.error = None
            why = '' if folder == wanted else f' ({wanted} already holds a log: this run writes beside it)'
            self.get_logger().info(f'residual log: {folder}{why}')
        except GimbalFrictionError as err:
            self.writer = None
            self._report_error(str(err))

    def _report_error(self, text: str) -> None:
        if text != self.error:
            self.get_logger().error(f'residual log: {text}')
        self.error = text

    def _write(self, fn: str, *args: Any) -> None:
        if not self.active:   # (not logging: nothing to write to, nothing dropped)
            return
        if self.writer is None:
            self.dropped += 1
            return
        try:
            getattr(self.writer, fn)(*args)
        except GimbalFrictionError as err:
            if self.writer.failed is None and fn == 'write_raw':
                # the writer is fine, this message is not (e.g. XCDR2 from another DDS setup): refuse only it
                self._refuse(f'{args[0]}: message not loggable (not plain CDR)')
                return
            self.dropped += 1
            self._report_error(str(err))
            self._abandon_writer()

    def _abandon_writer(self) -> None:
        writer, self.writer = self.writer, None
        if writer is not None:
            with contextlib.suppress(GimbalFrictionError):
                writer.close()
        self._last_retry = time.monotonic()

    def start_output(self) -> None:
        """The lifecycle's activate: the log opened (an error is reported and retried, as a write error)."""
        self._open_writer()

    def stop_output(self) -> None:
        """The lifecycle's deactivate (and shutdown): the waiting measurements logged, the log finished."""
        self.close_log()

    def close_log(self) -> None:
        """Finish the log (footer, metadata.yaml); on deactivate and shutdown (run_node's close)."""
        if self.writer is not None:
            try:  # the measurements still waiting are logged without a prediction; nothing may stop the close
                self.pair(final=True)
            except Exception as err:
                print(f'residual_logger: error: {self.pairing.waiting} waiting measurements not logged: '
                      f'{type(err).__name__}: {err}', file=sys.stderr)
            try:
                self.writer.close()
                # the ROS context may already be shut down here (SIGINT): report on stderr
                print(f'residual_logger: log closed: {self.folder} ({self.writer.stats.messages} messages)',
                      file=sys.stderr)
            except GimbalFrictionError as err:
                print(f'residual_logger: error: closing the log failed: {err}', file=sys.stderr)
            self.writer = None

    # ------------------------------------------------------------------ callbacks
    def _now_ns(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    def _refuse(self, reason: str, n: int = 1) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + n

    def _raw_logger(self, topic: str, msgtype: str) -> Callable[[bytes], None]:
        def log(data: bytes) -> None:
            self.log_raw(topic, msgtype, data)
        return log

    def log_raw(self, topic: str, msgtype: str, data: bytes) -> None:
        if self.settings.log_inputs:
            self._write('write_raw', topic, msgtype, self._now_ns(), data)

    def on_feedforward(self, data: bytes) -> None:
        self.log_raw(topics.FEEDFORWARD, topics.JOINT_STATE_TYPE, data)
        try:
            msg = deserialize_message(data, JointState)
        except Exception:
            self._refuse('undecodable feedforward')
            return
        stamp = effective_time(join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec), self._now_ns())
        if len(msg.effort) != len(msg.name):
            self._refuse('feedforward effort/name length mismatch')
            return
        credible = credible_torque(msg.effort).tolist()
        seen = set()
        for name, effort, ok in zip(msg.name, msg.effort, credible, strict=True):
            if name not in self._axes_set:
                self._refuse('feedforward of an unknown joint')
            elif name in seen:
                self._refuse('feedforward: duplicate joint name')  # the first entry counts, as everywhere
            elif not ok:
                self._refuse('feedforward not finite or not credible')  # the measurement is logged without it
            else:
                self.pairing.add_feedforward(name, stamp, float(effort))
            seen.add(name)

    def on_measured_detail(self, data: bytes) -> None:
        self.log_raw(topics.MEASURED_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE, data)
        try:
            msg = deserialize_message(data, Float64MultiArray)
        except Exception:
            self._refuse('undecodable measured_detail')
            return
        label = msg.layout.dim[0].label if msg.layout.dim else ''
        if len(msg.data) != len(MEASUREMENT_FIELDS) or not label:
            self._refuse(f'measured_detail not of {len(MEASUREMENT_FIELDS)} values with a joint label')
            return
        if label not in self._axes_set:
            self._refuse('measured_detail of an unknown joint')
            return
        try:
            m = from_detail([label], np.asarray(msg.data, dtype=np.float64).reshape(1, len(MEASUREMENT_FIELDS)))
        except ValueError:
            self._refuse('measured_detail with an invalid stamp or method')
            return
        self.pairing.add_measurement(m, time.monotonic())

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Keep what a publisher says it sent in all (``chamber_replay``'s ``finished`` status) on the topics
        logged here; :meth:`take_sent_counts` counts it against what arrived."""
        for st in msg.status:
            if st.name != PUBLISHER_STATUS:
                continue
            state, sent = read_publisher_values({kv.key: kv.value for kv in st.values})
            if state != STATE_FINISHED:
                continue
            usable = [s for s in sent if s.topic in SUBSCRIBED and s.gid is not None]
            if not usable:
                self._refuse('publisher status without a usable count of what it sent')
            for s in usable:
                if len(self._sent_counts) >= MAX_PENDING_COUNTS:
                    self._refuse('publisher counts beyond the pending limit')
                    break
                self._sent_counts.append((time.monotonic(), s))

    def take_sent_counts(self) -> None:
        """Count the publishers' counts received at least one diagnostics period ago (the messages they sent that
        were still queued here have been received by then) against what arrived: the rest is lost."""
        due = time.monotonic() - self.settings.diagnostics_period_s
        keep = []
        for since, s in self._sent_counts:
            if since <= due and s.gid is not None:
                self.inputs.publisher_sent(s.topic, s.gid, s.sent)
            else:
                keep.append((since, s))
        self._sent_counts = keep

    def on_pair_timer(self) -> None:
        self.pair()

    def pair(self, final: bool = False) -> None:
        """Pair the waiting measurements with the feedforwards received; log the rows that are complete or have
        waited long enough."""
        if not self.pairing.waiting:
            return
        rows = self.pairing.take(time.monotonic(), self.settings.pairing_timeout_s, final)
        if len(rows):
            self.log_rows(rows)   # (non-finite rows are refused there)

    def log_rows(self, rows: ResidualRows) -> None:
        ok = credible_rows(rows)
        self._refuse('not finite or not credible', int(np.count_nonzero(~ok)))
        rows = rows.select(ok)
        n = len(rows)
        if not n:
            return
        paired = int(np.count_nonzero(~np.isnan(rows.predicted_nm)))
        self.paired += paired
        self.no_feedforward += n - paired
        now = self._now_ns()
        stamps = np.round(rows.stamp_s * 1e9).astype(np.int64)
        detail = rows.matrix()
        for k, joint in enumerate(rows.joint.tolist()):
            r = slice(k, k + 1)
            res = split_rows(joint_state_cdr_rows(stamps[r], [joint], rows.position_rad[r], rows.velocity_rad_s[r],
                                                  rows.residual_nm[r]))[0]
            self._write('write_raw', topics.RESIDUAL, topics.JOINT_STATE_TYPE, now, res)
            det = split_rows(float64_multi_array_cdr_rows(detail[r], joint))[0]
            self._write('write_raw', topics.RESIDUAL_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE, now, det)
        self.stats.add(rows)
        self.residuals_logged += n

    def on_flush_timer(self) -> None:
        if not self.active:
            return
        if self.writer is None:
            if time.monotonic() - self._last_retry >= self.settings.retry_period_s:
                self._last_retry = time.monotonic()
                self._open_writer()
            return
        self._write('flush')

    # ------------------------------------------------------------------ parameters
    def _validate_params(self, params: list[Parameter[Any]]) -> None:
        (own,) = check_changes(params, (LoggerSettings, self.settings))
        fixed = set(own) - _LIVE
        if fixed:
            raise ConfigError(min(fixed), 'takes effect only at start-up (restart the node)')

    def _apply_params(self, params: list[Parameter[Any]]) -> None:
        (own,) = split_parameters(params, _SETTINGS)[1:]
        if own:
            old = self.settings
            self.settings = new = settings_from(LoggerSettings, own, old)
            self.stats.bin_c = new.residual_bin_c
            if self.writer is not None:
                self.writer.flush_interval_s = new.flush_period_s
            self._flush_timer = retime(self, self._flush_timer, old.flush_period_s, new.flush_period_s,
                                       self.on_flush_timer)
            self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s, new.diagnostics_period_s,
                                      self.publish_diagnostics)

    # ------------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        """``/diagnostics`` (its statuses and rules: :class:`~gimbal_friction.recording.log_report.LoggerReport`)."""
        self.take_sent_counts()
        statuses = self.report.statuses(
            active=self.active, error=self.error, folder=self.folder,
            stats=self.writer.stats if self.writer is not None else None,
            counts={'residuals_logged': self.residuals_logged, 'paired_with_feedforward': self.paired,
                    'no_feedforward': self.no_feedforward, 'waiting_for_feedforward': self.pairing.waiting,
                    'dropped': self.dropped},
            temperature_reliable=self._temperature.reliable, refused=self.refused, lost=self.inputs.new_losses(),
            input_problems=self.input_topics.problems(),
            input_values={**self.inputs.values(), **self.input_topics.values()}, errors=callback_error_values(self),
            rms=self.stats.rms())
        self.pub_diag.publish(diagnostic_array(self, [to_msg(one) for one in statuses]))


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``residual_logger --ros-args -p output_dir:=/tmp/residuals``."""
    sys.exit(run_node('residual_logger', ResidualLogger, args, suite_node='residual_logger'))


if __name__ == '__main__':
    main()
