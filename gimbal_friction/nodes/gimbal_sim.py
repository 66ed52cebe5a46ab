"""``gimbal_sim``: a simulated gimbal axis in closed loop with its seeker controller, at wall-clock pace.

A thin adapter around :class:`gimbal_friction.sim.realtime.RealtimeRun` (the very closed loop the offline
``gimbal-friction loop-study`` runs): the rigid axis with the truth friction (the node's own parameters, never the
configured model: the paper's bearing with a lubricant that differs from the datasheet, LuGre breakaway and
pre-sliding, position ripple, the measured CW/CCW asymmetry), the torque motor and its current
loop, the bearing temperature behind the environment, the sensors and the seeker's own stabilization controller
(rate PI on the LOS gyro at ``rate_loop_hz``, outer track loop). A thread steps the loop one controller tick at a
time when the tick is due (``realtime_factor`` simulated seconds per wall second) and publishes, stamped with the
tick's sample time (run start + simulated time):

- ``/joint_states`` (sensor_msgs/JointState): the resolver's joint angle [rad] and (RDC) rate [rad/s] of the gimbal
  *relative to the base* (what the feedforward and the estimator need), every ``publish_every_ticks``;
- ``/gimbal/motor_current`` (sensor_msgs/JointState): effort = measured armature current [A], same ticks;
- ``/gimbal/reference_velocity`` (sensor_msgs/JointState): velocity = the controller's reference joint velocity,
  commanded LOS rate − base rate estimate (gyro − resolver rate) [rad/s], same ticks (``publish_reference_velocity``):
  the input of ``friction_feedforward`` with ``velocity_source: reference``;
- ``/gimbal/temperature`` (sensor_msgs/Temperature): the bearing temperature sensor [°C] at ``temperature_rate_hz``
  (variance = the sensor noise²);
- ``/gimbal_sim/los_error`` (sensor_msgs/JointState), every ``los_error_every_ticks``: position = LOS angle error
  [rad], velocity = LOS rate error [rad/s] (inertial LOS − target), effort = the truth friction torque [N·m];
- ``/diagnostics``: run progress, lag behind real time, feedforward received, its transport latency (p50/p95)
  and age, LOS rate error RMS so far.

It subscribes ``/gimbal/friction/feedforward`` (sensor_msgs/JointState; the effort of its joint) and adds the latest
torque to the controller's output from the next tick on (``use_feedforward``): exactly the wiring a seeker
controller builds. The feedforward's stamp is the stamp of the joint state that produced it, so the node
measures the transport latency (arrival − publication of that joint state) and the age of the torque applied.

Parameters: the ``gimbal_sim`` section of ``config/gimbal_sim.yaml`` (every :class:`~gimbal_friction.sim.config.
SimConfig` parameter and the node settings :class:`~gimbal_friction.sim.config.RealtimeSettings`: profile,
environment temperature, duration, ``repeat`` / ``exit_when_done``, rates, ``record_path``), plus the model
parameters of the suite (``model.*``, ``axis.<joint>.*``: the configured K_T and J the seeker controller uses; the
truth friction, the plant's K_T and I_0 are the ``truth`` group of the ``gimbal_sim`` section, whatever the model
parameters say; the plant's J is the configured J times ``inertia_truth_ratio``). ``ros2 param set`` is validated
as a whole; a change applies to the next run. With ``exit_when_done`` the process ends after one run (exit code
0; 1 if it could not start). SIGINT ends it cleanly (the run so far is recorded when ``record_path`` is set).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState, Temperature

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import split_stamp
from gimbal_friction.config.parameter_rules import parameter_rule
from gimbal_friction.nodes._common import (
    ERROR,
    OK,
    WARN,
    InputCounter,
    ModelParameters,
    _value,
    callback_error_values,
    callback_failed,
    declare_typed,
    diagnostic_array,
    parameter_guard,
    run_node,
    settings_check,
    status,
    typed_descriptor,
    typed_value,
)
from gimbal_friction.nodes._qos import Inputs, create_publisher
from gimbal_friction.recording import topics
from gimbal_friction.sim.config import RealtimeSettings, SimConfig, parameter_specs
from gimbal_friction.sim.realtime import RealtimeRun, TickOutput
from gimbal_friction.streams.inputs import index_joints, unconfigured_joints

REFERENCE_VELOCITY = topics.REFERENCE_VELOCITY
LOS_ERROR = '/gimbal_sim/los_error'
#: publisher depth (a subscriber that falls behind loses the oldest)
DEPTH = 1000

_SIM_FIELDS = frozenset(f.name for f in dataclasses.fields(SimConfig))
_NODE_FIELDS = frozenset(f.name for f in dataclasses.fields(RealtimeSettings))


class GimbalSim(Node):
    """The simulator node (thin adapter around :class:`RealtimeRun`)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('gimbal_sim', **kwargs)
        self.model = ModelParameters(self)
        for spec in parameter_specs(node=True):
            declare_typed(self, spec['name'], typed_value(spec['default'], spec['default']),
                          typed_descriptor(spec['name'], spec['unit'], spec['description'], spec['default'],
                                           parameter_rule('gimbal_sim', spec['name'])),
                          settings_check(SimConfig if spec['name'] in _SIM_FIELDS else RealtimeSettings,
                                         spec['name'], ''))
        self.config, self.settings, self.joint = self._read({})
        self.axis = self.model.current()[self.joint]
        self._pending: tuple[SimConfig, RealtimeSettings, str] | None = None
        self.failed = False
        self.run: RealtimeRun | None = None
        self.runs_done = 0
        self.lag_s = 0.0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        qos = QoSProfile(depth=DEPTH)
        self.pub_js = create_publisher(self, JointState, topics.JOINT_STATES, qos)
        self.pub_cur = create_publisher(self, JointState, topics.MOTOR_CURRENT, qos)
        self.pub_ref = create_publisher(self, JointState, REFERENCE_VELOCITY, qos)
        self.pub_temp = create_publisher(self, Temperature, topics.TEMPERATURE, QoSProfile(depth=10))  # matches any
        self.pub_los = create_publisher(self, JointState, LOS_ERROR, qos)
        self.pub_diag = create_publisher(self, DiagnosticArray, topics.DIAGNOSTICS, 10)
        # the feedforward follows its publishers' reliability (nodes/_qos.py)
        self.input_topics = Inputs(self, InputCounter())
        self.input_topics.add(JointState, topics.FEEDFORWARD, self.on_feedforward, DEPTH)
        self._msgs = {name: JointState() for name in ('js', 'cur', 'ref', 'los')}
        for msg in self._msgs.values():
            msg.name = [self.joint]
        self._temp = Temperature()
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        parameter_guard(self, self._validate_params, self._apply_params)
        self._thread = threading.Thread(target=self._loop, name='gimbal_sim', daemon=True)
        self._thread.start()
        s = self.settings
        self.get_logger().info(
            f'gimbal_sim: joint {self.joint}, {s.profile} at {s.environment_temperature_c:g} degC, controller '
            f'{self.config.rate_loop_hz:g} Hz, feedforward {"on" if s.use_feedforward else "off"}')

    # ------------------------------------------------------------------ parameters
    def _read(self, proposed: dict[str, Any]) -> tuple[SimConfig, RealtimeSettings, str]:
        def get(name: str) -> Any:
            return proposed[name] if name in proposed else _value(self.get_parameter(name))

        config = SimConfig.from_mapping({name: get(name) for name in _SIM_FIELDS})
        settings = RealtimeSettings.from_mapping({name: get(name) for name in _NODE_FIELDS})
        joint = settings.joint or self.model.axes[0]
        refused = unconfigured_joints([joint], self.model.axes)
        if refused:
            raise ConfigError('joint', refused, joint)
        return config, settings, joint

    def _validate_params(self, params: list[Parameter[Any]]) -> None:
        proposed = {p.name: _value(p) for p in params}
        config, settings, joint = self._read(proposed)
        if joint != self.joint:
            raise ConfigError('joint', 'cannot change while running (restart the node)', joint)
        model = {k: v for k, v in proposed.items() if ModelParameters.is_model_parameter(k)}
        self.model.current(model)   # raises on an invalid model value
        self._pending = (config, settings, joint)

    def _apply_params(self, params: list[Parameter[Any]]) -> None:
        if self._pending is not None:
            with self._lock:
                self.config, self.settings, _ = self._pending
                self.axis = self.model.current()[self.joint]
            self._pending = None
            self.get_logger().info('gimbal_sim: new parameters apply to the next run')

    # ------------------------------------------------------------------ the feedforward
    def on_feedforward(self, msg: JointState) -> None:
        wall = time.monotonic()
        i = index_joints(msg.name, (), (self.joint,)).position.get(self.joint)
        if i is None or i >= len(msg.effort):
            return
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self._lock:
            run = self.run
            if run is not None:
                run.on_feedforward(float(msg.effort[i]), stamp_ns, wall)

    # ------------------------------------------------------------------ the simulation thread
    def _wait_start(self, settings: RealtimeSettings) -> bool:
        deadline = time.monotonic() + settings.start_timeout_s
        while not self._stop.is_set():
            ok = self.count_subscribers(topics.JOINT_STATES) >= settings.wait_for_subscribers
            if settings.use_feedforward and settings.wait_for_feedforward:
                ok = ok and self.count_publishers(topics.FEEDFORWARD) >= 1
            if ok:
                return True
            if time.monotonic() > deadline:
                self.get_logger().error(f'gimbal_sim: no subscribers / feedforward after '
                                        f'{settings.start_timeout_s:g} s')
                return False
            time.sleep(0.05)
        return False

    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                with self._lock:
                    config, settings, axis = self.config, self.settings, self.axis
                if not self._wait_start(settings):
                    self.failed = not self._stop.is_set()
                    break
                self._one_run(config, settings, axis)
                self.runs_done += 1
                if settings.exit_when_done or not settings.repeat or self._stop.is_set():
                    break
        except Exception as err:   # the node stays up and reports it on /diagnostics
            callback_failed(self, err)
            self.failed = True
        finally:
            with self._lock:
                settings = self.settings
            if settings.exit_when_done or self.failed:
                self.context.try_shutdown()

    def _one_run(self, config: SimConfig, settings: RealtimeSettings, axis: Any) -> None:
        run = RealtimeRun(config, axis, settings, epoch_ns=self.get_clock().now().nanoseconds)
        with self._lock:
            self.run = run
        start = time.monotonic()
        every, los_every = settings.publish_every_ticks, settings.los_error_every_ticks
        try:
            while not run.done and not self._stop.is_set():
                k = run.loop.k
                due = run.due_wall_s(start, k)
                now = time.monotonic()
                if due > now:
                    time.sleep(due - now)
                    now = time.monotonic()
                self.lag_s = now - due
                with self._lock:
                    out = run.step(now)
                self._publish(out, settings, every, los_every)
        finally:
            if settings.record_path:
                from gimbal_friction.runs.loop_live import save_run
                with self._lock:
                    save_run(settings.record_path, run)
                self.get_logger().info(f'gimbal_sim: run recorded to {settings.record_path}')

    def _publish(self, out: TickOutput, settings: RealtimeSettings, every: int, los_every: int) -> None:
        sec, nanosec = split_stamp(out.stamp_ns)
        m = self._msgs
        if out.tick % every == 0:
            js = m['js']
            js.header.stamp.sec, js.header.stamp.nanosec = sec, nanosec
            js.position, js.velocity = [out.joint_position_rad], [out.joint_velocity_rad_s]
            self.pub_js.publish(js)
            cur = m['cur']
            cur.header.stamp.sec, cur.header.stamp.nanosec = sec, nanosec
            cur.effort = [out.current_a]
            self.pub_cur.publish(cur)
            if settings.publish_reference_velocity:
                ref = m['ref']
                ref.header.stamp.sec, ref.header.stamp.nanosec = sec, nanosec
                ref.velocity = [out.reference_velocity_rad_s]
                self.pub_ref.publish(ref)
        if out.temperature_c is not None:
            t = self._temp
            t.header.stamp.sec, t.header.stamp.nanosec = sec, nanosec
            t.header.frame_id = self.joint
            t.temperature = out.temperature_c
            t.variance = self.config.temperature_noise_c ** 2
            self.pub_temp.publish(t)
        if out.tick % los_every == 0:
            los = m['los']
            los.header.stamp.sec, los.header.stamp.nanosec = sec, nanosec
            los.position, los.velocity = [out.position_error_rad], [out.rate_error_rad_s]
            los.effort = [out.friction_nm]
            self.pub_los.publish(los)

    # ------------------------------------------------------------------ diagnostics and shutdown
    def publish_diagnostics(self) -> None:
        with self._lock:
            run = self.run
            summary = run.latency_summary() if run is not None else {}
            k = run.loop.k if run is not None else 0
            ticks = run.ticks if run is not None else 0
            rms = math.nan
            if run is not None and k > 0:
                res = run.result()
                err = res.traces.los_rate_rad_s[:, 0] - res.profile.target_rate_rad_s
                rms = float(np.sqrt(np.mean(err * err)))
        s = self.settings
        level, problems = OK, []
        if self.lag_s > 0.01:
            level = WARN
            problems.append(f'{self.lag_s * 1e3:.0f} ms behind real time')
        if run is not None and s.use_feedforward and k > 1000 and not summary.get('feedforward_received'):
            level = WARN
            problems.append(f'no feedforward received on {topics.FEEDFORWARD}')
        values: dict[str, Any] = {
            'joint': self.joint, 'profile': s.profile, 'environment_temperature_c': s.environment_temperature_c,
            'runs_done': self.runs_done, 'tick': k, 'ticks': ticks, 'lag_s': self.lag_s,
            'use_feedforward': s.use_feedforward, 'los_rate_error_rms_rad_s': rms}
        values.update(summary)
        errors = callback_error_values(self)
        if errors:
            values.update(errors)
            level = ERROR
            problems.append('the simulation failed (see values)')
        self.pub_diag.publish(diagnostic_array(self, [status(f'gimbal_sim/{self.joint}', level,
                                                             '; '.join(problems) or 'ok', self.joint, values)]))

    def close(self) -> None:
        """Stop the simulation thread (the run so far is recorded if ``record_path`` is set)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``gimbal_sim --ros-args --params-file config/gimbal_sim.yaml``."""
    made: list[GimbalSim] = []

    def factory(**kwargs: Any) -> GimbalSim:
        node = GimbalSim(**kwargs)
        made.append(node)
        return node

    code = run_node('gimbal_sim', factory, args, suite_node='gimbal_sim')
    if code == 0 and made and made[0].failed:
        code = 1
    sys.exit(code)


if __name__ == '__main__':
    main()
