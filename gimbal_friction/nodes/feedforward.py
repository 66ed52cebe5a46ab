"""``friction_feedforward``: model-predicted friction torque of every configured joint as a feedforward term.

Subscribes ``/gimbal/temperature`` (sensor_msgs/Temperature, °C) and ``/joint_states`` (sensor_msgs/JointState);
optionally ``/gimbal/reference_velocity`` (JointState, velocity [rad/s]) when ``velocity_source`` is ``reference``.
Publishes, for each joint-state message (optionally rate-limited by ``max_rate_hz``):

- ``/gimbal/friction/feedforward`` (JointState): effort = torque [N·m] the motor must add, sign of motion, for the
  configured joints present in the message (configured order), stamped with the joint-state stamp that produced it;
- ``/gimbal/friction/feedforward_commands`` (Float64MultiArray): the torques of every configured joint in
  configured order (0 for a joint absent from the message);
- ``/diagnostics`` (every ``diagnostics_period_s``): per joint, temperature source and age, saturation, rejected
  inputs.

The logic is :class:`gimbal_friction.core.feedforward.Feedforward`, the very object a controller can use in its own
process and the offline replay runs over a whole bag; the node only converts messages. Times are message stamps
(the receive time where a stamp is zero), the rule of :mod:`gimbal_friction.core.inputs`.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.core.errors import ConfigError
from gimbal_friction.core.feedforward import (
    SOURCE_MEASURED,
    SOURCE_NAMES,
    SOURCE_ZERO,
    Feedforward,
    FeedforwardSettings,
    check_velocity_source,
    velocity_used,
)
from gimbal_friction.core.inputs import effective_time, is_fresh
from gimbal_friction.core.settings import setting, settings_from
from gimbal_friction.core.xp import SCALAR
from gimbal_friction.nodes._common import (
    ERROR,
    OK,
    WARN,
    ModelParameters,
    callback_error_values,
    declare_settings,
    diagnostic_array,
    field_names,
    parameter_guard,
    retime,
    run_node,
    split_parameters,
    stamp_to_s,
    status,
)
from gimbal_friction.recording import topics

REFERENCE_VELOCITY = '/gimbal/reference_velocity'
#: subscription depth of the joint states: a burst of this many messages is buffered, not dropped
JOINT_STATE_DEPTH = 1000


@dataclasses.dataclass(frozen=True)
class NodeSettings:
    """Node-level parameters of friction_feedforward (besides FeedforwardSettings and the model)."""

    velocity_source: str = setting('auto', '-', 'velocity used for the torque: measured (joint_states velocity, '
                                   'relative to the base), reference (reference_velocity topic; 0 N*m when it is '
                                   'stale) or auto (reference while fresh, else measured)')
    reference_timeout_s: float = setting(0.5, 's', 'a reference velocity whose stamp differs from the joint '
                                         'state\'s by more than this is not used (0 N*m)')
    max_rate_hz: float = setting(0.0, 'Hz', 'publish at most this often; 0 = for every joint-state message')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        check_velocity_source(self.velocity_source)
        if not 0.0 < self.reference_timeout_s <= 3600.0:
            raise ConfigError('reference_timeout_s', 'must lie in (0, 3600] [s]', self.reference_timeout_s)
        if not 0.0 <= self.max_rate_hz <= 1e6:
            raise ConfigError('max_rate_hz', 'must lie in [0, 1e6] [Hz]', self.max_rate_hz)
        if not 0.05 <= self.diagnostics_period_s <= 60.0:
            raise ConfigError('diagnostics_period_s', 'must lie in [0.05, 60] [s]', self.diagnostics_period_s)


_FF_FIELDS = field_names(FeedforwardSettings)
_NODE_FIELDS = field_names(NodeSettings)


class FrictionFeedforward(Node):
    """The feedforward node (thin adapter around :class:`Feedforward`)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('friction_feedforward', **kwargs)
        self.model = ModelParameters(self)
        ff_settings = declare_settings(self, FeedforwardSettings)
        self.settings = declare_settings(self, NodeSettings)
        self.ff = Feedforward(self.model.current(), ff_settings)
        self._candidate: tuple[Feedforward | None, NodeSettings] | None = None
        self._reference: dict[str, tuple[float, float]] = {}
        self._last_publish = -math.inf
        self._last_time_s = math.nan
        self._last_source = SOURCE_MEASURED
        self._rate_limited = 0
        self._last_warn: dict[str, float] = {}
        self._ff_msg = JointState()
        self._cmd_msg = Float64MultiArray()
        n_axes = len(self.ff.order)
        self._cmd_msg.layout.dim = [MultiArrayDimension(label='joints', size=n_axes, stride=n_axes)]
        qos = QoSProfile(depth=100)
        self.pub_ff = self.create_publisher(JointState, topics.FEEDFORWARD, qos)
        self.pub_cmd = self.create_publisher(Float64MultiArray, topics.FEEDFORWARD_COMMANDS, qos)
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_subscription(Temperature, topics.TEMPERATURE, self.on_temperature, qos_profile_sensor_data)
        self.create_subscription(JointState, topics.JOINT_STATES, self.on_joint_state,
                                 QoSProfile(depth=JOINT_STATE_DEPTH))
        self.create_subscription(JointState, REFERENCE_VELOCITY, self.on_reference, qos)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        parameter_guard(self, self._validate_params, self._apply_params)
        self.get_logger().info(f'friction_feedforward: joints {", ".join(self.model.axes)}, model table '
                               f'{ff_settings.temperature_min_c:g}..{ff_settings.temperature_max_c:g} degC')

    # ------------------------------------------------------------------ parameters
    def _validate_params(self, params: list[Parameter]) -> None:
        """Build the whole new feedforward (model tables included) from the proposed values; kept for apply."""
        model, ff, node = split_parameters(params, _FF_FIELDS, _NODE_FIELDS)
        axes = self.model.current(model)
        ff_settings = settings_from(FeedforwardSettings, ff, self.ff.settings)
        node_settings = settings_from(NodeSettings, node, self.settings)
        candidate = Feedforward(axes, ff_settings) if (model or ff) else None
        self._candidate = (candidate, node_settings)

    def _apply_params(self, params: list[Parameter]) -> None:
        if self._candidate is None:
            return
        candidate, node_settings = self._candidate
        self._candidate = None
        if candidate is not None:
            candidate.take_state(self.ff)
            self.ff = candidate
            self.get_logger().info('feedforward rebuilt with the new parameters')
        old = self.settings
        self.settings = node_settings
        self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s,
                                  node_settings.diagnostics_period_s, self.publish_diagnostics)

    # ------------------------------------------------------------------ callbacks
    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _warn(self, key: str, text: str, period_s: float = 5.0) -> None:
        now = self._now_s()
        if not now - self._last_warn.get(key, -math.inf) < period_s:
            self._last_warn[key] = now
            self.get_logger().warning(text)

    def on_temperature(self, msg: Temperature) -> None:
        time_s = effective_time(stamp_to_s(msg.header.stamp), self._now_s())
        reason = self.ff.update_temperature(float(msg.temperature), time_s)
        if reason is not None:
            self._warn('temperature', f'temperature {msg.temperature!r} degC rejected: {reason}')

    def on_reference(self, msg: JointState) -> None:
        if len(msg.velocity) != len(msg.name):
            self._warn('reference', 'reference_velocity: velocity/name length mismatch, ignored')
            return
        time_s = effective_time(stamp_to_s(msg.header.stamp), self._now_s())
        seen = set()
        for name, v in zip(msg.name, msg.velocity, strict=True):
            if name not in seen:  # the first entry of a joint counts, as for joint states
                seen.add(name)
                self._reference[name] = (float(v), time_s)

    def _velocities(self, msg: JointState, time_s: float) -> list[float]:
        source = self.settings.velocity_source
        measured = list(msg.velocity)
        if source == 'measured' or (source == 'auto' and len(measured) != len(msg.name)):
            return measured   # (a length mismatch is refused by Feedforward.message)
        timeout = self.settings.reference_timeout_s
        out = []
        for i, name in enumerate(msg.name):
            v, t = self._reference.get(name, (math.nan, math.nan))
            m = measured[i] if i < len(measured) else math.nan
            out.append(velocity_used(source, m, v, is_fresh(time_s, t, timeout, SCALAR), SCALAR))
        return out

    def on_joint_state(self, msg: JointState) -> None:
        if self.settings.max_rate_hz > 0.0:
            now = self._now_s()
            if now - self._last_publish < 1.0 / self.settings.max_rate_hz:
                self._rate_limited += 1
                return
            self._last_publish = now
        stamp_s = stamp_to_s(msg.header.stamp)
        # the receive time is needed only for an unstamped message (reading the clock costs a few µs)
        time_s = effective_time(stamp_s, self._now_s() if stamp_s == 0.0 else 0.0)
        names = list(msg.name)
        out = self.ff.message(names, self._velocities(msg, time_s), time_s)
        self._last_time_s = time_s
        if out is None:
            self._warn('joint_state', 'joint_states message not used (see /diagnostics for the reason)')
            return
        self._last_source = out.source
        ff, cmd = self._ff_msg, self._cmd_msg
        ff.header = msg.header  # the stamp of the joint state that produced it
        ff.name = out.names
        ff.effort = out.torques_nm
        self.pub_ff.publish(ff)  # messages are serialized on publish, so both are reused
        cmd.data = out.commands_nm
        self.pub_cmd.publish(cmd)

    # ------------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        ff = self.ff
        s = ff.settings
        c = ff.counters
        last_time = self._last_time_s if math.isfinite(self._last_time_s) else self._now_s()
        age = ff.temperature_age_s(last_time)
        temperature, source = ff.temperature(last_time)
        statuses = []
        for axis in ff.order:
            level, problems = OK, []
            if source != SOURCE_MEASURED:
                level = ERROR if source == SOURCE_ZERO else WARN
                problems.append(f'no fresh temperature: {SOURCE_NAMES[source]}')
            sat = c.saturated.get(axis, 0)
            if sat:
                level = max(level, WARN)
                problems.append(f'output saturated {sat}x')
            values: dict[str, Any] = {
                'temperature_c': temperature if math.isfinite(temperature) else 'none',
                'temperature_source': SOURCE_NAMES[source],
                'temperature_age_s': age if math.isfinite(age) else 'never',
                'model_range_c': f'{s.temperature_min_c:g}..{s.temperature_max_c:g}',
                'saturated_count': sat,
                'max_torque_nm': s.max_torque_nm,
                'published': c.published,
                'rate_limited': self._rate_limited,
            }
            for reason, count in c.temperature_rejected.items():
                values[f'rejected_temperature: {reason}'] = count
                level = max(level, WARN)
            for reason, count in c.joint_state_rejected.items():
                values[f'rejected_joint_state: {reason}'] = count
                level = max(level, WARN)
            errors = callback_error_values(self)
            if errors:
                values.update(errors)
                level = ERROR
                problems.append('a callback failed (see values)')
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
