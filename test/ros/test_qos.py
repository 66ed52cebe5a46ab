"""Any publisher's QoS (issue 32 item 1): best-effort inputs are heard, ``qos_overrides`` parameters are taken from a
parameter file and applied, and an input that cannot deliver (incompatible QoS, wrong type, no publisher) is named
on ``/diagnostics`` with its cause."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import String

FF = '/gimbal/friction/feedforward'
JS = '/joint_states'
ROOT = Path(__file__).resolve().parents[2]
WARN = b'\x01'
pytestmark = pytest.mark.ros


def start_feedforward(spawn, *extra):
    return spawn('friction_feedforward', '--ros-args', '--params-file', str(ROOT / 'config/gimbal_friction.yaml'),
                 '-p', 'temperature_timeout_s:=30.0', *extra)


def latest(probe, name):
    """(level, message, values) of the latest status ``name`` on /diagnostics, or None."""
    for arr in reversed(probe.received['/diagnostics']):
        for st in arr.status:
            if st.name == name:
                return st.level, st.message, {kv.key: kv.value for kv in st.values}
    return None


def joint_state(sec):
    msg = JointState(name=['elevation'], velocity=[0.05], position=[0.0])
    msg.header.stamp = Time(sec=sec)
    return msg


def feedforwards_arrive(probe, js_pub, t_pub):
    """Publish a temperature and joint states (stamps 1, 2, ...) until feedforwards of them arrive."""
    sec = [0]

    def answered():
        sec[0] += 1
        temperature = Temperature(temperature=-20.0)
        temperature.header.stamp = Time(sec=sec[0])
        t_pub.publish(temperature)
        js_pub.publish(joint_state(sec[0]))
        probe.executor.spin_once(timeout_sec=0.1)
        return len([m for m in probe.received[FF] if math.isfinite(m.effort[0]) and m.effort[0] != 0.0]) >= 3

    probe.spin_until(answered, what='feedforwards of best-effort joint states')


def test_best_effort_joint_states_get_feedforwards(spawn, probe):
    """A driver publishing joint states with qos_profile_sensor_data (best effort) gets its feedforwards (it got
    none: the subscription was reliable-only), and /diagnostics says the subscription follows it."""
    probe.subscribe(JointState, FF)
    probe.subscribe(DiagnosticArray, '/diagnostics')
    node = start_feedforward(spawn)
    js_pub = probe.node.create_publisher(JointState, JS, qos_profile_sensor_data)
    t_pub = probe.node.create_publisher(Temperature, '/gimbal/temperature', qos_profile_sensor_data)
    feedforwards_arrive(probe, js_pub, t_pub)
    name = 'gimbal_friction/feedforward/elevation'
    probe.spin_until(lambda: (latest(probe, name) or (0, '', {}))[2].get(f'qos: {JS}')
                     == 'best_effort (follows the publishers)', what='the subscription following best effort')
    rc, out = node.stop()
    assert rc == 0 and 'Traceback' not in out, out


@pytest.mark.slow
def test_qos_overrides_from_a_parameter_file_and_inputs_that_cannot_deliver(spawn, probe, tmp_path):
    """A parameter file's qos_overrides are accepted and applied (the feedforward published best effort, the
    joint-state subscription fixed reliable); a best-effort joint-state publisher then cannot match it, and a
    publisher of another type on the reference velocity never delivers: /diagnostics warns naming each topic and
    cause, while the feedforward itself works."""
    overrides = tmp_path / 'qos.yaml'
    overrides.write_text('/**:\n  ros__parameters:\n    qos_overrides:\n'
                         f'      {JS}:\n        subscription:\n          reliability: reliable\n'
                         f'      {FF}:\n        publisher:\n          reliability: best_effort\n'
                         '          depth: 20\n')
    probe.subscribe(JointState, FF, qos_profile_sensor_data)
    probe.subscribe(DiagnosticArray, '/diagnostics')
    node = start_feedforward(spawn, '--params-file', str(overrides))
    probe.wait_publisher(FF)
    infos = probe.node.get_publishers_info_by_topic(FF)
    assert [i.qos_profile.reliability for i in infos] == [ReliabilityPolicy.BEST_EFFORT]
    name = 'gimbal_friction/feedforward/elevation'
    probe.spin_until(lambda: latest(probe, name) is not None, what='diagnostics')
    assert latest(probe, name)[2][f'qos: {JS}'] == 'reliable (fixed)'
    # a reliable driver works as before
    reliable = probe.node.create_publisher(JointState, JS, QoSProfile(depth=10))
    t_pub = probe.node.create_publisher(Temperature, '/gimbal/temperature', qos_profile_sensor_data)
    feedforwards_arrive(probe, reliable, t_pub)
    # a best-effort driver cannot match the reliable subscription the file asked for; a String on the reference
    probe.node.create_publisher(JointState, JS, qos_profile_sensor_data)
    probe.node.create_publisher(String, '/gimbal/reference_velocity', 10)

    def both_named():
        st = latest(probe, name)
        return st is not None and st[0] == WARN and 'reference_velocity: publisher /probe sends std_msgs/msg/String' \
            in st[1] and f'{JS}: publisher /probe (best_effort) cannot match this reliable subscription' in st[1]
    probe.spin_until(both_named, what='a WARN naming both topics and causes')
    assert 'Best effort publisher and reliable subscription' in latest(probe, name)[1]
    rc, out = node.stop()
    assert rc == 0 and 'Traceback' not in out, out


@pytest.mark.slow
def test_an_input_without_publisher_is_named(spawn, probe):
    """The estimator with joint states and temperatures but no motor-current publisher: after the input timeout
    its /diagnostics warns that /gimbal/motor_current has no publisher (it said OK)."""
    probe.subscribe(DiagnosticArray, '/diagnostics')
    probe.node.create_publisher(JointState, JS, 10)
    probe.node.create_publisher(Temperature, '/gimbal/temperature', 10)
    node = spawn('friction_estimator', '--ros-args', '--params-file', str(ROOT / 'config/gimbal_friction.yaml'))

    def named():
        st = latest(probe, 'gimbal_friction/estimator')
        return st is not None and st[0] == WARN and '/gimbal/motor_current: no publisher for' in st[1]
    probe.spin_until(named, what='a WARN naming /gimbal/motor_current')
    message = latest(probe, 'gimbal_friction/estimator')[1]
    assert f'{JS}: no publisher' not in message and '/gimbal/temperature: no publisher' not in message
    rc, out = node.stop()
    assert rc == 0 and 'Traceback' not in out, out


def test_an_override_the_nodes_cannot_take_is_refused_with_one_line(spawn):
    node = spawn('friction_feedforward', '--ros-args', '-p',
                 'qos_overrides./joint_states.subscription.durability:=transient_local')
    rc, out = node.wait()
    assert rc == 1 and 'Traceback' not in out, out
    assert 'qos_overrides./joint_states.subscription.durability' in out and 'not overridable' in out, out
