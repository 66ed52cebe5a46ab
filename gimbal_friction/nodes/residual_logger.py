"""``residual_logger``: logs inputs, predictions, measurements and residuals to MCAP for the viscosity refit.

Subscribes ``/gimbal/temperature``, ``/joint_states``, ``/gimbal/motor_current``, ``/gimbal/friction/feedforward``
and ``/gimbal/friction/measured``. Every received message is logged as it arrived (raw CDR, log time = receive
time). Each measured sample is paired with the feedforward of the same stamp (the estimator stamps a measurement
with the joint-state stamp of its sample, the feedforward node its output with the same stamp) and logged as

- ``/gimbal/friction/residual`` (sensor_msgs/JointState): name = [joint], position [rad], velocity [rad/s],
  effort = [measured − predicted] [N·m], stamp = the sample's stamp;
- ``/gimbal/friction/residual_detail`` (std_msgs/Float64MultiArray): ``layout.dim[0].label`` = joint, data in
  the order of ``recording.topics.RESIDUAL_FIELDS`` (stamp_s, temperature_c, position_rad, velocity_rad_s,
  current_a, measured_nm, predicted_nm, m_rolling_nm, m_sliding_nm, m_viscous_nm, residual_nm).

Files: ``output_dir/residuals_<n>.mcap`` (ROS 2 profile, CDR, standard types only), flushed every
``flush_period_s`` in small chunks, rotated by ``max_file_mb`` / ``max_file_duration_s``, closed with footer and
``metadata.yaml`` on SIGINT/SIGTERM. If ``output_dir`` already holds a log, a timestamped sub-folder is used.
A write error (full disk, unwritable folder) is reported on ``/diagnostics`` (ERROR) and retried every
``retry_period_s``; the node stays up. ``/diagnostics`` also carries messages logged, bytes, current file and the
residual RMS per axis and temperature bin.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.core.errors import ConfigError, GimbalFrictionError
from gimbal_friction.core.feedforward import FeedforwardLogic, FeedforwardSettings, setting
from gimbal_friction.core.residuals import ResidualPairing, ResidualRecord, ResidualStats
from gimbal_friction.nodes._common import retime, ERROR, OK, WARN, check_changes, declare_settings, diagnostic_array, \
    field_names, ModelParameters, monotonic_s, parameter_guard, run_node, settings_from, split_parameters, status
from gimbal_friction.recording import topics
from gimbal_friction.recording.residual_log import ResidualLogWriter, residual_log_files


@dataclasses.dataclass(frozen=True)
class LoggerSettings:
    """Parameters of residual_logger."""

    output_dir: str = setting('residuals', '-', 'folder of the residual log (created; a timestamped sub-folder '
                              'is used if it already holds a log)')
    flush_period_s: float = setting(1.0, 's', 'completed data reaches the disk at least this often')
    chunk_kib: int = setting(64, 'KiB', 'MCAP chunk size; small chunks lose little when the process is killed')
    max_file_mb: float = setting(64.0, 'MB', 'rotate to a new file at this size; 0 = never')
    max_file_duration_s: float = setting(0.0, 's', 'rotate to a new file after this much log time; 0 = never')
    pairing_timeout_s: float = setting(1.0, 's', 'a measured sample waits this long for its feedforward, then '
                                       'the logger uses its own prediction')
    log_inputs: bool = setting(True, '-', 'also log the raw input topics (temperature, joint states, current, '
                               'feedforward, measured)')
    residual_bin_c: float = setting(5.0, 'degC', 'temperature bin of the residual RMS on /diagnostics')
    retry_period_s: float = setting(5.0, 's', 'after a write error, try a new file this often')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        if not self.output_dir.strip():
            raise ConfigError('output_dir', 'must be a folder path', self.output_dir)
        for name in ('flush_period_s', 'pairing_timeout_s', 'residual_bin_c', 'retry_period_s',
                     'diagnostics_period_s'):
            if not getattr(self, name) > 0.0:
                raise ConfigError(name, 'must be > 0', getattr(self, name))
        if not 1 <= self.chunk_kib <= 65536:
            raise ConfigError('chunk_kib', 'must lie in [1, 65536] [KiB]', self.chunk_kib)
        for name in ('max_file_mb', 'max_file_duration_s'):
            if not getattr(self, name) >= 0.0:
                raise ConfigError(name, 'must be >= 0 (0 = never)', getattr(self, name))


_SETTINGS = field_names(LoggerSettings)
_FF_SETTINGS = field_names(FeedforwardSettings)
_LIVE = {'pairing_timeout_s', 'residual_bin_c', 'diagnostics_period_s', 'flush_period_s', 'retry_period_s'}


class ResidualLogger(Node):
    """The residual logger node (adapter around ResidualPairing and ResidualLogWriter)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('residual_logger', **kwargs)
        self.model = ModelParameters(self)
        self.settings = declare_settings(self, LoggerSettings)
        ff_settings = declare_settings(self, FeedforwardSettings)
        self.ff = FeedforwardLogic(self.model.current(), ff_settings)
        self.pairing = ResidualPairing(self.ff, timeout_s=self.settings.pairing_timeout_s)
        self.stats = ResidualStats(self.settings.residual_bin_c)
        self.writer: ResidualLogWriter | None = None
        self.folder: Path | None = None
        self.error: str | None = None
        self.dropped = 0
        self.residuals_logged = 0
        self._last_retry = -math.inf
        self._open_writer()
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        raw = {'raw': True}
        self.create_subscription(Temperature, topics.TEMPERATURE, self.on_temperature, qos_profile_sensor_data, **raw)
        self.create_subscription(JointState, topics.JOINT_STATES,
                                 lambda b: self.log_raw(topics.JOINT_STATES, topics.JOINT_STATE_TYPE, b), 100, **raw)
        self.create_subscription(JointState, topics.MOTOR_CURRENT,
                                 lambda b: self.log_raw(topics.MOTOR_CURRENT, topics.JOINT_STATE_TYPE, b), 100, **raw)
        self.create_subscription(JointState, topics.FEEDFORWARD, self.on_feedforward, 100, **raw)
        self.create_subscription(JointState, topics.MEASURED, self.on_measured, 100, **raw)
        self._flush_timer = self.create_timer(self.settings.flush_period_s, self.on_flush_timer)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        parameter_guard(self, self._validate_params, self._apply_params)

    # ------------------------------------------------------------------ log file lifecycle
    def _open_writer(self) -> None:
        s = self.settings
        folder = Path(s.output_dir).expanduser()
        try:
            if folder.exists() and (residual_log_files(folder) or (folder / 'metadata.yaml').exists()):
                folder = folder / time.strftime('%Y%m%d_%H%M%S', time.gmtime())
        except GimbalFrictionError:
            pass
        try:
            self.writer = ResidualLogWriter(
                folder, chunk_size=s.chunk_kib * 1024, flush_interval_s=s.flush_period_s,
                max_bytes=int(s.max_file_mb * 1e6) if s.max_file_mb > 0 else None,
                max_duration_s=s.max_file_duration_s if s.max_file_duration_s > 0 else None)
            self.folder = folder
            self.error = None
            self.get_logger().info(f'residual log: {folder}')
        except GimbalFrictionError as err:
            self.writer = None
            self._report_error(str(err))

    def _report_error(self, text: str) -> None:
        if text != self.error:
            self.get_logger().error(f'residual log: {text}')
        self.error = text

    def _write(self, fn: str, *args: Any) -> None:
        if self.writer is None:
            self.dropped += 1
            return
        try:
            getattr(self.writer, fn)(*args)
        except GimbalFrictionError as err:
            self.dropped += 1
            self._report_error(str(err))
            self._abandon_writer()

    def _abandon_writer(self) -> None:
        writer, self.writer = self.writer, None
        if writer is not None:
            try:
                writer.close()
            except GimbalFrictionError:
                pass
        self._last_retry = monotonic_s()

    def close(self) -> None:
        """Finish the log (footer, metadata.yaml); called on shutdown by run_node."""
        if self.writer is not None:
            for rec in self.pairing.expire(math.inf):
                self.log_record(rec)
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
        return self.get_clock().now().nanoseconds

    def log_raw(self, topic: str, msgtype: str, data: bytes) -> None:
        if self.settings.log_inputs:
            self._write('write_raw', topic, msgtype, self._now_ns(), data)

    def on_temperature(self, data: bytes) -> None:
        self.log_raw(topics.TEMPERATURE, topics.TEMPERATURE_TYPE, data)
        msg = deserialize_message(data, Temperature)
        self.ff.update_temperature(float(msg.temperature), monotonic_s())

    def on_feedforward(self, data: bytes) -> None:
        self.log_raw(topics.FEEDFORWARD, topics.JOINT_STATE_TYPE, data)
        msg = deserialize_message(data, JointState)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for rec in self.pairing.on_feedforward(stamp, msg.name, msg.effort):
            self.log_record(rec)

    def on_measured(self, data: bytes) -> None:
        self.log_raw(topics.MEASURED, topics.JOINT_STATE_TYPE, data)
        msg = deserialize_message(data, JointState)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for rec in self.pairing.on_measured(stamp, msg.name, msg.position, msg.velocity, msg.effort,
                                            monotonic_s()):
            self.log_record(rec)

    def log_record(self, rec: ResidualRecord) -> None:
        now = self._now_ns()
        res = JointState(name=[rec.joint], position=[rec.position_rad], velocity=[rec.velocity_rad_s],
                         effort=[rec.residual_nm])
        res.header.stamp.sec, res.header.stamp.nanosec = divmod(rec.stamp_ns, 1_000_000_000)
        self._write('write_raw', topics.RESIDUAL, topics.JOINT_STATE_TYPE, now, serialize_message(res))
        detail = Float64MultiArray()
        detail.layout.dim = [MultiArrayDimension(label=rec.joint, size=len(topics.RESIDUAL_FIELDS),
                                                 stride=len(topics.RESIDUAL_FIELDS))]
        detail.data = rec.detail_values()
        self._write('write_raw', topics.RESIDUAL_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE, now,
                    serialize_message(detail))
        self.stats.add(rec)
        self.residuals_logged += 1

    def on_flush_timer(self) -> None:
        for rec in self.pairing.expire(monotonic_s()):
            self.log_record(rec)
        if self.writer is None:
            if monotonic_s() - self._last_retry >= self.settings.retry_period_s:
                self._last_retry = monotonic_s()
                self._open_writer()
            return
        self._write('flush')

    # ------------------------------------------------------------------ parameters
    def _validate_params(self, params: list[Parameter]) -> None:
        _, own, _ = check_changes(params, self.model, (LoggerSettings, self.settings),
                                  (FeedforwardSettings, self.ff.settings))
        fixed = set(own) - _LIVE
        if fixed:
            raise ConfigError(sorted(fixed)[0], 'takes effect only at start-up (restart the node)')

    def _apply_params(self, params: list[Parameter]) -> None:
        model, own, ff = split_parameters(params, _SETTINGS, _FF_SETTINGS)
        if own:
            old = self.settings
            self.settings = new = settings_from(LoggerSettings, own, old)
            self.pairing.timeout_s = new.pairing_timeout_s
            self.stats.bin_c = new.residual_bin_c
            if self.writer is not None:
                self.writer.flush_interval_s = new.flush_period_s
            self._flush_timer = retime(self, self._flush_timer, old.flush_period_s, new.flush_period_s,
                                       self.on_flush_timer)
            self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s, new.diagnostics_period_s,
                                      self.publish_diagnostics)
        if ff:
            self.ff.update_settings(settings_from(FeedforwardSettings, ff, self.ff.settings))
        if model:
            for axis, p in self.model.current().items():
                if self.ff.axes.get(axis) != p:
                    self.ff.set_axis_params(axis, p)

    # ------------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        w = self.writer
        stats = w.stats if w is not None else None
        level = OK
        message = 'logging'
        if self.error is not None:
            level, message = ERROR, f'not logging: {self.error}'
        elif self.pairing.own_prediction:
            level, message = WARN, 'some measured samples had no feedforward (own prediction used)'
        values: dict[str, Any] = {
            'folder': str(self.folder) if self.folder else 'none',
            'current_file': str(stats.current_file) if stats and stats.current_file else 'none',
            'files': len(stats.files) if stats else 0,
            'messages_logged': stats.messages if stats else 0,
            'bytes': stats.bytes if stats else 0,
            'residuals_logged': self.residuals_logged,
            'paired_with_feedforward': self.pairing.paired,
            'own_prediction': self.pairing.own_prediction,
            'dropped': self.dropped,
        }
        statuses = [status('gimbal_friction/residual_logger', level, message, 'residual_logger', values)]
        by_axis: dict[str, dict[str, Any]] = {}
        for (joint, b), (n, rms) in sorted(self.stats.rms().items(), key=lambda kv: (kv[0][0], kv[0][1])):
            by_axis.setdefault(joint, {})[f'rms_nm_at_{b:+g}C'] = rms
            by_axis[joint][f'samples_at_{b:+g}C'] = n
        for joint, vals in by_axis.items():
            statuses.append(status(f'gimbal_friction/residual_logger/{joint}', OK, 'residual RMS per temperature '
                                   'bin', joint, vals))
        self.pub_diag.publish(diagnostic_array(self, statuses))


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``residual_logger --ros-args -p output_dir:=/tmp/residuals``."""
    sys.exit(run_node('residual_logger', ResidualLogger, args))


if __name__ == '__main__':
    main()
