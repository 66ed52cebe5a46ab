"""friction_feedforward as its own process on an isolated domain: torque, sign, bad inputs, parameters."""

from __future__ import annotations

import itertools
import math
import time

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray

from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams

FF = '/gimbal/friction/feedforward'
CMD = '/gimbal/friction/feedforward_commands'
V_TH = FeedforwardSettings().velocity_threshold_rad_s
V_TEST = 2 * math.pi / 180  # 1/3 rpm in rad/s
RPM = 60 / (2 * math.pi)
pytestmark = pytest.mark.ros


def model_nm(t_c: float, v: float, params: AxisParams | None = None) -> float:
    """Expected feedforward from the pure model (direct, not the table)."""
    p = params or AxisParams()
    m = float(friction_torque(p, t_c, abs(v) * RPM).m_total_nmm) * 1e-3
    return math.tanh(v / V_TH) * m


def setup_probe(probe):
    probe.subscribe(JointState, FF)
    probe.subscribe(Float64MultiArray, CMD)
    probe.subscribe(DiagnosticArray, '/diagnostics')
    probe.publisher(Temperature, '/gimbal/temperature')
    probe.publisher(JointState, '/joint_states')


def send_temperature(probe, t_c, sec=0):
    """A temperature stamped ``sec`` (the stamp the next joint states carry: freshness compares stamps)."""
    msg = Temperature(temperature=float(t_c))
    msg.header.stamp = Time(sec=sec)
    probe.pubs['/gimbal/temperature'].publish(msg)


def send_joint(probe, names, velocities, sec=1, nanosec=0):
    msg = JointState(name=list(names), velocity=[float(v) for v in velocities],
                     position=[0.0] * len(names))
    msg.header.stamp = Time(sec=sec, nanosec=nanosec)
    probe.pubs['/joint_states'].publish(msg)
    return msg


def request(probe, names, velocities, sec):
    """Publish a joint state and wait for the feedforward carrying its stamp. The joint state is sent again (same
    stamp) if no answer came within a second: right after start-up the node's feedforward writer may not have matched
    the probe's reader yet, although the probe already sees the writer (discovery is not symmetric in time), and a
    volatile reliable writer does not resend to a reader that matched late."""
    n0 = len(probe.received[FF])
    sent = [0.0]

    def answered() -> bool:
        if time.monotonic() - sent[0] > 1.0:
            send_joint(probe, names, velocities, sec=sec)
            sent[0] = time.monotonic()
        return any(m.header.stamp.sec == sec for m in probe.received[FF][n0:])

    probe.spin_until(answered, what=f'feedforward for stamp {sec}')
    return [m for m in probe.received[FF][n0:] if m.header.stamp.sec == sec][-1]


def wait_temperature_used(probe, t_c, sec_start):
    """Re-send the temperature until a feedforward reflects it (the first sample may be lost to discovery)."""
    expected = model_nm(t_c, V_TEST)
    sec = [sec_start]

    def ok():
        send_temperature(probe, t_c, sec[0] + 1)
        probe.executor.spin_once(timeout_sec=0.05)
        sec[0] += 1
        msg = request(probe, ['elevation'], [V_TEST], sec[0])
        return abs(msg.effort[0] - expected) < 1e-3 * abs(expected)

    probe.spin_until(ok, what=f'temperature {t_c} in use')
    return sec[0]


def start_node(spawn, *extra):
    return spawn('friction_feedforward', '--ros-args', '--params-file', 'config/gimbal_friction.yaml', *extra)


@pytest.fixture
def node_and_probe(spawn, probe, monkeypatch):
    monkeypatch.chdir(__import__('pathlib').Path(__file__).resolve().parents[2])
    setup_probe(probe)
    node = start_node(spawn, '-p', 'temperature_timeout_s:=30.0')
    probe.wait_matched('/joint_states')
    probe.wait_matched('/gimbal/temperature')
    probe.wait_publisher(FF)
    return node, probe


def test_torque_sign_and_smooth_zero_crossing(node_and_probe):
    node, probe = node_and_probe
    sec = wait_temperature_used(probe, -40.0, 100)
    pos = request(probe, ['elevation'], [V_TEST], sec + 1)
    neg = request(probe, ['elevation'], [-V_TEST], sec + 2)
    assert pos.effort[0] == pytest.approx(model_nm(-40.0, V_TEST), rel=1e-4)
    assert pos.effort[0] == pytest.approx(3.143e-3, rel=2e-3)  # the paper's M(-40 degC) in N*m
    assert neg.effort[0] == pytest.approx(-pos.effort[0], rel=1e-9)
    # smooth through zero: odd, monotonic, 0 at rest, tanh(1) of the torque at v_th
    vs = [-3 * V_TH, -V_TH, -0.2 * V_TH, 0.0, 0.2 * V_TH, V_TH, 3 * V_TH]
    out = [request(probe, ['elevation'], [v], sec + 10 + i).effort[0] for i, v in enumerate(vs)]
    assert out[3] == 0.0
    assert all(b > a for a, b in itertools.pairwise(out))
    for v, tau in zip(vs, out):
        assert tau == pytest.approx(model_nm(-40.0, v), rel=1e-4, abs=1e-12)
    assert abs(out[4]) < 0.25 * abs(out[6])
    # the stamp is the joint-state stamp; commands in configured joint order
    assert pos.header.stamp.sec == sec + 1 and list(pos.name) == ['elevation']
    probe.spin_until(lambda: len(probe.received[CMD]) >= 3, what='commands')
    assert len(probe.received[CMD][-1].data) == 1
    # a warmer bearing gives less friction
    sec2 = wait_temperature_used(probe, 20.0, sec + 40)
    warm = request(probe, ['elevation'], [V_TEST], sec2 + 1)
    assert warm.effort[0] == pytest.approx(model_nm(20.0, V_TEST), rel=1e-4)
    assert node.alive()
    rc, out_text = node.stop()
    assert rc == 0, out_text
    assert 'Traceback' not in out_text


def _diag_values(probe, key_contains):
    for arr in reversed(probe.received['/diagnostics']):
        for st in arr.status:
            for kv in st.values:
                if key_contains in kv.key:
                    return st, kv
    return None


@pytest.mark.slow
def test_bad_inputs_never_reach_the_output(node_and_probe):
    node, probe = node_and_probe
    sec = wait_temperature_used(probe, 0.0, 200)
    good = model_nm(0.0, V_TEST)
    for bad in (math.nan, math.inf, 500.0, -300.0):
        send_temperature(probe, bad)
    after = request(probe, ['elevation'], [V_TEST], sec + 1)
    assert after.effort[0] == pytest.approx(good, rel=1e-4)  # last valid temperature kept
    # mismatched arrays: no output for that message; unknown names ignored; NaN velocity: the joint is not
    # used (no output for a message with nothing else); never NaN
    n0 = len(probe.received[FF])
    bad = JointState(name=['elevation', 'azimuth'], velocity=[V_TEST])
    bad.header.stamp = Time(sec=sec + 2)
    probe.pubs['/joint_states'].publish(bad)
    mixed = request(probe, ['bogus', 'elevation'], [1.0, -V_TEST], sec + 3)
    assert list(mixed.name) == ['elevation'] and mixed.effort[0] == pytest.approx(-good, rel=1e-4)
    send_joint(probe, ['elevation'], [math.nan], sec=sec + 4)
    request(probe, ['elevation'], [V_TEST], sec + 5)                  # the node is alive and answers
    assert not any(m.header.stamp.sec in (sec + 2, sec + 4) for m in probe.received[FF][n0:])
    for m in probe.received[FF]:
        assert all(math.isfinite(e) for e in m.effort)
    for m in probe.received[CMD]:
        assert all(math.isfinite(e) for e in m.data)
    # diagnostics say why (published at 1 Hz)
    probe.spin_until(lambda: _diag_values(probe, 'rejected_temperature: non-finite') is not None
                     and _diag_values(probe, 'length mismatch') is not None
                     and _diag_values(probe, 'non-finite velocity') is not None, what='diagnostics of rejections')
    st, kv = _diag_values(probe, 'rejected_temperature: non-finite')
    assert int(kv.value) >= 2 and st.level != b'\x00'
    assert _diag_values(probe, 'rejected_temperature: temperature out of range') is not None
    assert node.alive()
    assert node.stop()[0] == 0


def _set(probe, name, value):
    client = probe.node.create_client(SetParameters, '/friction_feedforward/set_parameters')
    probe.spin_until(client.service_is_ready, what='set_parameters service')
    if isinstance(value, float):
        pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
    else:
        pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    future = client.call_async(SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)]))
    probe.spin_until(future.done, what=f'set {name}')
    return future.result().results[0]


@pytest.mark.slow
def test_runtime_parameter_change_and_refusal(node_and_probe):
    node, probe = node_and_probe
    sec = wait_temperature_used(probe, -40.0, 300)
    before = request(probe, ['elevation'], [V_TEST], sec + 1).effort[0]
    refused = _set(probe, 'model.ball_diameter_mm', -1.0)
    assert not refused.successful and 'ball_diameter_mm' in refused.reason and '> 0' in refused.reason
    refused2 = _set(probe, 'stale_policy', 'panic')
    assert not refused2.successful and 'stale_policy' in refused2.reason
    same = request(probe, ['elevation'], [V_TEST], sec + 2).effort[0]
    assert same == pytest.approx(before, rel=1e-12)
    ok = _set(probe, 'model.palmgren_factor', 3.0)
    assert ok.successful, ok.reason
    changed = request(probe, ['elevation'], [V_TEST], sec + 3).effort[0]
    assert changed == pytest.approx(model_nm(-40.0, V_TEST, AxisParams(palmgren_factor=3.0)), rel=1e-4)
    assert changed > before
    ok2 = _set(probe, 'axis.elevation.scale_positive', 0.5)
    assert ok2.successful, ok2.reason
    half = request(probe, ['elevation'], [V_TEST], sec + 4).effort[0]
    assert half == pytest.approx(0.5 * changed, rel=1e-9)
    neg = request(probe, ['elevation'], [-V_TEST], sec + 5).effort[0]
    assert neg == pytest.approx(-changed, rel=1e-9)  # scale_negative untouched
    assert node.stop()[0] == 0


@pytest.mark.slow
def test_stale_temperature_policy(spawn, probe, monkeypatch):
    monkeypatch.chdir(__import__('pathlib').Path(__file__).resolve().parents[2])
    setup_probe(probe)
    node = start_node(spawn, '-p', 'temperature_timeout_s:=1.5', '-p', 'stale_policy:=zero')
    probe.wait_matched('/joint_states')
    probe.wait_publisher(FF)
    # never any temperature: zero policy publishes 0 N*m (not NaN, not a guess)
    first = request(probe, ['elevation'], [V_TEST], 1)
    assert first.effort[0] == 0.0
    probe.spin_until(lambda: _diag_values(probe, 'temperature_source') is not None, what='diagnostics')
    st, kv = _diag_values(probe, 'temperature_source')
    assert kv.value == 'zero' and st.level == b'\x02'
    assert node.stop()[0] == 0


@pytest.mark.slow
def test_bad_parameter_file_exits_with_one_line(spawn, tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    model:\n      ball_diameter_mm: -2.0\n')
    node = spawn('friction_feedforward', '--ros-args', '--params-file', str(bad))
    node.proc.wait(30)
    rc, out = node.stop()
    assert rc == 1
    lines = [line for line in out.splitlines() if 'friction_feedforward: error' in line]
    assert len(lines) == 1 and 'model.ball_diameter_mm' in lines[0] and 'Traceback' not in out


@pytest.mark.slow
def test_refitted_parameter_file_changes_the_output(spawn, probe, tmp_path, monkeypatch):
    """A refit output (values under axis.<joint>) layered as a second --params-file changes the feedforward."""
    from gimbal_friction.config.loader import render_parameter_file
    monkeypatch.chdir(__import__('pathlib').Path(__file__).resolve().parents[2])
    refit = tmp_path / 'refit.yaml'
    refit.write_text(render_parameter_file(axes_overrides={'elevation': {'walther_a': 8.6345,
                                                                          'palmgren_factor': 2.0}}))
    setup_probe(probe)
    node = start_node(spawn, '--params-file', str(refit), '-p', 'temperature_timeout_s:=30.0')
    probe.wait_matched('/joint_states')
    probe.wait_matched('/gimbal/temperature')
    probe.wait_publisher(FF)
    refitted = AxisParams(walther_a=8.6345, palmgren_factor=2.0)
    expected_cold = model_nm(-40.0, V_TEST, refitted)

    def cold_in_use(sec=[500]):  # noqa: B006 - a counter across calls
        send_temperature(probe, -40.0, sec[0] + 1)
        probe.executor.spin_once(timeout_sec=0.05)
        sec[0] += 1
        return request(probe, ['elevation'], [V_TEST], sec[0]).effort[0] == pytest.approx(expected_cold, rel=1e-4)

    probe.spin_until(cold_in_use, what='refitted model in use')
    assert expected_cold > 1.2 * model_nm(-40.0, V_TEST)  # more viscous lubricant: more cold friction
    assert node.stop()[0] == 0


@pytest.mark.slow
def test_chamber_replay_refuses_a_bag_without_the_contract_topics(spawn, tmp_path):
    from gimbal_friction.recording.bag_write import make_temperature, write_chamber_bag
    bag = write_chamber_bag(tmp_path / 'bag', [('/gimbal/temperature', 'sensor_msgs/msg/Temperature', 1,
                                                make_temperature(1, 20.0))])
    node = spawn('chamber_replay', '--ros-args', '-p', f'bag:={bag}')
    node.proc.wait(30)
    rc, out = node.stop()
    assert rc == 1 and '/joint_states' in out and 'Traceback' not in out


def test_output_bytes_deserialize_to_the_messages_the_node_publishes():
    """The node publishes its outputs as CDR bytes packed into the encoder's templates: a subscriber reads the very
    JointState / Float64MultiArray the message objects would have carried, for any stamp, frame_id and names (also
    past the layouts it keeps)."""
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import MultiArrayDimension

    from gimbal_friction.nodes.feedforward import OutputBytes
    out = OutputBytes(3)
    out.MAX_LAYOUTS = 2
    cases = [(['elevation'], [1.5e-3], 7, 250, ''), (['elevation', 'azimuth'], [-2e-3, 0.0], -3, 999_999_999, 'b'),
             (['élévation'], [0.02], 2**31 - 1, 0, 'gimbal/ü'), (['elevation'], [-1e-3], 0, 1, '')]
    for names, torques, sec, nanosec, frame_id in cases * 2:
        want = JointState(name=names, effort=torques)
        want.header.stamp = Time(sec=sec, nanosec=nanosec)
        want.header.frame_id = frame_id
        assert deserialize_message(out.feedforward(want.header, names, torques), JointState) == want
    cmd = Float64MultiArray(data=[1e-3, 0.0, -2.5e-3])
    cmd.layout.dim = [MultiArrayDimension(label='joints', size=3, stride=3)]
    assert deserialize_message(out.commands([1e-3, 0.0, -2.5e-3]), Float64MultiArray) == cmd
