"""``friction_feedforward``: model-predicted friction torque of every configured joint as a feedforward term.

Subscribes ``/gimbal/temperature`` (sensor_msgs/Temperature, °C) and ``/joint_states`` (sensor_msgs/JointState);
optionally ``/gimbal/reference_velocity`` (JointState, velocity [rad/s]) when ``velocity_source`` is ``reference``.
Publishes, for each joint-state message (optionally rate-limited by ``max_rate_hz``):

- ``/gimbal/friction/feedforward`` (JointState): effort = torque [N·m] the motor must add, sign of motion,
  stamped with the joint-state stamp that produced it;
- ``/gimbal/friction/feedforward_commands`` (Float64MultiArray): the same torques in configured joint order;
- ``/diagnostics`` (1 Hz): per joint, temperature age, model range, saturation, rejected inputs.

The physics is :class:`gimbal_friction.core.feedforward.FeedforwardLogic` (the same code the offline replay uses).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.core.errors import ConfigError
from gimbal_friction.core.feedforward import FeedforwardLogic, FeedforwardSettings, setting
from gimbal_friction.nodes._common import ERROR, OK, WARN, check_changes, declare_settings, diagnostic_array, \
    field_names, ModelParameters, monotonic_s, parameter_guard, retime, run_node, settings_from, split_parameters, \
    status
from gimbal_friction.recording import topics

VELOCITY_SOURCES = ('measured', 'reference')


@dataclasses.dataclass(frozen=True)
class NodeSettings:
    """Node-level parameters of friction_feedforward (besides FeedforwardSettings and the model)."""

    velocity_source: str = setting('measured', '-', 'velocity used for the torque: measured (joint_states '
                                   'velocity) or reference (reference_velocity topic)')
    reference_timeout_s: float = setting(0.5, 's', 'a reference velocity older than this is not used (0 N*m)')
    max_rate_hz: float = setting(0.0, 'Hz', 'publish at most this often; 0 = for every joint-state message')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        if self.velocity_source not in VELOCITY_SOURCES:
            raise ConfigError('velocity_source', f'must be one of {", ".join(VELOCITY_SOURCES)}',
                              self.velocity_source)
        if not self.reference_timeout_s > 0.0:
            raise ConfigError('reference_timeout_s', 'must be > 0 [s]', self.reference_timeout_s)
        if not self.max_rate_hz >= 0.0:
            raise ConfigError('max_rate_hz', 'must be >= 0 [Hz]', self.max_rate_hz)
        if not 0.05 <= self.diagnostics_period_s <= 60.0:
            raise ConfigError('diagnostics_period_s', 'must lie in [0.05, 60] [s]', self.diagnostics_period_s)


_FF_FIELDS = field_names(FeedforwardSettings)
_NODE_FIELDS = field_names(NodeSettings)


class FrictionFeedforward(Node):
    """The feedforward node (thin adapter around FeedforwardLogic)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('friction_feedforward', **kwargs)
        self.model = ModelParameters(self)
        ff_settings = declare_settings(self, FeedforwardSettings)
        self.settings = declare_settings(self, NodeSettings)
        self.logic = FeedforwardLogic(self.model.current(), ff_settings)
        self._reference: dict[str, tuple[float, float]] = {}
        self._last_publish = -math.inf
        self._rate_limited = 0
        self._last_warn: dict[str, float] = {}
        self._axis_names = list(self.logic.axes)
        self._ff_msg = JointState()
        self._cmd_msg = Float64MultiArray()
        n_axes = len(self._axis_names)
        self._cmd_msg.layout.dim = [MultiArrayDimension(label='joints', size=n_axes, stride=n_axes)]
        qos = QoSProfile(depth=10)
        self.pub_ff = self.create_publisher(JointState, topics.FEEDFORWARD, qos)
        self.pub_cmd = self.create_publisher(Float64MultiArray, topics.FEEDFORWARD_COMMANDS, qos)
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_subscription(Temperature, topics.TEMPERATURE, self.on_temperature, qos_profile_sensor_data)
        self.create_subscription(JointState, topics.JOINT_STATES, self.on_joint_state, qos)
        self.create_subscription(JointState, '/gimbal/reference_velocity', self.on_reference, qos)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        parameter_guard(self, self._validate_params, self._apply_params)
        self.get_logger().info(f'friction_feedforward: joints {", ".join(self.model.axes)}, model table '
                               f'{ff_settings.temperature_min_c:g}..{ff_settings.temperature_max_c:g} degC')

    # ------------------------------------------------------------------ parameters
    def _validate_params(self, params: list[Parameter]) -> None:
        check_changes(params, self.model, (FeedforwardSettings, self.logic.settings), (NodeSettings, self.settings))

    def _apply_params(self, params: list[Parameter]) -> None:
        model, ff, node = split_parameters(params, _FF_FIELDS, _NODE_FIELDS)
        if ff:
            self.logic.update_settings(settings_from(FeedforwardSettings, ff, self.logic.settings))
        if node:
            old = self.settings
            self.settings = settings_from(NodeSettings, node, old)
            self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s,
                                      self.settings.diagnostics_period_s, self.publish_diagnostics)
        if model:
            current = self.model.current()
            for axis, p in current.items():
                if self.logic.axes.get(axis) != p:
                    self.logic.set_axis_params(axis, p)
                    self.get_logger().info(f'model of {axis} changed: table rebuilt')

    # ------------------------------------------------------------------ callbacks
    def _warn(self, key: str, text: str, period_s: float = 5.0) -> None:
        now = monotonic_s()
        if now - self._last_warn.get(key, -math.inf) >= period_s:
            self._last_warn[key] = now
            self.get_logger().warning(text)

    def on_temperature(self, msg: Temperature) -> None:
        reason = self.logic.update_temperature(float(msg.temperature), monotonic_s())
        if reason is not None:
            self._warn('temperature', f'temperature {msg.temperature!r} degC rejected: {reason}')

    def on_reference(self, msg: JointState) -> None:
        if len(msg.velocity) != len(msg.name):
            self._warn('reference', 'reference_velocity: velocity/name length mismatch, ignored')
            return
        now = monotonic_s()
        for name, v in zip(msg.name, msg.velocity):
            self._reference[name] = (float(v), now)

    def _velocities(self, msg: JointState) -> tuple[list[str], list[float]]:
        if self.settings.velocity_source == 'measured':
            return list(msg.name), list(msg.velocity)
        now = monotonic_s()
        timeout = self.settings.reference_timeout_s
        names = list(msg.name)
        vel = []
        for n in names:
            v, t = self._reference.get(n, (math.nan, -math.inf))
            vel.append(v if now - t <= timeout else 0.0)
        return names, vel

    def on_joint_state(self, msg: JointState) -> None:
        if self.settings.max_rate_hz > 0.0:
            now = monotonic_s()
            if now - self._last_publish < 1.0 / self.settings.max_rate_hz:
                self._rate_limited += 1
                return
            self._last_publish = now
        names, velocities = self._velocities(msg)
        now = monotonic_s()
        # common case (exactly the configured joints, finite velocities): no intermediate records
        torques = self.logic.torques_in_order(names, velocities, now)
        ff, cmd = self._ff_msg, self._cmd_msg
        if torques is not None:
            ff.name = self._axis_names
            commands = torques
        else:
            out = self.logic.compute(names, velocities, now)
            if out is None:
                self._warn('joint_state', f'joint_states message rejected: {self.logic.last_rejection}')
                return
            ff.name = [j.name for j in out.joints]
            torques = [j.torque_nm for j in out.joints]
            commands = self.logic.command_vector(out)
        ff.header = msg.header  # the stamp of the joint state that produced it
        ff.effort = torques
        self.pub_ff.publish(ff)  # messages are serialized on publish, so both are reused
        cmd.data = commands
        self.pub_cmd.publish(cmd)

    # ------------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        now = monotonic_s()
        logic = self.logic
        age = logic.temperature_age_s(now)
        temperature, source = logic.effective_temperature(now)
        s = logic.settings
        statuses = []
        for axis in logic.axes:
            level, problems = OK, []
            if source != 'measured':
                level = WARN if source != 'zero' else ERROR
                problems.append(f'no fresh temperature: {source}')
            sat = logic.counters.saturated.get(axis, 0)
            if sat:
                level = max(level, WARN)
                problems.append(f'output saturated {sat}x')
            values = {
                'temperature_c': temperature if temperature is not None else 'none',
                'temperature_source': source,
                'temperature_age_s': age if math.isfinite(age) else 'never',
                'model_range_c': f'{s.temperature_min_c:g}..{s.temperature_max_c:g}',
                'in_model_range': temperature is not None and s.temperature_min_c <= temperature <= s.temperature_max_c,
                'saturated_count': sat,
                'max_torque_nm': s.max_torque_nm,
                'published': logic.counters.published,
                'rate_limited': self._rate_limited,
            }
            for reason, count in logic.counters.temperature_rejected.items():
                values[f'rejected_temperature: {reason}'] = count
                level = max(level, WARN)
            for reason, count in logic.counters.joint_state_rejected.items():
                values[f'rejected_joint_state: {reason}'] = count
                level = max(level, WARN)
            if level != OK and not problems:
                problems.append('inputs rejected (see values)')
            statuses.append(status(f'gimbal_friction/feedforward/{axis}', level, '; '.join(problems) or 'ok',
                                   axis, values))
        self.pub_diag.publish(diagnostic_array(self, statuses))


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``friction_feedforward --ros-args --params-file config/gimbal_friction.yaml``."""
    sys.exit(run_node('friction_feedforward', FrictionFeedforward, args))


if __name__ == '__main__':
    main()
