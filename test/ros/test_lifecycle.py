"""The managed nodes through the real lifecycle services: each node started with ``autostart:=false`` as its own
process, its transitions driven by ``/<node>/change_state`` and read back by ``/<node>/get_state``
(lifecycle_msgs/srv/ChangeState, GetState), its outputs checked in each state."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray

from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import default_typestore
from gimbal_friction.streams.delivery import received_key

pytestmark = [pytest.mark.ros, pytest.mark.slow]
V = 0.05  #: joint rate of the test's joint states [rad/s]


def state(probe: Any, node: str) -> str:
    return str(probe.call(GetState, f'/{node}/get_state', GetState.Request(), resend_s=2.0).current_state.label)


def change(probe: Any, node: str, transition: int) -> bool:
    request = ChangeState.Request()
    request.transition.id = transition
    return bool(probe.call(ChangeState, f'/{node}/change_state', request).success)


def diag_values(probe: Any, name: str) -> list[tuple[str, dict[str, str]]]:
    """(message, values) of every status ``name`` (or ``name/...``) received on /diagnostics, oldest first."""
    return [(st.message, {kv.key: kv.value for kv in st.values}) for arr in probe.received['/diagnostics']
            for st in arr.status if st.name == name or st.name.startswith(name + '/')]


def wait_diag(probe: Any, name: str, cond: Any, what: str) -> tuple[str, dict[str, str]]:
    found: list[tuple[str, dict[str, str]]] = []

    def seen() -> bool:
        found[:] = [one for one in diag_values(probe, name) if cond(*one)]
        return bool(found)
    probe.spin_until(seen, what=what)
    return found[-1]


def joint_state(sec: int) -> JointState:
    msg = JointState(name=['elevation'], position=[0.01], velocity=[V], effort=[0.0])
    msg.header.stamp = Time(sec=sec, nanosec=0)
    return msg


def test_feedforward_publishes_only_while_active_and_leaves_a_zero_behind(spawn, probe):
    """unconfigured -> inactive: nothing published for the joint states received; active: one feedforward per
    joint state; deactivate: exactly one zero feedforward for every joint (and zero commands), then nothing while
    inactive; cleanup releases the subscriptions; shutdown finalizes; SIGINT ends the process cleanly."""
    node = 'friction_feedforward'
    proc = spawn(node, '--ros-args', '-p', 'autostart:=false', '-p', 'diagnostics_period_s:=0.1')
    status_name = 'gimbal_friction/feedforward/elevation'
    probe.subscribe(JointState, topics.FEEDFORWARD, 1000)
    probe.subscribe(Float64MultiArray, topics.FEEDFORWARD_COMMANDS, 1000)
    probe.subscribe(DiagnosticArray, '/diagnostics', 1000)
    probe.publisher(Temperature, topics.TEMPERATURE)
    js = probe.publisher(JointState, topics.JOINT_STATES)
    assert state(probe, node) == 'unconfigured'
    assert js.get_subscription_count() == 0   # nothing made before configure
    assert change(probe, node, Transition.TRANSITION_CONFIGURE)
    assert state(probe, node) == 'inactive'
    probe.wait_matched(topics.JOINT_STATES)
    probe.pubs[topics.TEMPERATURE].publish(Temperature(temperature=-20.0))

    def send_and_wait_received(secs: range, total: int, lifecycle: str) -> None:
        for sec in secs:
            js.publish(joint_state(sec))
        wait_diag(probe, status_name, lambda m, v: v.get(received_key(topics.JOINT_STATES)) == str(total)
                  and v.get('lifecycle_state') == lifecycle, f'{total} joint states received while {lifecycle}')

    send_and_wait_received(range(100, 110), 10, 'inactive')   # inactive: received, not answered
    message, _ = diag_values(probe, status_name)[-1]
    assert message.startswith('inactive:'), message
    assert change(probe, node, Transition.TRANSITION_ACTIVATE)
    assert state(probe, node) == 'active'
    for sec in range(200, 210):
        js.publish(joint_state(sec))
    ff = probe.received[topics.FEEDFORWARD]
    probe.spin_until(lambda: len(ff) >= 10, what='10 feedforwards while active')
    assert [m.header.stamp.sec for m in ff] == list(range(200, 210))   # none of the inactive ones came late
    assert all(m.effort[0] > 0.0 for m in ff)   # moving positive: a positive torque
    assert change(probe, node, Transition.TRANSITION_DEACTIVATE)
    assert state(probe, node) == 'inactive'
    probe.spin_until(lambda: len(ff) >= 11, what='the zero feedforward of the deactivation')
    zero = ff[10]
    assert list(zero.name) == ['elevation'] and list(zero.effort) == [0.0]
    cmd = probe.received[topics.FEEDFORWARD_COMMANDS]
    probe.spin_until(lambda: len(cmd) >= 11, what='the zero commands of the deactivation')
    assert list(cmd[10].data) == [0.0]
    send_and_wait_received(range(300, 310), 30, 'inactive')   # inactive again: nothing more
    assert change(probe, node, Transition.TRANSITION_ACTIVATE)
    for sec in range(400, 405):
        js.publish(joint_state(sec))
    probe.spin_until(lambda: len(ff) >= 16, what='feedforwards after the second activation')
    assert [m.header.stamp.sec for m in ff[11:]] == list(range(400, 405))   # nothing of the inactive time
    assert len(ff) == 16
    assert change(probe, node, Transition.TRANSITION_DEACTIVATE)
    probe.spin_until(lambda: len(ff) >= 17, what='the second zero feedforward')
    assert list(ff[16].effort) == [0.0]
    assert change(probe, node, Transition.TRANSITION_CLEANUP)
    assert state(probe, node) == 'unconfigured'
    probe.spin_until(lambda: js.get_subscription_count() == 0, what='the subscriptions released by cleanup')
    assert change(probe, node, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert state(probe, node) == 'finalized'
    assert proc.alive(), proc.output()
    code, out = proc.stop()
    assert code == 0, out
    assert len(ff) == 17


def test_configure_with_a_bad_parameter_fails_and_the_node_stays_unconfigured(spawn, probe):
    """A value configure refuses: the transition fails (FAILURE), the reason is on /diagnostics (ERROR, naming the
    parameter), the node stays unconfigured and keeps running; a second try fails the same way. The same value
    with autostart (the default) stops the process with the reason, as before."""
    node = 'friction_feedforward'
    probe.subscribe(DiagnosticArray, '/diagnostics', 100)
    proc = spawn(node, '--ros-args', '-p', 'autostart:=false', '-p', 'max_torque_nm:=-1.0')
    assert state(probe, node) == 'unconfigured'
    assert not change(probe, node, Transition.TRANSITION_CONFIGURE)
    assert state(probe, node) == 'unconfigured'
    message, values = wait_diag(probe, f'gimbal_friction/{node}/lifecycle', lambda m, v: True,
                                'the refusal on /diagnostics')
    assert 'max_torque_nm' in message and values['lifecycle_state'] == 'unconfigured', (message, values)
    level = [st.level for arr in probe.received['/diagnostics'] for st in arr.status
             if st.name == f'gimbal_friction/{node}/lifecycle'][-1]
    assert level == DiagnosticStatus.ERROR
    lifecycle = f'gimbal_friction/{node}/lifecycle'
    probe.spin_until(lambda: len(diag_values(probe, lifecycle)) >= 2, what='the refusal repeated on /diagnostics')
    assert not change(probe, node, Transition.TRANSITION_CONFIGURE)
    assert state(probe, node) == 'unconfigured' and proc.alive(), proc.output()
    assert 'configure failed' in proc.output() and 'max_torque_nm' in proc.output()
    autostarted = spawn(node, '--ros-args', '-p', 'max_torque_nm:=-1.0')
    code, out = autostarted.wait()
    assert code == 1 and 'max_torque_nm' in out, out


def test_estimator_transitions_and_diagnostics_say_the_state(spawn, probe):
    """friction_estimator through configure, activate, deactivate, cleanup and shutdown: each answered SUCCESS,
    get_state following, its /diagnostics (published while inactive too) saying the state; its outputs are
    LifecyclePublishers (none while inactive)."""
    node = 'friction_estimator'
    probe.subscribe(DiagnosticArray, '/diagnostics', 100)
    proc = spawn(node, '--ros-args', '-p', 'autostart:=false', '-p', 'diagnostics_period_s:=0.1')
    name = 'gimbal_friction/estimator'
    assert state(probe, node) == 'unconfigured'
    assert change(probe, node, Transition.TRANSITION_CONFIGURE) and state(probe, node) == 'inactive'
    wait_diag(probe, name, lambda m, v: v.get('lifecycle_state') == 'inactive', 'diagnostics saying inactive')
    assert change(probe, node, Transition.TRANSITION_ACTIVATE) and state(probe, node) == 'active'
    wait_diag(probe, name, lambda m, v: v.get('lifecycle_state') == 'active', 'diagnostics saying active')
    assert change(probe, node, Transition.TRANSITION_DEACTIVATE) and state(probe, node) == 'inactive'
    assert change(probe, node, Transition.TRANSITION_CLEANUP) and state(probe, node) == 'unconfigured'
    assert change(probe, node, Transition.TRANSITION_CONFIGURE) and state(probe, node) == 'inactive'
    assert change(probe, node, Transition.TRANSITION_INACTIVE_SHUTDOWN) and state(probe, node) == 'finalized'
    code, out = proc.stop()
    assert code == 0, out


def test_logger_opens_the_log_on_activate_and_closes_it_on_deactivate(spawn, probe, tmp_path: Path):
    """Configure opens nothing; activate opens the log; deactivate closes it cleanly (metadata.yaml written, the
    folder readable by rosbags while the node still runs, holding what arrived while active); a second activation
    writes a log of its own beside it."""
    node = 'residual_logger'
    folder = tmp_path / 'log'
    probe.subscribe(DiagnosticArray, '/diagnostics', 100)
    temp = probe.publisher(Temperature, topics.TEMPERATURE)
    proc = spawn(node, '--ros-args', '-p', 'autostart:=false', '-p', f'output_dir:={folder}', '-p',
                 'diagnostics_period_s:=0.1', '-p', 'flush_period_s:=0.1')
    name = 'gimbal_friction/residual_logger'
    assert change(probe, node, Transition.TRANSITION_CONFIGURE) and state(probe, node) == 'inactive'
    message, _ = wait_diag(probe, name, lambda m, v: v.get('lifecycle_state') == 'inactive', 'inactive')
    assert message == 'inactive: not logging' and not folder.exists(), message
    assert change(probe, node, Transition.TRANSITION_ACTIVATE)
    wait_diag(probe, name, lambda m, v: v.get('current_file', 'none') != 'none', 'the log open')
    probe.wait_matched(topics.TEMPERATURE)
    for i in range(20):
        temp.publish(Temperature(temperature=float(i)))
    wait_diag(probe, name, lambda m, v: int(v.get('messages_logged', 0)) >= 20, '20 temperatures logged')
    assert not (folder / 'metadata.yaml').exists()   # open: not finished yet
    assert change(probe, node, Transition.TRANSITION_DEACTIVATE)
    assert (folder / 'metadata.yaml').exists() and proc.alive()
    with AnyReader([folder], default_typestore=default_typestore()) as reader:
        logged = [c for c in reader.connections if c.topic == topics.TEMPERATURE]
        assert sum(1 for _ in reader.messages(connections=logged)) == 20
    assert change(probe, node, Transition.TRANSITION_ACTIVATE)
    siblings = [p for p in tmp_path.iterdir() if p.name.startswith('log_')]
    assert len(siblings) == 1, list(tmp_path.iterdir())
    code, out = proc.stop()
    assert code == 0, out
    assert (siblings[0] / 'metadata.yaml').exists()   # closed at the end of the process (shutdown from active)


def test_an_unexpected_error_goes_through_error_processing_back_to_unconfigured(probe, ros_env):
    """An exception that is not a refusal (a bug, a lost disk) in configure: the transition answers ERROR (not an
    exception), error processing releases what configure had made, the reason (its type and text) is logged and on
    /diagnostics, and the node is unconfigured again (get_state over the real service)."""
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from gimbal_friction.nodes._lifecycle import ManagedNode

    class Broken(ManagedNode):
        def configure_node(self) -> None:
            self.create_timer(1.0, lambda: None)
            self.create_subscription(Temperature, topics.TEMPERATURE, lambda m: None, 10)
            raise RuntimeError('disk on fire')

    probe.subscribe(DiagnosticArray, '/diagnostics', 100)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_env[0])
    node = Broken('broken', context=context, parameter_overrides=[Parameter('autostart', value=False)])
    timers = len(list(node.timers))   # (the node's own, made before any configure)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        probe.spin_until(lambda: node.count_subscribers('/diagnostics') > 0, what='the probe on /diagnostics')
        assert state(probe, 'broken') == 'unconfigured'
        assert not change(probe, 'broken', Transition.TRANSITION_CONFIGURE)
        assert state(probe, 'broken') == 'unconfigured'
        message, values = wait_diag(probe, 'gimbal_friction/broken/lifecycle', lambda m, v: True, 'the reason')
        assert message == 'unconfigured: configure failed: RuntimeError: disk on fire', message
        assert node.lifecycle_error == 'configure failed: RuntimeError: disk on fire'
        assert values['transition'] == 'configure' and values['lifecycle_state'] == 'unconfigured'
        assert len(list(node.timers)) == timers   # released: the timer and the subscription configure made
        assert not [s for s in node.subscriptions if s.topic_name == topics.TEMPERATURE]
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
        spinner.join(10)


def test_estimator_publishes_the_samples_waiting_for_a_temperature_on_deactivate_and_shutdown(spawn, probe):
    """Samples paired while active but waiting for a later temperature (``temperature_wait_s``, 60 s of stamps)
    are published when the node is deactivated, and again when it is shut down from active, with the temperature in
    force at their
    stamp: nothing measured while active is lost. (Inputs keep arriving throughout, so the idle release of a
    silent input does not publish them first; without the flush they went to a publisher already stopped.)"""
    node = 'friction_estimator'
    proc = spawn(node, '--ros-args', '-p', 'autostart:=false', '-p', 'diagnostics_period_s:=0.1',
                 '-p', 'min_dwell_s:=0.0', '-p', 'temperature_wait_s:=60.0')
    measured: list[JointState] = []
    detail: list[Float64MultiArray] = []
    probe.node.create_subscription(JointState, topics.MEASURED, measured.append, 1000)
    probe.node.create_subscription(Float64MultiArray, topics.MEASURED_DETAIL, detail.append, 1000)
    probe.subscribe(DiagnosticArray, '/diagnostics', 1000)
    temp = probe.publisher(Temperature, topics.TEMPERATURE)
    js = probe.publisher(JointState, topics.JOINT_STATES)
    cur = probe.publisher(JointState, topics.MOTOR_CURRENT)
    assert change(probe, node, Transition.TRANSITION_CONFIGURE)
    assert change(probe, node, Transition.TRANSITION_ACTIVATE) and state(probe, node) == 'active'
    for topic in (topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT):
        probe.wait_matched(topic)
    # another joint's states keep the input alive (no idle release) until the node is shut down
    keepalive = JointState(name=['not_configured'], position=[0.0], velocity=[0.0])
    probe.node.create_timer(0.1, lambda: js.publish(keepalive))
    sent_t = [0]

    def temperature_known() -> bool:   # (resent, stamped a millisecond later, until the node has it)
        msg = Temperature(temperature=-20.0)
        msg.header.stamp = Time(sec=100, nanosec=sent_t[0] * 1_000_000)
        sent_t[0] += 1
        temp.publish(msg)
        return any(v.get('temperature_c') == '-20' for _, v in diag_values(probe, 'gimbal_friction/estimator'))
    probe.spin_until(temperature_known, what='the temperature in the diagnostics')
    v = 2 * 3.141592653589793 / 180   # the commanded speed, 1/3 rpm [rad/s]

    def send_samples(start_s: int) -> int:
        for k in range(20):
            stamp = Time(sec=start_s + (k * 20) // 1000, nanosec=((k * 20) % 1000) * 1_000_000)
            state_msg = JointState(name=['elevation'], position=[0.1 + v * k * 0.02], velocity=[v])
            state_msg.header.stamp = stamp
            current = JointState(name=['elevation'], effort=[0.06])
            current.header.stamp = stamp
            cur.publish(current)
            js.publish(state_msg)
        found = wait_diag(probe, 'gimbal_friction/estimator/elevation',
                          lambda m, vals: int(vals.get('waiting_for_temperature', 0)) >= 10,
                          'samples waiting for a later temperature')
        return int(found[1]['waiting_for_temperature'])

    def since(sec: int) -> list[JointState]:
        return [m for m in measured if m.header.stamp.sec >= sec]

    waiting = send_samples(101)
    assert measured == []   # held: none published while active
    assert change(probe, node, Transition.TRANSITION_DEACTIVATE) and state(probe, node) == 'inactive'
    probe.spin_until(lambda: len(measured) >= waiting, what=f'the {waiting} waiting samples on deactivate')
    assert all(m.header.stamp.sec == 101 and list(m.name) == ['elevation'] for m in measured)
    from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS
    t_index = MEASUREMENT_FIELDS.index('temperature_c')
    probe.spin_until(lambda: len(detail) >= waiting, what='the details of the waiting samples')
    assert all(d.data[t_index] == -20.0 for d in detail)   # the temperature in force at their stamp
    assert change(probe, node, Transition.TRANSITION_ACTIVATE)
    waiting = send_samples(103)
    assert since(103) == []
    assert change(probe, node, Transition.TRANSITION_ACTIVE_SHUTDOWN) and state(probe, node) == 'finalized'
    probe.spin_until(lambda: len(since(103)) >= waiting, what='the waiting samples on shutdown')
    code, out = proc.stop()
    assert code == 0, out


def test_an_unconfigured_node_has_its_parameters_declared_and_configure_reads_what_was_set(spawn, probe):
    """With autostart:=false every parameter is declared at construction (as nav2's nodes are): ``ros2 param
    list / describe / set`` work before configure (the type is fixed: an integer for a double is refused), and
    configure reads the values set then: a valid one is kept, an invalid pair (temperature_max_c below
    temperature_min_c) makes configure fail naming it."""
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters

    def set_one(node: str, name: str, value: ParameterValue) -> Any:
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
        return probe.call(SetParameters, f'/{node}/set_parameters', request).results[0]

    def double(x: float) -> ParameterValue:
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=x)

    for node, name in (('friction_estimator', 'min_dwell_s'), ('friction_feedforward', 'max_torque_nm'),
                       ('residual_logger', 'flush_period_s')):
        proc = spawn(node, '--ros-args', '-p', 'autostart:=false')
        assert state(probe, node) == 'unconfigured'
        names = set(probe.call(ListParameters, f'/{node}/list_parameters', ListParameters.Request()).result.names)
        assert {name, 'axes', 'autostart'} <= names, sorted(names)
        if node != 'residual_logger':
            assert 'model.ball_count' in names
        (desc,) = probe.call(DescribeParameters, f'/{node}/describe_parameters',
                             DescribeParameters.Request(names=[name])).descriptors
        assert desc.type == ParameterType.PARAMETER_DOUBLE and not desc.dynamic_typing
        assert not set_one(node, name, ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                                      integer_value=1)).successful
        assert set_one(node, name, double(0.25)).successful
        assert change(probe, node, Transition.TRANSITION_CONFIGURE), proc.output()
        (value,) = probe.call(GetParameters, f'/{node}/get_parameters', GetParameters.Request(names=[name])).values
        assert value.double_value == 0.25
        proc.stop()
    node = 'friction_estimator'
    proc = spawn(node, '--ros-args', '-p', 'autostart:=false')
    assert set_one(node, 'temperature_max_c', double(-100.0)).successful   # (checked by configure)
    assert not change(probe, node, Transition.TRANSITION_CONFIGURE)
    assert state(probe, node) == 'unconfigured' and 'temperature_max_c' in proc.output(), proc.output()
