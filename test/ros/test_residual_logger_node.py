"""residual_logger as its own process: pairing, close-and-reopen, SIGKILL-and-read, rotation, bad folder."""

from __future__ import annotations

import math
import signal
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from gimbal_friction.recording import topics
from gimbal_friction.recording.bag import default_typestore
from gimbal_friction.recording.residual_read import read_residual_rows
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS

pytestmark = pytest.mark.ros
V = 2 * math.pi / 180


def _setup(probe):
    for topic, kind in ((topics.TEMPERATURE, Temperature), (topics.JOINT_STATES, JointState),
                        (topics.MOTOR_CURRENT, JointState), (topics.FEEDFORWARD, JointState),
                        (topics.MEASURED, JointState), (topics.MEASURED_DETAIL, Float64MultiArray)):
        probe.publisher(kind, topic)
    probe.subscribe(DiagnosticArray, '/diagnostics')


def _js(sec: int, nanosec: int, effort: float, velocity: float = V) -> JointState:
    msg = JointState(name=['elevation'], position=[0.01], velocity=[velocity], effort=[effort])
    msg.header.stamp = Time(sec=sec, nanosec=nanosec)
    return msg


def _detail(sec: int, friction: float, velocity: float, current: float, temperature: float) -> Float64MultiArray:
    """A measured_detail message as friction_estimator publishes it (MEASUREMENT_FIELDS)."""
    values = {'stamp_sec': sec, 'stamp_nanosec': 0, 'position_rad': 0.01, 'velocity_rad_s': velocity,
              'acceleration_rad_s2': 0.0, 'current_a': current, 'temperature_c': temperature, 'temperature_fresh': 1,
              'friction_nm': friction, 'torque_constant_nm_per_a': 0.05, 'no_load_current_a': 0.002,
              'inertia_kg_m2': 0.0, 'method': 0}
    n = len(MEASUREMENT_FIELDS)
    msg = Float64MultiArray(data=[float(values[f]) for f in MEASUREMENT_FIELDS])
    msg.layout.dim = [MultiArrayDimension(label='elevation', size=n, stride=n)]
    return msg


def _diag(probe, key):
    for arr in reversed(probe.received['/diagnostics']):
        for st in arr.status:
            if st.name == 'gimbal_friction/residual_logger':
                for kv in st.values:
                    if kv.key == key:
                        return st, kv.value
    return None, None


def _start(spawn, folder: Path, *extra: str):
    return spawn('residual_logger', '--ros-args', '-p', f'output_dir:={folder}', '-p', 'flush_period_s:=0.2',
                 '-p', 'diagnostics_period_s:=0.2', *extra)


def _wait_ready(probe):
    for topic in (topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT, topics.FEEDFORWARD,
                  topics.MEASURED, topics.MEASURED_DETAIL):
        probe.wait_matched(topic)


def _send_pairs(probe, n: int, start: int = 0, temperature: float = -40.0):
    """n measured samples with their feedforward (same stamps); returns expected (pred, meas, current) per
    stamp."""
    probe.pubs[topics.TEMPERATURE].publish(Temperature(temperature=temperature))
    expected = {}
    for i in range(start, start + n):
        pred = 3.1e-3 * (1 if i % 2 == 0 else -1)
        meas = pred * 1.05
        v = V if i % 2 == 0 else -V
        probe.pubs[topics.JOINT_STATES].publish(_js(10 + i, 0, 0.0, v))
        probe.pubs[topics.FEEDFORWARD].publish(_js(10 + i, 0, pred, v))
        probe.pubs[topics.MEASURED].publish(_js(10 + i, 0, meas, v))
        current = 0.01 * i
        probe.pubs[topics.MEASURED_DETAIL].publish(_detail(10 + i, meas, v, current, temperature))
        expected[(10 + i) * 1_000_000_000] = (pred, meas, current)
        probe.executor.spin_once(timeout_sec=0.002)
    return expected


@pytest.mark.slow
def test_pairs_and_closes_a_readable_log(spawn, probe, tmp_path):
    _setup(probe)
    folder = tmp_path / 'res'
    node = _start(spawn, folder)
    _wait_ready(probe)
    # the temperature must reach the logger before the samples use it: wait until it is logged
    def logged():  # re-send: the first samples after discovery can be lost (best-effort subscription)
        probe.pubs[topics.TEMPERATURE].publish(Temperature(temperature=-40.0))
        probe.executor.spin_once(timeout_sec=0.1)
        return (_diag(probe, 'messages_logged')[1] or '0') != '0'
    probe.spin_until(logged, what='first message logged')
    expected = _send_pairs(probe, 40)
    probe.spin_until(lambda: int(_diag(probe, 'residuals_logged')[1] or 0) >= 40, what='40 residuals logged')
    rc, out = node.stop()
    assert rc == 0, out
    assert (folder / 'metadata.yaml').exists()
    d, log = read_residual_rows([folder])
    assert len(d) == 40 and not log.truncated_files
    for k in range(len(d)):
        pred, meas, current = expected[round(d.stamp_s[k] * 1e9)]
        assert d.predicted_nm[k] == pytest.approx(pred) and d.measured_nm[k] == pytest.approx(meas)
        assert d.residual_nm[k] == pytest.approx(meas - pred)
        assert d.temperature_c[k] == -40.0
        assert d.current_a[k] == current   # what the estimator measured, not reconstructed
        assert (d.torque_constant_nm_per_a[k], d.no_load_current_a[k], d.method[k]) == (0.05, 0.002, 0)
    assert log.topic_counts[topics.RESIDUAL] == 40 and log.topic_counts[topics.MEASURED] == 40
    assert log.topic_counts[topics.MEASURED_DETAIL] == 40
    assert log.topic_counts[topics.FEEDFORWARD] == 40 and log.topic_counts[topics.TEMPERATURE] >= 2
    # standard tools open the closed folder (rosbag2 metadata.yaml + MCAP)
    with AnyReader([folder], default_typestore=default_typestore()) as reader:
        conns = {c.topic: c.msgtype for c in reader.connections}
        assert conns[topics.RESIDUAL] == 'sensor_msgs/msg/JointState'
        assert conns[topics.RESIDUAL_DETAIL] == 'std_msgs/msg/Float64MultiArray'
        assert sum(1 for _ in reader.messages()) == sum(log.topic_counts.values())
    # re-open: a second run into the same folder does not overwrite the first log
    node2 = _start(spawn, folder)
    _wait_ready(probe)
    rc2, out2 = node2.stop()
    assert rc2 == 0, out2
    assert len(read_residual_rows([folder])[0]) == 40
    assert not [p for p in folder.iterdir() if p.is_dir()]  # not nested inside the first log
    siblings = [p for p in folder.parent.iterdir() if p.name.startswith(f'{folder.name}_')]
    assert len(siblings) == 1 and (siblings[0] / 'metadata.yaml').exists()


@pytest.mark.slow
def test_two_loggers_on_one_folder_each_write_their_own_sibling_log(spawn, probe, tmp_path):
    """Started at once with the same output_dir, two loggers write two separate logs side by side, each named in
    its log line; neither log is inside the other, and each closes cleanly."""
    folder = tmp_path / 'shared'
    nodes = [_start(spawn, folder), _start(spawn, folder)]

    def folders():
        out = []
        for node in nodes:
            lines = [x for x in node.output().splitlines() if 'residual log: ' in x]
            out.append(lines[0].split('residual log: ', 1)[1].split(' (')[0] if lines else None)
        return out

    probe.spin_until(lambda: None not in folders(), what='both loggers opened their log')
    first, second = (Path(f) for f in folders())
    assert first != second and first.parent == second.parent == tmp_path
    assert folder in (first, second)
    other = second if first == folder else first
    assert other.name.startswith('shared_')  # shared_<UTC yyyymmdd_HHMMSS>, beside the first
    for node in nodes:
        rc, out = node.stop()
        assert rc == 0, out
    for f in (first, second):
        assert (f / 'metadata.yaml').exists() and not [p for p in f.iterdir() if p.is_dir()]


@pytest.mark.slow
def test_sigkill_leaves_readable_chunks_and_rotation(spawn, probe, tmp_path):
    _setup(probe)
    folder = tmp_path / 'killed'
    node = _start(spawn, folder, '-p', 'max_file_mb:=0.004', '-p', 'chunk_kib:=2')
    _wait_ready(probe)
    _send_pairs(probe, 300)
    probe.spin_until(lambda: int(_diag(probe, 'residuals_logged')[1] or 0) >= 270, what='270 residuals logged')
    probe.spin_until(lambda: int(_diag(probe, 'files')[1] or 0) >= 3, what='rotation to several files')
    # wait until flushes have caught up: the reported bytes stop changing over several diagnostics periods
    seen: list[tuple[str | None, str | None]] = []

    def settled():
        probe.executor.spin_once(timeout_sec=0.25)
        seen.append((_diag(probe, 'bytes')[1], _diag(probe, 'residuals_logged')[1]))
        return len(seen) > 8 and len(set(seen[-6:])) == 1

    probe.spin_until(settled, what='flushed bytes stable')
    logged = int(seen[-1][1])
    node.proc.send_signal(signal.SIGKILL)
    node.proc.wait(10)
    rows, log = read_residual_rows([folder])
    assert not (folder / 'metadata.yaml').exists()  # killed: no clean close
    assert len(log.files) >= 3
    assert len(rows) == logged, (len(rows), logged)  # everything flushed before the kill reads back
    assert np.all(np.isfinite(rows.residual_nm))


@pytest.mark.slow
def test_unwritable_folder_reported_node_stays_up(spawn, probe, tmp_path):
    _setup(probe)
    blocker = tmp_path / 'file'
    blocker.write_text('not a folder')
    node = _start(spawn, blocker / 'sub')
    probe.spin_until(lambda: _diag(probe, 'folder')[0] is not None, what='diagnostics')
    st, _ = _diag(probe, 'folder')
    assert st.level == b'\x02' and 'not logging' in st.message
    _wait_ready(probe)
    _send_pairs(probe, 5)
    probe.spin_until(lambda: int(_diag(probe, 'dropped')[1] or 0) > 0, what='dropped count')
    assert node.alive()
    rc, out = node.stop()
    assert rc == 0 and 'Traceback' not in out


@pytest.mark.slow
def test_runtime_period_change_takes_effect_and_start_up_only_setting_is_refused(spawn, probe, tmp_path):
    import time

    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    _setup(probe)
    node = spawn('residual_logger', '--ros-args', '-p', f'output_dir:={tmp_path / "p"}',
                 '-p', 'diagnostics_period_s:=10.0')
    client = probe.node.create_client(SetParameters, '/residual_logger/set_parameters')
    probe.spin_until(client.service_is_ready, what='set_parameters service')

    def set_double(name, value):
        req = SetParameters.Request(parameters=[ParameterMsg(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
        future = client.call_async(req)
        probe.spin_until(future.done, what=f'set {name}')
        return future.result().results[0]

    refused = set_double('max_file_mb', 1.0)
    assert not refused.successful and 'start-up' in refused.reason
    assert set_double('diagnostics_period_s', 0.2).successful
    n0 = len(probe.received['/diagnostics'])
    t0 = time.monotonic()
    # with the old 10 s timer kept, five diagnostics would take 50 s
    probe.spin_until(lambda: len(probe.received['/diagnostics']) >= n0 + 5, timeout=8.0,
                     what='diagnostics at the new 0.2 s period')
    assert time.monotonic() - t0 < 8.0
    assert node.stop()[0] == 0


@pytest.mark.slow
def test_a_temperature_burst_is_logged_whole_and_the_qos_follows_the_publishers(spawn, probe, tmp_path):
    """A reliable temperature publisher: the logger's subscription turns reliable and 10 000 messages at about
    2 kHz are logged whole (it used to be best-effort with depth 5: 14 of 14 938 lost in a burst, reported as
    'dropped 0'); flat out, what is not logged is counted lost on /diagnostics, message for message; a best-effort
    publisher joining turns the subscription back to best-effort, which hears both."""
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    probe.subscribe(DiagnosticArray, '/diagnostics')
    folder = tmp_path / 'burst'
    node = _start(spawn, folder)
    reliable = probe.node.create_publisher(Temperature, topics.TEMPERATURE, QoSProfile(
        depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE))
    probe.spin_until(lambda: _diag(probe, 'temperature_qos')[1] == 'reliable', what='reliable temperature QoS')
    probe.spin_until(lambda: reliable.get_subscription_count() >= 1, what='the logger matched')
    received = f'received: {topics.TEMPERATURE}'
    lost = f'lost: {topics.TEMPERATURE}'

    def publish(first: int, count: int, per_pause: int) -> None:
        for i in range(first, first + count):
            while True:
                try:
                    reliable.publish(temperature_msg(i))
                    break
                except RCLError:  # the writer's queue is full of messages the logger has not acknowledged yet
                    probe.executor.spin_once(timeout_sec=0.01)
            if i % per_pause == per_pause - 1:
                probe.executor.spin_once(timeout_sec=0.05)

    def accounted(total: int) -> bool:  # every message sent is either logged or counted lost
        return int(_diag(probe, received)[1] or 0) + int(_diag(probe, lost)[1] or 0) >= total

    # at a chamber test's high rate (about 2 kHz in bursts of 100): every message logged
    n = 10_000
    publish(0, n, 100)
    probe.spin_until(lambda: accounted(n), timeout=120, what=f'{n} temperatures accounted for')
    st, _ = _diag(probe, received)
    assert _diag(probe, received)[1] == str(n) and _diag(probe, lost)[1] == '0', st.values
    # flat out (a fuzz burst): what does not make it is counted, never silent
    publish(n, n, n)
    probe.spin_until(lambda: accounted(2 * n), timeout=120, what=f'{2 * n} temperatures accounted for')
    logged_burst = int(_diag(probe, received)[1]) - n
    assert int(_diag(probe, lost)[1]) == n - logged_burst  # each message either logged or counted lost
    best_effort = probe.node.create_publisher(Temperature, topics.TEMPERATURE, QoSProfile(
        depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    probe.spin_until(lambda: _diag(probe, 'temperature_qos')[1] == 'best_effort', what='best-effort QoS')

    def heard_both():
        best_effort.publish(temperature_msg(-1))
        reliable.publish(temperature_msg(-2))
        probe.executor.spin_once(timeout_sec=0.1)
        return int(_diag(probe, received)[1]) + int(_diag(probe, lost)[1]) >= 2 * n + 4
    probe.spin_until(heard_both, what='messages of both publishers')
    rc, out = node.stop()
    assert rc == 0, out
    temps = sorted(t for t in read_topic(folder, topics.TEMPERATURE) if t >= 0)
    assert temps[:n] == list(range(n)) and len(temps) == n + logged_burst  # each logged once
    assert -1.0 in read_topic(folder, topics.TEMPERATURE)  # the best-effort publisher was heard


def temperature_msg(i: int) -> Temperature:
    return Temperature(temperature=float(i))


def read_topic(folder: Path, topic: str) -> list[float]:
    """Temperatures logged on ``topic`` (each message once)."""
    out = []
    with AnyReader([folder], default_typestore=default_typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, _, raw in reader.messages(connections=conns):
            out.append(reader.deserialize(raw, conn.msgtype).temperature)
    return out


def test_open_own_folder_moves_beside_a_folder_taken_under_its_feet(tmp_path):
    """The race of two loggers: the folder was free when looked at, another logger created its first file before
    this one; this run takes the next sibling. A folder that cannot be written is an error, not a reason to
    move."""
    from gimbal_friction.common.errors import GimbalFrictionError
    from gimbal_friction.nodes.residual_logger import open_own_folder
    wanted = tmp_path / 'res'
    tried = []

    def writer(folder: Path):
        tried.append(folder)
        if folder == wanted:  # the other logger wins the exclusive create of the first file
            folder.mkdir()
            (folder / 'residuals_0.mcap').write_bytes(b'')
            raise GimbalFrictionError('residuals_0.mcap exists')
        folder.mkdir()
        (folder / 'residuals_0.mcap').write_bytes(b'')
        return 'writer'

    folder, made = open_own_folder(wanted, writer, now=lambda: 0.0)
    assert made == 'writer' and folder == tmp_path / 'res_19700101_000000' and tried == [wanted, folder]
    folder, _ = open_own_folder(wanted, writer, now=lambda: 0.0)  # a third run in the same second
    assert folder == tmp_path / 'res_19700101_000000_2'

    def unwritable(folder: Path):
        raise GimbalFrictionError('permission denied')

    with pytest.raises(GimbalFrictionError, match='permission denied'):
        open_own_folder(tmp_path / 'other', unwritable)


# ------------------------------------------------------------------------------------------------ sent against arrived
def _logger_counts(probe) -> dict[str, str]:
    """The values of the logger's latest status (key -> text)."""
    for arr in reversed(probe.received['/diagnostics']):
        for st in arr.status:
            if st.name == 'gimbal_friction/residual_logger':
                return {kv.key: kv.value for kv in st.values}
    return {}


@pytest.mark.slow
def test_what_a_publisher_said_it_sent_and_never_arrived_counts_as_lost(spawn, probe, tmp_path):
    """A publisher that says how many messages it sent (chamber_replay's ``finished`` status) is counted against
    what arrived: the messages it sent before the logger was there, which no sequence gap shows, count as lost
    (received + lost = sent). Main counted 0 lost of the 30 that never arrived."""
    _setup(probe)
    joint_states = probe.pubs[topics.JOINT_STATES]
    probe.publisher(DiagnosticArray, '/diagnostics')
    for i in range(30):  # nobody listens yet: these never arrive
        joint_states.publish(_js(1 + i, 0, 0.0))
    node = _start(spawn, tmp_path / 'res')
    _wait_ready(probe)
    probe.wait_matched('/diagnostics')
    for i in range(30, 50):
        joint_states.publish(_js(1 + i, 0, 0.0))
    probe.spin_until(lambda: _logger_counts(probe).get('received: /joint_states') == '20', what='20 joint states')
    assert _logger_counts(probe)['lost: /joint_states'] == '0'  # no gap: sequence numbers alone see nothing
    gid = next(bytes(i.endpoint_gid) for i in probe.node.get_publishers_info_by_topic(topics.JOINT_STATES)
               if i.node_name == 'probe')
    finished = DiagnosticArray()  # the documented status (docs/ros.md, chamber_replay)
    finished.status = [DiagnosticStatus(name='gimbal_friction/chamber_replay', values=[
        KeyValue(key='state', value='finished'), KeyValue(key='published: /joint_states', value='50'),
        KeyValue(key='publisher_gid: /joint_states', value=gid.hex())])]
    probe.pubs['/diagnostics'].publish(finished)
    probe.spin_until(lambda: _logger_counts(probe).get('lost: /joint_states') == '30', what='30 counted lost')
    counts = _logger_counts(probe)
    assert (counts['received: /joint_states'], counts['sent: /joint_states']) == ('20', '50')
    rc, out = node.stop()
    assert rc == 0, out


@pytest.mark.slow
def test_at_a_2000x_replay_every_message_sent_is_received_or_counted_lost(spawn, probe, tmp_path):
    """chamber_replay at 2000x into the logger: DDS loses many messages (the replay's keep-last history of 100
    overflows), some before the first or after the last one that arrived (0-2975 joint states a run were neither
    received nor counted before). Now received + lost = what the replay says it sent = the bag's count, per
    topic."""
    from gimbal_friction.recording.bag import open_chamber_bag

    bag = Path(__file__).resolve().parents[2] / 'bags' / 'chamber_sample'
    in_bag = {t: open_chamber_bag(bag).topics[t].messages for t in topics.CHAMBER_TOPICS}
    probe.subscribe(DiagnosticArray, '/diagnostics', qos=100)
    logger = _start(spawn, tmp_path / 'res')
    probe.spin_until(lambda: bool(_logger_counts(probe)), what='the logger up')
    player = spawn('chamber_replay', '--ros-args', '-p', f'bag:={bag}', '-p', 'rate:=2000.0',
                   '-p', 'wait_for_subscribers:=1')
    probe.spin_until(lambda: player.proc.poll() is not None, timeout=120.0, what='the replay played')
    assert player.wait()[0] == 0

    def accounted() -> bool:
        c = _logger_counts(probe)
        return all(c.get(f'sent: {t}') == str(n) and int(c.get(f'received: {t}', 0)) + int(c[f'lost: {t}']) == n
                   for t, n in in_bag.items())
    probe.spin_until(accounted, what=f'received + lost = sent = {in_bag}')
    rc, out = logger.stop()
    assert rc == 0, out
