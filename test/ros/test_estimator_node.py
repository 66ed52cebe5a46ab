"""friction_estimator as its own process on an isolated domain: Eq. 23 in steady state, rejections, live == offline."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState, Temperature

from gimbal_friction.chamber import synth
from gimbal_friction.estimation.estimator import EstimatorLogic, EstimatorSettings
from gimbal_friction.physics.params import AxisParams

ROOT = Path(__file__).resolve().parents[2]
MEAS = '/gimbal/friction/measured'
STATS = '/gimbal/friction/statistics'
JS, CUR, TEMP = '/joint_states', '/gimbal/motor_current', '/gimbal/temperature'
EL = 'elevation'
V = 2 * math.pi / 180          # commanded 1/3 rpm [rad/s]
KT, I0 = 0.05, 0.01
NS = 1_000_000_000
MS = 1_000_000
pytestmark = pytest.mark.ros


# ------------------------------------------------------------------------------------------------ helpers
class Link:
    """Probe publishers with deep reliable history, a deep measured subscription, and paced sending."""

    def __init__(self, probe):
        self.probe = probe
        node = probe.node
        self.measured: list[JointState] = []
        self.sub = node.create_subscription(JointState, MEAS, self.measured.append, QoSProfile(depth=5000))
        probe.subscribe(DiagnosticArray, '/diagnostics')
        probe.subscribe(DiagnosticArray, STATS)
        for topic, typ in ((JS, JointState), (CUR, JointState), (TEMP, Temperature)):
            probe.pubs[topic] = node.create_publisher(typ, topic, QoSProfile(depth=5000))
        self.sent = 0

    def wait_ready(self):
        for topic in (JS, CUR, TEMP):
            self.probe.wait_matched(topic)
        self.probe.spin_until(lambda: self.sub.get_publisher_count() > 0, what='the measured publisher')

    def send(self, topic, msg):
        self.probe.pubs[topic].publish(msg)
        self.sent += 1
        self.probe.executor.spin_once(timeout_sec=0.0)
        time.sleep(0.0008)   # pace: well below what the node takes, so reliable keep-last never drops


def stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), NS)
    return Time(sec=sec, nanosec=nanosec)


def joint_state(t_ns, names, positions, velocities):
    msg = JointState(name=list(names), position=[float(x) for x in positions],
                     velocity=[float(x) for x in velocities])
    msg.header.stamp = stamp(t_ns)
    return msg


def current(t_ns, names, currents):
    msg = JointState(name=list(names), effort=[float(x) for x in currents])
    msg.header.stamp = stamp(t_ns)
    return msg


def latest_status(probe, name, topic='/diagnostics'):
    for arr in reversed(probe.received[topic]):
        for st in arr.status:
            if st.name == name:
                return st, {kv.key: kv.value for kv in st.values}
    return None, {}


def start_node(spawn, monkeypatch, *extra):
    monkeypatch.chdir(ROOT)
    return spawn('friction_estimator', '--ros-args', '--params-file', 'config/gimbal_friction.yaml',
                 '-p', 'diagnostics_period_s:=0.2', '-p', 'statistics_period_s:=0.3', *extra)


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


def wait_temperature(link, value, stamp_ns=0):
    """Send the temperature (stamped ``stamp_ns``) until the node reports it (the sensor-data subscription is best
    effort)."""
    def seen():
        msg = Temperature(temperature=float(value))
        msg.header.stamp = stamp(stamp_ns)
        link.send(TEMP, msg)
        _, values = latest_status(link.probe, 'gimbal_friction/estimator')
        return values.get('temperature_c') == f'{value:.6g}'
    link.probe.spin_until(seen, what=f'temperature {value} in use')


# ------------------------------------------------------------------------------------------------ sweep
def sweep_plan():
    """A constant-speed sweep forward (-5.5 -> +11 deg) and back (+11 -> -6 deg) at 25 Hz, with an acceleration
    wobble and bad inputs in the steady part. Returns (messages, expected accepted {stamp: friction}, expected
    rejection counts), derived here from the rules, independently of the estimator code."""
    dt = 40 * MS
    lo, hi = math.radians(-5.0), math.radians(10.0)
    t0 = 1000 * NS
    messages = []
    accepted: dict[int, tuple[float, float, int]] = {}
    counts = {'outside position window': 0, 'dwell': 0, 'acceleration': 0, 'non-finite': 0,
              'over current rating': 0, 'non-finite joint state': 0, 'unpaired': 0}
    unknown = 0
    passes = [(+1, math.radians(-5.5), 207, t0), (-1, math.radians(11.0), 213, t0 + 10 * NS)]
    last = (passes[-1][0], passes[-1][2] - 1)    # the very last current: no later joint state decides it
    offsets = (0, 2 * MS, -3 * MS, 4 * MS)
    for direction, start, n, tp in passes:
        wobble = {90, 140} if direction > 0 else {100}
        nan_current, over_current, nan_js = (70, 120, 160) if direction > 0 else (60, 80, 150)
        for k in range(n):
            t = tp + k * dt
            pos = start + direction * V * k * dt * 1e-9
            v = direction * V * (1.05 if k in wobble else 1.0)
            js_pos = math.nan if k == nan_js else pos
            tau = 2e-3 * (1.0 + 0.1 * math.sin(k / 7.0))          # distinct friction per sample [N*m]
            amps = direction * (tau / KT + I0)
            if k == nan_current:
                amps = math.nan
            elif k == over_current:
                amps = 3.0 * direction
            c_t = t + offsets[k % len(offsets)]
            js_msg = joint_state(t, [EL], [js_pos], [v])
            cur_msg = current(c_t, [EL], [amps])
            # alternate which of the pair goes first (pairing must not care)
            messages.extend([(JS, js_msg), (CUR, cur_msg)] if k % 2 else [(CUR, cur_msg), (JS, js_msg)])
            if k == 100:
                messages.append((CUR, current(t, ['bogus'], [0.1])))
                messages.append((JS, joint_state(t + 1, ['bogus'], [0.0], [V])))
                unknown += 2
            # expected verdict of this sample
            if (direction, k) == last:
                continue
            if k == nan_js:
                counts['non-finite joint state'] += 1
                counts['unpaired'] += 1      # its current finds no joint state within 5 ms
                continue
            if k == nan_current:
                counts['non-finite'] += 1
                continue
            if k == over_current:
                counts['over current rating'] += 1
                continue
            if not lo <= pos <= hi:
                counts['outside position window'] += 1
            elif k in wobble or (k - 2) in wobble:
                # the least-squares slope over the last three joint states (80 ms): 5 % of V in 80 ms
                # = 0.022 rad/s^2 > 0.02 in the windows ending at the wobble and two samples later
                counts['acceleration'] += 1
            elif k * dt < 500 * MS:                     # within 0.5 s of the start of the pass
                counts['dwell'] += 1
            else:
                accepted[t] = (pos, KT * (amps - direction * I0), direction)
    return messages, accepted, counts, unknown


@pytest.mark.slow
def test_constant_speed_sweep_gives_eq23_friction_and_rejects_the_rest(spawn, probe, monkeypatch):
    # the packaged config sets K_T and I_0 per axis (axis.elevation.*), which override model.*
    node = start_node(spawn, monkeypatch, '-p', f'axis.elevation.no_load_current_a:={I0}',
                      '-p', 'max_accel_rad_s2:=0.02', '-p', 'temperature_timeout_s:=600.0')
    link = Link(probe)
    link.wait_ready()
    wait_temperature(link, 20.0, 1000 * NS)      # stamped at the start of the sweep (fresh for 600 s)
    messages, accepted, counts, unknown = sweep_plan()
    assert len(accepted) > 250 and all(counts.values())
    for topic, msg in messages:
        link.send(topic, msg)
    # a temperature stamped after the sweep: the last samples stop waiting for the one at their stamp (20 degC)
    wait_temperature(link, 20.1, 1100 * NS)
    probe.spin_until(lambda: len(link.measured) >= len(accepted), what=f'{len(accepted)} measured samples')

    # every published sample is an expected one, with Eq. 23 friction, signed like the motion, never NaN
    got = {stamp_ns(m): m for m in link.measured}
    assert len(got) == len(link.measured) == len(accepted)
    assert set(got) == set(accepted)
    for t, m in got.items():
        pos, friction, direction = accepted[t]
        assert list(m.name) == [EL]
        assert m.effort[0] == pytest.approx(friction, rel=1e-12, abs=1e-18)
        assert math.copysign(1.0, m.effort[0]) == direction == math.copysign(1.0, m.velocity[0])
        assert m.position[0] == pytest.approx(pos, abs=1e-15)
        assert all(math.isfinite(x) for x in (*m.position, *m.velocity, *m.effort))
    assert {d for _, _, d in accepted.values()} == {1, -1}

    # rejections counted by reason on /diagnostics
    name = f'gimbal_friction/estimator/{EL}'

    def diag_complete():
        _, values = latest_status(probe, name)
        return values.get('accepted') == str(len(accepted)) and \
            all(values.get(f'rejected: {r}') == str(c) for r, c in counts.items())

    try:
        probe.spin_until(diag_complete, what='diagnostics with every count')
    except AssertionError:
        raise AssertionError(f'expected {counts}, got {latest_status(probe, name)[1]}') from None
    _st, values = latest_status(probe, name)
    # bad inputs were rejected: WARN naming them while they came; OK again once they stopped
    warned = [s for arr in probe.received['/diagnostics'] for s in arr.status
              if s.name == name and s.level == b'\x01' and 'bad inputs rejected' in s.message]
    assert warned and any('over current rating' in s.message for s in warned)
    probe.spin_until(lambda: latest_status(probe, name)[0].level == b'\x00', what='back to OK')
    assert float(values['torque_constant_nm_per_a']) == KT and float(values['no_load_current_a']) == I0
    assert float(values['last_friction_nm']) == pytest.approx(accepted[max(accepted)][1], rel=1e-5)
    probe.spin_until(lambda: latest_status(probe, 'gimbal_friction/estimator')[1].get('rejected: unknown joint')
                     == str(unknown), what='unknown joints counted')

    # statistics summary: one status per direction at the 20 degC plateau
    def stats_complete():
        arr = probe.received[STATS][-1] if probe.received[STATS] else None
        return arr is not None and sum(int({kv.key: kv.value for kv in s.values}['count']) for s in arr.status) \
            == len(accepted)

    probe.spin_until(stats_complete, what='statistics of every sample')
    records = [{kv.key: kv.value for kv in s.values} for s in probe.received[STATS][-1].status]
    assert [(r['direction'], r['plateau_c']) for r in records] == [('-1', '20.0'), ('+1', '20.0')]
    for r in records:
        d = int(r['direction'])
        f = np.array([fr for _, fr, dd in accepted.values() if dd == d])
        assert int(r['count']) == f.size
        assert float(r['mean_nm']) == pytest.approx(f.mean(), rel=1e-12)
        assert float(r['std_nm']) == pytest.approx(f.std(ddof=1), rel=1e-9)
        assert float(r['ripple_nm']) > 0.0

    # runtime parameters: refused with the reason, accepted when valid
    client = probe.node.create_client(SetParameters, '/friction_estimator/set_parameters')
    probe.spin_until(client.service_is_ready, what='set_parameters service')

    def set_param(pname, value):
        pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        future = client.call_async(SetParameters.Request(parameters=[ParameterMsg(name=pname, value=pv)]))
        probe.spin_until(future.done, what=f'set {pname}')
        return future.result().results[0]

    refused = set_param('speed_tolerance', 1.5)
    assert not refused.successful and 'speed_tolerance' in refused.reason and '(0, 1)' in refused.reason
    ok = set_param('axis.elevation.torque_constant_nm_per_a', 0.08)
    assert ok.successful, ok.reason
    probe.spin_until(lambda: latest_status(probe, name)[1].get('torque_constant_nm_per_a') == '0.08',
                     what='new K_T in diagnostics')
    assert node.alive()
    rc, out = node.stop()
    assert rc == 0, out
    assert 'Traceback' not in out


# ------------------------------------------------------------------------------------------------ live == offline
@pytest.mark.slow
def test_live_node_matches_the_offline_logic(spawn, probe, monkeypatch):
    cfg = synth.SynthConfig(plateaus_c=(-40.0,), hold_s=12.0, joint_rate_hz=25.0, temperature_rate_hz=2.0,
                            no_load_current_a=0.004, seed=11)
    data = synth.generate(cfg)
    axes = {EL: AxisParams(no_load_current_a=0.004)}
    settings = EstimatorSettings()
    # the message sequence in log-time order, as rclpy messages, and the same sequence into the offline logic
    logic = EstimatorLogic(axes, settings)
    offline = []
    sequence = []
    _, streams, indices = synth.message_order(data)
    for k, i in zip(streams.tolist(), indices.tolist()):
        if k == 0:
            t_c = float(data.temperature_c[i])
            msg = Temperature(temperature=t_c)
            msg.header.stamp = stamp(int(data.temperature_stamp_ns[i]))
            sequence.append((TEMP, msg))
            offline.extend(logic.on_temperature(t_c, int(data.temperature_stamp_ns[i])))   # releases samples
        elif k == 1:
            t = int(data.joint_stamp_ns[i])
            p, v = float(data.position_rad[i, 0]), float(data.velocity_rad_s[i, 0])
            sequence.append((JS, joint_state(t, [EL], [p], [v])))
            offline.extend(logic.on_joint_state(t, [EL], [p], [v]))
        else:
            t = int(data.current_stamp_ns[i])
            c = float(data.current_a[i, 0])
            sequence.append((CUR, current(t, [EL], [c])))
            offline.extend(logic.on_current(t, [EL], [c]))
    offline.extend(logic.flush().records())   # the node's input ends too: it releases the waiting samples
    assert len(offline) > 150 and {m.direction for m in offline} == {1, -1}

    node = start_node(spawn, monkeypatch, '-p', 'axis.elevation.no_load_current_a:=0.004')
    link = Link(probe)
    link.wait_ready()
    for topic, msg in sequence:
        link.send(topic, msg)
    probe.spin_until(lambda: len(link.measured) >= len(offline), what=f'{len(offline)} measured samples')
    live = [(stamp_ns(m), m.name[0], m.position[0], m.velocity[0], m.effort[0]) for m in link.measured]
    expected = [(m.stamp_ns, m.joint, m.position_rad, m.velocity_rad_s, m.friction_nm) for m in offline]
    assert sorted(live) == sorted(expected)          # bit-identical values (float64 end to end)

    name = f'gimbal_friction/estimator/{EL}'
    want = {f'rejected: {r}': str(c) for r, c in logic.counters.rejected[EL].items()}
    want['accepted'] = str(logic.counters.accepted[EL])

    def same_counts():
        _, values = latest_status(probe, name)
        return all(values.get(k) == v for k, v in want.items())

    probe.spin_until(same_counts, what=f'the offline counters {want}')
    # the statistics summary carries the offline statistics
    total = sum(r['count'] for r in logic.statistics())

    def stats_complete():
        arr = probe.received[STATS][-1] if probe.received[STATS] else None
        return arr is not None and sum(int({kv.key: kv.value for kv in s.values}['count']) for s in arr.status) \
            == total

    probe.spin_until(stats_complete, what='statistics of every sample')
    live_stats = {(r['direction'], r['plateau_c']): r for r in
                  ({kv.key: kv.value for kv in s.values} for s in probe.received[STATS][-1].status)}
    for rec in logic.statistics():
        key = ('+1' if rec['direction'] > 0 else '-1', 'unknown' if rec['plateau_c'] is None
               else repr(rec['plateau_c']))
        if key in live_stats:   # a best-effort temperature sample could in principle move a sample's plateau
            assert float(live_stats[key]['mean_nm']) == pytest.approx(rec['mean_nm'], rel=1e-12), \
                (key, live_stats, logic.statistics())
    assert node.stop()[0] == 0
