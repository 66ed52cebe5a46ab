"""``friction_feedforward``: model-predicted friction torque of every configured joint as a feedforward term.

Subscribes ``/gimbal/temperature`` (sensor_msgs/Temperature, °C) and ``/joint_states`` (sensor_msgs/JointState);
and ``/gimbal/reference_velocity`` (JointState, velocity = reference joint rate [rad/s]), used by ``velocity_source``
``auto`` (the default: while fresh) and ``reference``.
Publishes, for each joint-state message (optionally rate-limited by ``max_rate_hz``):

- ``/gimbal/friction/feedforward`` (JointState): effort = torque [N·m] the motor must add, sign of motion, for the
  configured joints present in the message (configured order), stamped with the joint-state stamp that produced it;
- ``/gimbal/friction/feedforward_commands`` (Float64MultiArray): the torques of every configured joint in
  configured order (0 for a joint absent from the message);
- ``/diagnostics`` (every ``diagnostics_period_s``): per joint, temperature source and age, saturation, rejected
  inputs.

The logic is :class:`gimbal_friction.feedforward.rule.Feedforward`, the very object a controller can use in its own
process and the offline replay runs over a whole bag; the node only converts messages. Times are message stamps
(the receive time where a stamp is zero), the rule of :mod:`gimbal_friction.streams.inputs`.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.common.settings import settings_from
from gimbal_friction.config.node_settings import FeedforwardNodeSettings
from gimbal_friction.feedforward.rule import (
    SOURCE_MEASURED,
    SOURCE_NAMES,
    SOURCE_ZERO,
    Feedforward,
    FeedforwardSettings,
)
from gimbal_friction.nodes._common import (
    ERROR,
    OK,
    WARN,
    InputCounter,
    ModelParameters,
    callback_error_values,
    declare_settings,
    diagnostic_array,
    field_names,
    parameter_guard,
    retime,
    run_node,
    settings_defaults,
    split_parameters,
    stamp_to_s,
    startup_model_error,
    status,
    subscribe,
)
from gimbal_friction.recording import topics
from gimbal_friction.streams.inputs import effective_time

REFERENCE_VELOCITY = topics.REFERENCE_VELOCITY
#: subscription depth of the joint states: a burst of this many messages is buffered, not dropped
JOINT_STATE_DEPTH = 1000
NodeSettings = FeedforwardNodeSettings  # the node-level parameters (gimbal_friction.common.settings)

_FF_FIELDS = field_names(FeedforwardSettings)
_NODE_FIELDS = field_names(NodeSettings)


class FrictionFeedforward(Node):
    """The feedforward node (thin adapter around :class:`Feedforward`)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('friction_feedforward', **kwargs)
        self.model = ModelParameters(self)
        ff_settings = declare_settings(self, FeedforwardSettings)
        self.settings = declare_settings(self, NodeSettings)
        self.ff = self._build(self.model.current(), ff_settings, startup=True)
        self._candidate: tuple[Feedforward | None, NodeSettings] | None = None
        self._last_publish = -math.inf
        self._last_time_s = math.nan
        self._last_source = SOURCE_MEASURED
        self._rate_limited = 0
        self._last_warn: dict[str, float] = {}
        self.inputs = InputCounter()
        self._reported: dict[str, dict[str, int]] = {}
        self._ff_msg = JointState()
        self._cmd_msg = Float64MultiArray()
        n_axes = len(self.ff.order)
        self._cmd_msg.layout.dim = [MultiArrayDimension(label='joints', size=n_axes, stride=n_axes)]
        qos = QoSProfile(depth=100)
        self.pub_ff = self.create_publisher(JointState, topics.FEEDFORWARD, qos)
        self.pub_cmd = self.create_publisher(Float64MultiArray, topics.FEEDFORWARD_COMMANDS, qos)
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        subscribe(self, self.inputs, Temperature, topics.TEMPERATURE, self.on_temperature, qos_profile_sensor_data)
        subscribe(self, self.inputs, JointState, topics.JOINT_STATES, self.on_joint_state,
                  QoSProfile(depth=JOINT_STATE_DEPTH))
        subscribe(self, self.inputs, JointState, REFERENCE_VELOCITY, self.on_reference, qos)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        parameter_guard(self, self._validate_params, self._apply_params)
        self.get_logger().info(f'friction_feedforward: joints {", ".join(self.model.axes)}, model table '
                               f'{ff_settings.temperature_min_c:g}..{ff_settings.temperature_max_c:g} degC')

    # ------------------------------------------------------------------ parameters
    def _build(self, axes: dict[str, Any], settings: FeedforwardSettings, startup: bool = False) -> Feedforward:
        """The whole feedforward (model tables included); a model that does not build is refused with the
        parameters to look at."""
        try:
            with np.errstate(all='ignore'):
                return Feedforward(axes, settings)
        except ModelDomainError as err:
            if not startup:
                raise
            defaults = {**self.model.defaults, **settings_defaults(FeedforwardSettings)}
            raise startup_model_error(self, err, defaults) from None

    def _validate_params(self, params: list[Parameter[Any]]) -> None:
        """Build the whole new feedforward (model tables included) from the proposed values; kept for apply."""
        model, ff, node = split_parameters(params, _FF_FIELDS, _NODE_FIELDS)
        axes = self.model.current(model)
        ff_settings = settings_from(FeedforwardSettings, ff, self.ff.settings)
        node_settings = settings_from(NodeSettings, node, self.settings)
        candidate = self._build(axes, ff_settings) if (model or ff) else None
        self._candidate = (candidate, node_settings)

    def _apply_params(self, params: list[Parameter[Any]]) -> None:
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
        time_s = effective_time(stamp_to_s(msg.header.stamp), self._now_s())
        reason = self.ff.update_reference(list(msg.name), list(msg.velocity), time_s)
        if reason is not None:
            self._warn('reference', f'reference_velocity message refused: {reason}')

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
        out = self.ff.message(names, list(msg.velocity), time_s)
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
    def _new_since_report(self, key: str, counts: dict[str, int]) -> dict[str, int]:
        """Counts that grew since the previous diagnostics report (what keeps a status at WARN)."""
        previous = self._reported.get(key, {})
        self._reported[key] = dict(counts)
        return {r: n - previous.get(r, 0) for r, n in counts.items() if n > previous.get(r, 0)}

    def publish_diagnostics(self) -> None:
        """One status per joint. WARN (ERROR for the zero policy or a failed callback) names what happened since
        the previous report; the status returns to OK once the cause has gone for a period. The totals stay in the
        values."""
        ff = self.ff
        s = ff.settings
        c = ff.counters
        last_time = self._last_time_s if math.isfinite(self._last_time_s) else self._now_s()
        age = ff.temperature_age_s(last_time)
        temperature, source = ff.temperature(last_time)
        new_t = self._new_since_report('temperature', c.temperature_rejected)
        new_j = self._new_since_report('joint_state', c.joint_state_rejected)
        new_r = self._new_since_report('reference', c.reference_rejected)
        new_sat = self._new_since_report('saturated', c.saturated)
        new_lost = self.inputs.new_losses()
        errors = callback_error_values(self)
        new_errors = self._new_since_report('errors', errors)
        statuses = []
        for axis in ff.order:
            level, problems = OK, []
            if source != SOURCE_MEASURED:
                level = ERROR if source == SOURCE_ZERO else WARN
                problems.append(f'no fresh temperature: {SOURCE_NAMES[source]}')
            if new_sat.get(axis):
                level = max(level, WARN)
                problems.append(f'output saturated {new_sat[axis]}x')
            if new_t:
                level = max(level, WARN)
                problems.append('temperatures rejected: ' + ', '.join(f'{r} {n}x' for r, n in sorted(new_t.items())))
            if new_j:
                level = max(level, WARN)
                problems.append('joint states rejected: ' + ', '.join(f'{r} {n}x' for r, n in sorted(new_j.items())))
            if new_r:
                level = max(level, WARN)
                problems.append('reference velocities rejected: ' + ', '.join(f'{r} {n}x'
                                                                              for r, n in sorted(new_r.items())))
            if new_lost:
                level = max(level, WARN)
                problems.append('messages lost on the way: ' + ', '.join(f'{t} {n}'
                                                                          for t, n in sorted(new_lost.items())))
            if new_errors:
                level = ERROR
                problems.append('a callback failed (see values)')
            values: dict[str, Any] = {
                'temperature_c': temperature if math.isfinite(temperature) else 'none',
                'temperature_source': SOURCE_NAMES[source],
                'temperature_age_s': age if math.isfinite(age) else 'never',
                'model_range_c': f'{s.temperature_min_c:g}..{s.temperature_max_c:g}',
                'saturated_count': c.saturated.get(axis, 0),
                'max_torque_nm': s.max_torque_nm,
                'published': c.published,
                'rate_limited': self._rate_limited,
            }
            for reason, count in c.temperature_rejected.items():
                values[f'rejected_temperature: {reason}'] = count
            for reason, count in c.joint_state_rejected.items():
                values[f'rejected_joint_state: {reason}'] = count
            for reason, count in c.reference_rejected.items():
                values[f'rejected_reference: {reason}'] = count
            values['velocity_source'] = s.velocity_source
            values.update(self.inputs.values())
            values.update(errors)
            statuses.append(status(f'gimbal_friction/feedforward/{axis}', level, '; '.join(problems) or 'ok',
                                   axis, values))
        self.pub_diag.publish(diagnostic_array(self, statuses))


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``friction_feedforward --ros-args --params-file config/gimbal_friction.yaml``."""
    sys.exit(run_node('friction_feedforward', FrictionFeedforward, args, suite_node='friction_feedforward'))


if __name__ == '__main__':
    main()
