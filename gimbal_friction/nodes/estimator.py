"""``friction_estimator``: measured friction torque from motor current in steady state (paper Eq. 23).

Subscribes ``/gimbal/motor_current`` (sensor_msgs/JointState, effort = armature current [A] per joint),
``/joint_states`` (position [rad], velocity [rad/s]) and ``/gimbal/temperature`` (sensor_msgs/Temperature, °C,
``qos_profile_sensor_data``). Each current sample is paired with a joint state by stamp and accepted only in steady
state (commanded constant speed for a minimum dwell, inside the position window, low acceleration); the rules,
the rejection reasons and the statistics are those of :mod:`gimbal_friction.core.estimator`, the same code the
offline ``replay`` runs (``estimate_arrays``), so live and offline give the same numbers.

Publishes:

- ``/gimbal/friction/measured`` (sensor_msgs/JointState), one message per accepted sample:
  ``header.stamp`` = stamp of the joint state of the pair (so it lines up with the feedforward of that joint
  state), ``name = [joint]``, ``position = [rad]``, ``velocity = [rad/s]``,
  ``effort = [friction N·m]``, signed like the motion: ``K_T (I − sign(v) I_0)``. Never NaN.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, every ``diagnostics_period_s``): one status per joint,
  ``gimbal_friction/estimator/<joint>`` (hardware_id = joint) with the keys ``accepted``, ``rejected: <reason>``
  (one key per reason seen, e.g. ``rejected: outside position window``, ``rejected: non-finite``), ``pending``
  (currents waiting for their joint state), ``last_friction_nm``, ``last_stamp_s``, ``torque_constant_nm_per_a``,
  ``no_load_current_a``; and one status ``gimbal_friction/estimator`` for the inputs that belong to no joint
  (``rejected: unknown joint``, ``rejected: length mismatch``, ``rejected_temperature: <reason>``) and the last
  temperature (``temperature_c``). Level WARN while no sample was accepted or when bad inputs were rejected
  (reasons other than the steady-state ones), else OK.
- ``/gimbal/friction/statistics`` (diagnostic_msgs/DiagnosticArray, every ``statistics_period_s``): the running
  statistics, one DiagnosticStatus per (joint, direction, temperature plateau), in joint order, direction −1
  first, plateau ascending with ``unknown`` last:

  ==================  ==========================================================================================
  ``name``            ``gimbal_friction/estimator/statistics/<joint>/<+1|-1>/<plateau_c|unknown>``
  ``hardware_id``     joint
  ``level``           OK
  ``message``         e.g. ``mean 3.93 N*mm, 120 samples``
  ``values``          ``joint``, ``direction`` (``+1``/``-1``), ``plateau_c`` (°C or ``unknown``: no fresh
                      temperature), ``count``, ``mean_nm``, ``std_nm`` (sample std), ``ripple_nm`` (peak-to-peak of
                      the position-binned means), ``min_position_rad``, ``max_position_rad``; numbers as
                      round-trip decimal strings (``float(value)`` restores them exactly)
  ==================  ==========================================================================================

  An empty array is published while there is no accepted sample.

Parameters: the model parameters (K_T = ``torque_constant_nm_per_a``, I_0 = ``no_load_current_a``, per joint via
``axis.<joint>.*``), every field of :class:`~gimbal_friction.core.estimator.EstimatorSettings` and the node's
``statistics_period_s`` / ``diagnostics_period_s``. ``ros2 param set`` is validated: an invalid value is refused
with the reason and nothing changes. A change of the estimator settings restarts steady-state detection; a
change of a joint's K_T or I_0 restarts that joint's statistics.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from typing import Any, Sequence

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState, Temperature

from gimbal_friction.core.errors import ConfigError
from gimbal_friction.core.estimator import INPUT_REASONS, UNKNOWN_JOINT, EstimatorLogic, EstimatorSettings, \
    Measurement
from gimbal_friction.core.feedforward import setting
from gimbal_friction.nodes._common import OK, WARN, check_changes, declare_settings, diagnostic_array, field_names, \
    ModelParameters, monotonic_s, parameter_guard, retime, run_node, settings_from, split_parameters, status
from gimbal_friction.recording import topics

#: summary topic of the running statistics (diagnostic_msgs/DiagnosticArray, layout in the module docstring)
STATISTICS = '/gimbal/friction/statistics'
_NS = 1_000_000_000


@dataclasses.dataclass(frozen=True)
class NodeSettings:
    """Node-level parameters of friction_estimator (besides EstimatorSettings and the model)."""

    statistics_period_s: float = setting(2.0, 's', 'period of the statistics summary on '
                                         '/gimbal/friction/statistics')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        for name in ('statistics_period_s', 'diagnostics_period_s'):
            value = getattr(self, name)
            if not 0.05 <= value <= 3600.0:
                raise ConfigError(name, 'must lie in [0.05, 3600] [s]', value)


_EST_FIELDS = field_names(EstimatorSettings)
_NODE_FIELDS = field_names(NodeSettings)


def _num(value: float) -> str:
    return repr(float(value))


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * _NS + int(stamp.nanosec)


class FrictionEstimator(Node):
    """The estimator node (thin adapter around EstimatorLogic)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('friction_estimator', **kwargs)
        self.model = ModelParameters(self)
        est_settings = declare_settings(self, EstimatorSettings)
        self.settings = declare_settings(self, NodeSettings)
        self.logic = EstimatorLogic(self.model.current(), est_settings)
        self._last_warn: dict[str, float] = {}
        self.pub_measured = self.create_publisher(JointState, topics.MEASURED, QoSProfile(depth=100))
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.pub_stats = self.create_publisher(DiagnosticArray, STATISTICS, 10)
        qos = QoSProfile(depth=100)
        self.create_subscription(Temperature, topics.TEMPERATURE, self.on_temperature, qos_profile_sensor_data)
        self.create_subscription(JointState, topics.JOINT_STATES, self.on_joint_state, qos)
        self.create_subscription(JointState, topics.MOTOR_CURRENT, self.on_current, qos)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        self._stats_timer = self.create_timer(self.settings.statistics_period_s, self.publish_statistics)
        parameter_guard(self, self._validate_params, self._apply_params)
        kt = ', '.join(f'{j} K_T={p.torque_constant_nm_per_a:g} N*m/A I_0={p.no_load_current_a:g} A'
                       for j, p in self.logic.axes.items())
        self.get_logger().info(f'friction_estimator: {kt}; speed {est_settings.commanded_speed_rad_s:g} rad/s, '
                               f'window {math.degrees(est_settings.position_min_rad):g}..'
                               f'{math.degrees(est_settings.position_max_rad):g} deg')

    # ------------------------------------------------------------------ parameters
    def _validate_params(self, params: list[Parameter]) -> None:
        check_changes(params, self.model, (EstimatorSettings, self.logic.settings), (NodeSettings, self.settings))

    def _apply_params(self, params: list[Parameter]) -> None:
        model, est, node = split_parameters(params, _EST_FIELDS, _NODE_FIELDS)
        if est:
            self.logic.update_settings(settings_from(EstimatorSettings, est, self.logic.settings))
            self.get_logger().info('estimator settings changed: steady-state detection restarted')
        if node:
            old = self.settings
            self.settings = settings_from(NodeSettings, node, old)
            self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s,
                                      self.settings.diagnostics_period_s, self.publish_diagnostics)
            self._stats_timer = retime(self, self._stats_timer, old.statistics_period_s,
                                       self.settings.statistics_period_s, self.publish_statistics)
        if model:
            for axis, p in self.model.current().items():
                old_p = self.logic.axes[axis]
                if (old_p.torque_constant_nm_per_a, old_p.no_load_current_a) != \
                        (p.torque_constant_nm_per_a, p.no_load_current_a):
                    self.get_logger().info(f'{axis}: K_T={p.torque_constant_nm_per_a:g} N*m/A, '
                                           f'I_0={p.no_load_current_a:g} A; statistics restarted')
                self.logic.set_axis_params(axis, p)

    # ------------------------------------------------------------------ callbacks
    def _warn(self, key: str, text: str, period_s: float = 5.0) -> None:
        now = monotonic_s()
        if now - self._last_warn.get(key, -math.inf) >= period_s:
            self._last_warn[key] = now
            self.get_logger().warning(text)

    def on_temperature(self, msg: Temperature) -> None:
        reason = self.logic.on_temperature(float(msg.temperature))
        if reason is not None:
            self._warn('temperature', f'temperature {msg.temperature!r} degC rejected: {reason}')

    def on_joint_state(self, msg: JointState) -> None:
        self._publish(self.logic.on_joint_state(_stamp_ns(msg.header.stamp), msg.name, msg.position, msg.velocity))

    def on_current(self, msg: JointState) -> None:
        self._publish(self.logic.on_current(_stamp_ns(msg.header.stamp), msg.name, msg.effort))

    def _publish(self, measurements: list[Measurement]) -> None:
        for m in measurements:
            values = (m.position_rad, m.velocity_rad_s, m.friction_nm)
            if not all(math.isfinite(x) for x in values):  # pragma: no cover - excluded by the logic
                self._warn('nan', f'{m.joint}: non-finite measurement not published')
                continue
            out = JointState()
            sec, nanosec = divmod(m.stamp_ns, _NS)
            out.header.stamp = Time(sec=sec, nanosec=nanosec)
            out.name = [m.joint]
            out.position = [m.position_rad]
            out.velocity = [m.velocity_rad_s]
            out.effort = [m.friction_nm]
            self.pub_measured.publish(out)

    # ------------------------------------------------------------------ diagnostics and statistics
    def publish_diagnostics(self) -> None:
        logic = self.logic
        counters = logic.counters
        statuses = []
        for axis in logic.order:
            accepted = counters.accepted.get(axis, 0)
            rejected = counters.rejected.get(axis, {})
            last = logic.last_measurement(axis)
            params = logic.axes[axis]
            values: dict[str, Any] = {
                'accepted': accepted,
                'pending': logic.pending(axis),
                'last_friction_nm': last.friction_nm if last is not None else 'none',
                'last_stamp_s': f'{last.stamp_ns / _NS:.9f}' if last is not None else 'none',
                'torque_constant_nm_per_a': float(params.torque_constant_nm_per_a),
                'no_load_current_a': float(params.no_load_current_a),
            }
            for reason, count in sorted(rejected.items()):
                values[f'rejected: {reason}'] = count
            bad = {r: c for r, c in rejected.items() if r in INPUT_REASONS}
            problems = []
            if not accepted:
                problems.append('no steady-state sample accepted yet')
            if bad:
                problems.append('bad inputs rejected: ' + ', '.join(f'{r} {c}x' for r, c in sorted(bad.items())))
            level = WARN if problems else OK
            statuses.append(status(f'gimbal_friction/estimator/{axis}', level, '; '.join(problems) or 'ok', axis,
                                   values))
        general: dict[str, Any] = {
            'temperature_c': logic.last_temperature_c if logic.last_temperature_c is not None else 'none'}
        for reason, count in sorted(counters.rejected.get(UNKNOWN_JOINT, {}).items()):
            general[f'rejected: {reason}'] = count
        for reason, count in sorted(counters.temperature_rejected.items()):
            general[f'rejected_temperature: {reason}'] = count
        level = WARN if len(general) > 1 else OK
        statuses.append(status('gimbal_friction/estimator', level,
                               'inputs rejected (see values)' if level != OK else 'ok', '', general))
        self.pub_diag.publish(diagnostic_array(self, statuses))

    def publish_statistics(self) -> None:
        statuses = []
        for rec in self.logic.statistics():
            plateau = 'unknown' if rec['plateau_c'] is None else _num(rec['plateau_c'])
            direction = '+1' if rec['direction'] > 0 else '-1'
            values = [
                ('joint', rec['joint']), ('direction', direction), ('plateau_c', plateau),
                ('count', str(rec['count'])), ('mean_nm', _num(rec['mean_nm'])), ('std_nm', _num(rec['std_nm'])),
                ('ripple_nm', _num(rec['ripple_nm'])), ('min_position_rad', _num(rec['min_position'])),
                ('max_position_rad', _num(rec['max_position'])),
            ]
            statuses.append(DiagnosticStatus(
                level=OK, name=f'gimbal_friction/estimator/statistics/{rec["joint"]}/{direction}/{plateau}',
                message=f'mean {rec["mean_nm"] * 1e3:.4g} N*mm, {rec["count"]} samples', hardware_id=rec['joint'],
                values=[KeyValue(key=k, value=v) for k, v in values]))
        self.pub_stats.publish(diagnostic_array(self, statuses))


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``friction_estimator --ros-args --params-file config/gimbal_friction.yaml``."""
    sys.exit(run_node('friction_estimator', FrictionEstimator, args))


if __name__ == '__main__':
    main()
