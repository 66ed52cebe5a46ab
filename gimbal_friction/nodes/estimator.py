"""``friction_estimator``: measured friction torque from motor current (paper Eq. 23), in steady state or while
the gimbal works (observer).

A lifecycle node (``/<node>/change_state``, ``get_state``; docs/ros.md, Lifecycle): ``autostart`` (default true)
configures and activates it at start-up; ``autostart:=false`` waits for a lifecycle manager. Deactivate and
shutdown first publish the samples still waiting for a later temperature (with the one in force at their stamp).

Subscribes ``/gimbal/motor_current`` (sensor_msgs/JointState, effort = armature current [A] per joint),
``/joint_states`` (position [rad], velocity [rad/s] relative to the base) and ``/gimbal/temperature``
(sensor_msgs/Temperature, °C); every input follows its publishers' reliability (the temperature starts best
effort) and every publisher and subscription takes ``qos_overrides.*`` (:mod:`gimbal_friction.nodes._qos`). The messages
received are handed every ``batch_period_s`` to :class:`gimbal_friction.estimation.estimator.EstimatorLogic` —
the same code the offline ``replay`` runs over a whole bag; its result does not depend on the batching, so live
and offline give the same numbers. The rules (pairing, steady-state and observer acceptance, stamps, rejections,
statistics) are in that module.

Publishes:

- ``/gimbal/friction/measured`` (sensor_msgs/JointState), one message per accepted sample: ``header.stamp`` =
  stamp of the joint state of the pair (so it lines up with the feedforward of that joint state), ``name =
  [joint]``, ``position = [rad]``, ``velocity = [rad/s]``, ``effort = [friction N·m]`` signed like the motion. Never
  NaN.
- ``/gimbal/friction/measured_detail`` (std_msgs/Float64MultiArray), one message per accepted sample:
  ``layout.dim[0].label`` = joint, ``data`` = :data:`gimbal_friction.streams.measurement.MEASUREMENT_FIELDS` (stamp sec
  and nanosec, position, velocity, acceleration, current, temperature used and whether it was fresh, friction, the
  K_T, I_0 and J applied, and the method: 0 steady state, 1 observer). What the residual logger logs.
- ``/diagnostics`` (every ``diagnostics_period_s``): one status per joint, ``gimbal_friction/estimator/<joint>``
  (hardware_id = joint) with ``accepted``, ``rejected: <reason>`` per reason seen, ``pending`` (currents waiting
  for their joint state), ``last_friction_nm``, ``last_stamp_s``, ``last_method``, ``torque_constant_nm_per_a``,
  ``no_load_current_a``, ``inertia_kg_m2``; and ``gimbal_friction/estimator`` for inputs that belong to no joint
  and the temperature. WARN while no sample was accepted or when bad inputs were rejected (not the
  steady-state/observer verdicts), with the reasons in the message; back to OK once the cause has gone for a
  diagnostics period.
- ``/gimbal/friction/statistics`` (diagnostic_msgs/DiagnosticArray, every ``statistics_period_s``): the running
  statistics of the steady-state samples, one DiagnosticStatus per (joint, direction, temperature plateau) named
  ``gimbal_friction/estimator/statistics/<joint>/<+1|-1>/<plateau_c|unknown>`` with the values ``joint``,
  ``direction``, ``plateau_c``, ``count``, ``mean_nm``, ``std_nm``, ``ripple_nm``, ``min_position_rad``,
  ``max_position_rad`` (round-trip decimal strings).

Parameters: the model parameters (K_T = ``torque_constant_nm_per_a``, I_0 = ``no_load_current_a``, J =
``inertia_kg_m2``, per joint via ``axis.<joint>.*``), every field of
:class:`~gimbal_friction.estimation.estimator.EstimatorSettings` and the node's periods. ``ros2 param set`` is
validated as a whole before it succeeds; a change of the estimator settings restarts steady-state detection, a
change of a joint's K_T or I_0 restarts that joint's statistics.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.common.settings import settings_from
from gimbal_friction.common.units import join_stamp, split_stamp
from gimbal_friction.config.node_settings import EstimatorNodeSettings
from gimbal_friction.estimation.estimator import (
    EstimatorLogic,
    EstimatorSettings,
)
from gimbal_friction.estimation.report import EstimatorReport
from gimbal_friction.nodes._common import (
    InputCounter,
    ModelParameters,
    callback_error_values,
    check_model,
    declare_settings,
    diagnostic_array,
    field_names,
    parameter_guard,
    retime,
    run_node,
    settings_defaults,
    split_parameters,
    startup_model_error,
    to_msg,
)
from gimbal_friction.nodes._lifecycle import ManagedNode
from gimbal_friction.nodes._qos import Inputs, create_publisher
from gimbal_friction.recording import topics
from gimbal_friction.streams.arrays import chamber_arrays
from gimbal_friction.streams.diagnostics import statistics_statuses
from gimbal_friction.streams.input_health import SILENCE_TIMEOUT_S
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, MeasurementArrays, detail_matrix

#: subscription depth: a burst of this many messages is buffered, not dropped
DEPTH = 1000
#: no message for this long [s, wall clock]: the input has ended, the samples waiting for a temperature go out
IDLE_RELEASE_S = 1.0
_Msg = tuple[int, int, list[str], list[float], list[float], list[float]]


NodeSettings = EstimatorNodeSettings  # the node-level parameters (gimbal_friction.common.settings)

_EST_FIELDS = field_names(EstimatorSettings)
_NODE_FIELDS = field_names(NodeSettings)


class FrictionEstimator(ManagedNode):
    """The estimator node (thin adapter around :class:`EstimatorLogic`), a lifecycle node
    (:mod:`gimbal_friction.nodes._lifecycle`): with ``autostart`` (the default) configured and active once built."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('friction_estimator', **kwargs)

    def parameter_steps(self) -> list[Callable[[], object]]:
        """The model, the estimator's and the node's settings (declared at construction and by configure)."""
        return [lambda: ModelParameters(self), lambda: declare_settings(self, EstimatorSettings),
                lambda: declare_settings(self, NodeSettings)]

    def configure_node(self) -> None:
        """The lifecycle's configure: parameters read and validated (the shared model must build), the estimator,
        subscriptions, publishers and timers made."""
        self.model = ModelParameters(self)
        est_settings = declare_settings(self, EstimatorSettings)
        self.settings = declare_settings(self, NodeSettings)
        self.inputs = InputCounter()
        axes = self.model.current()
        try:
            check_model(axes, est_settings.temperature_min_c, est_settings.temperature_max_c)
        except ModelDomainError as err:
            defaults = {**self.model.defaults, **settings_defaults(EstimatorSettings)}
            raise startup_model_error(self, err, defaults) from None
        self.logic = EstimatorLogic(axes, est_settings)
        self._candidate: tuple[Any, EstimatorSettings | None, NodeSettings] | None = None
        self._temps: list[tuple[int, int, float]] = []
        self._joint_states: list[_Msg] = []
        self._currents: list[_Msg] = []
        self._arrival = 0
        self.report = EstimatorReport()   #: the /diagnostics statuses, report after report
        self._last_warn: dict[str, float] = {}
        self.pub_measured = create_publisher(self, JointState, topics.MEASURED, DEPTH)
        self.pub_detail = create_publisher(self, Float64MultiArray, topics.MEASURED_DETAIL, DEPTH)
        self.pub_diag = create_publisher(self, DiagnosticArray, topics.DIAGNOSTICS, 10, managed=False)
        self.pub_stats = create_publisher(self, DiagnosticArray, topics.STATISTICS, 10)
        # every input hears reliable and best-effort publishers (nodes/_qos.py). The temperature too, with a deep
        # queue: a temperature dropped by a full best-effort queue of 5 gave the samples of its period the previous
        # one (live no longer equal to replay)
        self.input_topics = ins = Inputs(self, self.inputs)
        ins.add(Temperature, topics.TEMPERATURE, self.on_temperature, DEPTH, required=True,
                timeout_s=max(SILENCE_TIMEOUT_S, est_settings.temperature_timeout_s))
        ins.add(JointState, topics.JOINT_STATES, self.on_joint_state, DEPTH, required=True)
        ins.add(JointState, topics.MOTOR_CURRENT, self.on_current, DEPTH, required=True)
        self._last_input = time.monotonic()
        self._batch_timer = self.create_timer(self.settings.batch_period_s, self.process)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        self._stats_timer = self.create_timer(self.settings.statistics_period_s, self.publish_statistics)
        parameter_guard(self, self._validate_params, self._apply_params)
        kt = ', '.join(f'{j} K_T={p.torque_constant_nm_per_a:g} N*m/A I_0={p.no_load_current_a:g} A'
                       for j, p in self.logic.axes.items())
        self.get_logger().info(f'friction_estimator ({est_settings.method}): {kt}')

    def stop_output(self) -> None:
        """The lifecycle's deactivate (and shutdown from active), before the publishers stop: the messages
        received so far processed, then the samples still waiting for a later temperature published with the one
        in force at their stamp (:meth:`EstimatorLogic.flush`), so nothing measured while active is lost."""
        self.process()
        self._publish(self.logic.flush())

    # ------------------------------------------------------------------ parameters
    def _validate_params(self, params: list[Parameter[Any]]) -> None:
        model, est, node = split_parameters(params, _EST_FIELDS, _NODE_FIELDS)
        axes = self.model.current(model) if model else None
        est_settings = settings_from(EstimatorSettings, est, self.logic.settings) if est else None
        if axes is not None or est_settings is not None:  # the whole estimator and the shared model must build
            new_axes, new_settings = axes or self.logic.axes, est_settings or self.logic.settings
            check_model(new_axes, new_settings.temperature_min_c, new_settings.temperature_max_c)
            EstimatorLogic(new_axes, new_settings)
        self._candidate = (axes, est_settings, settings_from(NodeSettings, node, self.settings))

    def _apply_params(self, params: list[Parameter[Any]]) -> None:
        if self._candidate is None:
            return
        axes, est_settings, node_settings = self._candidate
        self._candidate = None
        self.process()  # what was received so far is judged with the old parameters
        if est_settings is not None:
            self.logic.update_settings(est_settings)
            self.get_logger().info('estimator settings changed: steady-state detection restarted')
        if axes is not None:
            for axis, p in axes.items():
                self.logic.set_axis_params(axis, p)
        old = self.settings
        self.settings = node_settings
        self._batch_timer = retime(self, self._batch_timer, old.batch_period_s, node_settings.batch_period_s,
                                   self.process)
        self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s,
                                  node_settings.diagnostics_period_s, self.publish_diagnostics)
        self._stats_timer = retime(self, self._stats_timer, old.statistics_period_s,
                                   node_settings.statistics_period_s, self.publish_statistics)

    # ------------------------------------------------------------------ callbacks: buffer, then process
    def _arrival_ns(self) -> int:
        """Receive time [ns], strictly increasing (it orders the messages of a batch)."""
        now = self.get_clock().now().nanoseconds
        self._arrival = max(now, self._arrival + 1)
        return self._arrival

    def on_temperature(self, msg: Temperature) -> None:
        self._temps.append((self._arrival_ns(), join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec),
                            float(msg.temperature)))

    def on_joint_state(self, msg: JointState) -> None:
        self._joint_states.append((self._arrival_ns(), join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec),
                                   list(msg.name), list(msg.position), list(msg.velocity), []))

    def on_current(self, msg: JointState) -> None:
        self._currents.append((self._arrival_ns(), join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec),
                               list(msg.name), [], [], list(msg.effort)))

    def process(self) -> None:
        """Hand the buffered messages to the logic and publish what it accepted. When no message has come for
        :data:`IDLE_RELEASE_S` the input has ended (a bag played out, a test stand stopped): the samples still waiting
        for a later temperature are published with the one in force at their stamp."""
        now = time.monotonic()
        if not (self._temps or self._joint_states or self._currents):
            if now - self._last_input > IDLE_RELEASE_S and any(self.logic.held(j) for j in self.logic.order):
                self._publish(self.logic.flush())
            return
        self._last_input = now
        batch, js_counts, cur_counts = chamber_arrays(self._temps, self._joint_states, self._currents,
                                                       configured=self.logic.order)
        self._temps, self._joint_states, self._currents = [], [], []
        self.logic.count_messages(js_counts, cur_counts)
        measured = self.logic.feed(batch)
        self._publish(measured)

    def _publish(self, m: MeasurementArrays) -> None:
        if not len(m):
            return
        detail = detail_matrix(m)
        n_fields = len(MEASUREMENT_FIELDS)
        for k, joint in enumerate(m.joint.tolist()):
            sec, nanosec = split_stamp(int(m.stamp_ns[k]))
            out = JointState()
            out.header.stamp = Time(sec=sec, nanosec=nanosec)
            out.name = [joint]
            out.position = [float(m.position_rad[k])]
            out.velocity = [float(m.velocity_rad_s[k])]
            out.effort = [float(m.friction_nm[k])]
            self.pub_measured.publish(out)
            d = Float64MultiArray()
            d.layout.dim = [MultiArrayDimension(label=joint, size=n_fields, stride=n_fields)]
            d.data = detail[k].tolist()
            self.pub_detail.publish(d)

    # ------------------------------------------------------------------ diagnostics and statistics
    def publish_diagnostics(self) -> None:
        """``/diagnostics`` (its statuses and rules: :class:`~gimbal_friction.estimation.report.EstimatorReport`)."""
        statuses = self.report.statuses(
            self.logic, lost=self.inputs.new_losses(), input_problems=self.input_topics.problems(),
            input_values={**self.inputs.values(), **self.input_topics.values()}, errors=callback_error_values(self))
        self.pub_diag.publish(diagnostic_array(self, [to_msg(one) for one in statuses]))

    def publish_statistics(self) -> None:
        """``/gimbal/friction/statistics`` (:func:`~gimbal_friction.streams.diagnostics.statistics_statuses`)."""
        statuses = [to_msg(one) for one in statistics_statuses(self.logic.statistics())]
        self.pub_stats.publish(diagnostic_array(self, statuses))


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``friction_estimator --ros-args --params-file config/gimbal_friction.yaml``."""
    sys.exit(run_node('friction_estimator', FrictionEstimator, args, suite_node='friction_estimator'))


if __name__ == '__main__':
    main()
