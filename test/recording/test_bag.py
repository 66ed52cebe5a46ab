"""Chamber-test bags: write tiny bags in tmp_path (MCAP and sqlite3), read them back, describe them, refuse bad ones."""

from __future__ import annotations

import math
import sqlite3
from contextlib import closing
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer as McapWriter
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.recording.bag import ChamberArrays, foreign_serialization, open_chamber_bag
from gimbal_friction.recording.bag_write import write_chamber_bag
from gimbal_friction.recording.cdr import (
    default_typestore,
    make_float64_multi_array,
    make_joint_state,
    make_temperature,
)
from gimbal_friction.recording.errors import EmptyInputError, RecordingError
from gimbal_friction.recording.mcap_scan import McapScanner
from gimbal_friction.recording.recover import recover
from gimbal_friction.recording.topics import (
    CHAMBER_TOPICS,
    FLOAT64_MULTI_ARRAY_TYPE,
    JOINT_STATE_TYPE,
    JOINT_STATES,
    MOTOR_CURRENT,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)

T0 = 1_700_000_000_000_000_000  # log time of the first message [ns]
NAN = math.nan


def chamber_messages(
    joint_topic: str = JOINT_STATES, current_topic: str = MOTOR_CURRENT, temperature_topic: str = TEMPERATURE
) -> list[tuple[str, str, int, object]]:
    """A small chamber run: 3 temperatures, 6 joint states (2 joints, one without velocity), 4 currents."""
    out: list[tuple[str, str, int, object]] = []
    for i, temp in enumerate((-40.0, 20.0, 60.5)):
        t = T0 + i * 2_000_000
        out.append((temperature_topic, TEMPERATURE_TYPE, t, make_temperature(t - 5, temp)))
    for i in range(6):
        t = T0 + 100 + i * 1_000_000
        velocity = None if i == 3 else [0.5 + i, -0.25 * i]
        msg = make_joint_state(t - 7, ['elevation', 'azimuth'], position=[0.1 * i, -0.2 * i], velocity=velocity)
        out.append((joint_topic, JOINT_STATE_TYPE, t, msg))
    for i in range(4):
        t = T0 + 200 + i * 1_500_000
        out.append((current_topic, JOINT_STATE_TYPE, t, make_joint_state(t, ['elevation'], effort=[1.5 + i])))
    return sorted(out, key=lambda x: x[2])


@pytest.fixture(params=['mcap', 'sqlite3'])
def chamber_bag(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    return write_chamber_bag(tmp_path / f'bag_{request.param}', chamber_messages(), storage=request.param)


def test_open_reports_topics_counts_and_times(chamber_bag: Path) -> None:
    bag = open_chamber_bag(chamber_bag)
    assert bag.topics[TEMPERATURE] == (TEMPERATURE_TYPE, 3)
    assert bag.topics[JOINT_STATES] == (JOINT_STATE_TYPE, 6)
    assert bag.topics[MOTOR_CURRENT] == (JOINT_STATE_TYPE, 4)
    assert bag.message_count == 13
    assert bag.start_ns == T0
    assert bag.duration_ns == 5_000_100  # last joint state at T0 + 100 + 5 ms
    assert bag.end_ns == T0 + 5_000_100


def test_read_arrays_equal_what_was_written(chamber_bag: Path) -> None:
    arrays = open_chamber_bag(chamber_bag).read_arrays()
    assert isinstance(arrays, ChamberArrays)
    temp = arrays.temperature
    np.testing.assert_array_equal(temp.log_time_ns, [T0, T0 + 2_000_000, T0 + 4_000_000])
    np.testing.assert_array_equal(temp.stamp_ns, temp.log_time_ns - 5)
    np.testing.assert_array_equal(temp.temperature_c, [-40.0, 20.0, 60.5])
    assert temp.log_time_ns.dtype == np.int64

    js = arrays.joint_states
    assert len(js) == 6
    assert js.names == ('elevation', 'azimuth')
    i = np.arange(6)
    np.testing.assert_array_equal(js.log_time_ns, T0 + 100 + i * 1_000_000)
    np.testing.assert_array_equal(js.stamp_ns, js.log_time_ns - 7)
    np.testing.assert_allclose(js.position['elevation'], 0.1 * i)
    np.testing.assert_allclose(js.position['azimuth'], -0.2 * i)
    np.testing.assert_allclose(js.velocity['elevation'], [0.5, 1.5, 2.5, NAN, 4.5, 5.5])
    np.testing.assert_allclose(js.velocity['azimuth'], [0.0, -0.25, -0.5, NAN, -1.0, -1.25])
    assert np.isnan(js.effort['elevation']).all()
    assert np.isnan(js.effort['azimuth']).all()

    mc = arrays.motor_current
    assert mc.names == ('elevation',)
    np.testing.assert_array_equal(mc.effort['elevation'], [1.5, 2.5, 3.5, 4.5])
    assert np.isnan(mc.position['elevation']).all()


def test_bare_mcap_file_opens(tmp_path: Path) -> None:
    bag_dir = write_chamber_bag(tmp_path / 'bag', chamber_messages())
    (mcap_file,) = bag_dir.glob('*.mcap')
    bag = open_chamber_bag(mcap_file)
    assert bag.topics[JOINT_STATES] == (JOINT_STATE_TYPE, 6)
    arrays = bag.read_arrays()
    np.testing.assert_array_equal(arrays.temperature.temperature_c, [-40.0, 20.0, 60.5])


def test_iter_raw_in_log_time_order_and_decodable(chamber_bag: Path) -> None:
    bag = open_chamber_bag(chamber_bag)
    raw = list(bag.iter_raw())
    expected = chamber_messages()
    assert [(x.topic, x.msgtype, x.log_time_ns) for x in raw] == [(t, m, lt) for t, m, lt, _ in expected]
    store = default_typestore()
    for item, (_, msgtype, _, msg) in zip(raw, expected, strict=False):
        assert isinstance(item.data, (bytes, memoryview))
        decoded = store.deserialize_cdr(item.data, msgtype)
        assert decoded.header.stamp == msg.header.stamp  # type: ignore[attr-defined]
    only = list(bag.iter_raw([MOTOR_CURRENT]))
    assert [x.topic for x in only] == [MOTOR_CURRENT] * 4


def test_iter_decoded_gives_messages(chamber_bag: Path) -> None:
    bag = open_chamber_bag(chamber_bag)
    items = list(bag.iter_decoded([TEMPERATURE, MOTOR_CURRENT]))
    assert [x.topic for x in items] == [
        TEMPERATURE, MOTOR_CURRENT, MOTOR_CURRENT, TEMPERATURE, MOTOR_CURRENT, TEMPERATURE, MOTOR_CURRENT
    ]
    assert items[0].msg.temperature == -40.0  # type: ignore[attr-defined]
    assert list(items[1].msg.effort) == [1.5]  # type: ignore[attr-defined]
    with pytest.raises(RecordingError, match='/no/such/topic'):
        list(bag.iter_decoded(['/no/such/topic']))


def test_bare_db3_file_opens(tmp_path: Path) -> None:
    bag_dir = write_chamber_bag(tmp_path / 'bag', chamber_messages(), storage='sqlite3')
    (db3,) = bag_dir.glob('*.db3')
    arrays = open_chamber_bag(db3).read_arrays()
    np.testing.assert_array_equal(arrays.temperature.temperature_c, [-40.0, 20.0, 60.5])
    assert len(arrays.joint_states) == 6


def test_reader_closes_when_iteration_stops_early(chamber_bag: Path) -> None:
    bag = open_chamber_bag(chamber_bag)
    gen = bag.iter_raw()
    next(gen)
    gen.close()  # GeneratorExit closes the AnyReader inside
    assert len(list(bag.iter_raw())) == 13


@pytest.mark.parametrize('missing', [TEMPERATURE, JOINT_STATES, MOTOR_CURRENT])
def test_missing_topic_is_refused_by_name(tmp_path: Path, missing: str) -> None:
    path = write_chamber_bag(tmp_path / 'bag', [m for m in chamber_messages() if m[0] != missing])
    with pytest.raises(RecordingError, match=f'required topic {missing} is missing'):
        open_chamber_bag(path)


def test_wrong_type_is_refused_by_name(tmp_path: Path) -> None:
    msgs = [m for m in chamber_messages() if m[0] != TEMPERATURE]
    msgs.append((TEMPERATURE, FLOAT64_MULTI_ARRAY_TYPE, T0, make_float64_multi_array([20.0], 'x')))
    path = write_chamber_bag(tmp_path / 'bag', msgs)
    with pytest.raises(RecordingError, match=f'{TEMPERATURE} has type {FLOAT64_MULTI_ARRAY_TYPE}'):
        open_chamber_bag(path)


def test_refusals_are_gimbal_friction_errors(tmp_path: Path) -> None:
    with pytest.raises(GimbalFrictionError, match=r'not a rosbag2 bag: .*no such file'):
        open_chamber_bag(tmp_path / 'nope')
    (tmp_path / 'empty_dir').mkdir()
    with pytest.raises(RecordingError, match=r'not a rosbag2 bag: .*metadata.yaml'):
        open_chamber_bag(tmp_path / 'empty_dir')
    (tmp_path / 'notes.txt').write_text('hello')
    with pytest.raises(RecordingError, match=r'not a rosbag2 bag: .*a .mcap or a .db3 file'):
        open_chamber_bag(tmp_path / 'notes.txt')
    (tmp_path / 'junk.mcap').write_bytes(b'definitely not mcap' * 10)
    with pytest.raises(RecordingError, match=r'junk.mcap: opening failed .*gimbal-friction recover'):
        open_chamber_bag(tmp_path / 'junk.mcap')
    killed = tmp_path / 'killed'  # a recorder killed before writing metadata.yaml
    killed.mkdir()
    (killed / 'killed_0.mcap').write_bytes(b'\x89MCAP0\r\n')
    with pytest.raises(RecordingError, match=r'no metadata.yaml .*gimbal-friction recover'):
        open_chamber_bag(killed)


def test_topic_map_remaps_bag_names(tmp_path: Path) -> None:
    path = write_chamber_bag(
        tmp_path / 'bag', chamber_messages(joint_topic='/gimbal/joint_states', current_topic='/drive/current')
    )
    with pytest.raises(RecordingError, match='required topics /joint_states, /gimbal/motor_current are missing'):
        open_chamber_bag(path)
    with pytest.raises(RecordingError, match=r'/joint_states \(recorded as /wrong\) is missing'):
        open_chamber_bag(path, {JOINT_STATES: '/wrong', MOTOR_CURRENT: '/drive/current'})
    bag = open_chamber_bag(path, {JOINT_STATES: '/gimbal/joint_states', MOTOR_CURRENT: '/drive/current'})
    assert set(bag.topics) == {TEMPERATURE, JOINT_STATES, MOTOR_CURRENT}  # bag names are not visible twice
    assert bag.topic_map[JOINT_STATES] == '/gimbal/joint_states'
    assert {x.topic for x in bag.iter_raw()} == {TEMPERATURE, JOINT_STATES, MOTOR_CURRENT}
    arrays = bag.read_arrays()
    assert len(arrays.joint_states) == 6
    np.testing.assert_array_equal(arrays.motor_current.effort['elevation'], [1.5, 2.5, 3.5, 4.5])


def test_one_bag_topic_can_feed_two_inputs(tmp_path: Path) -> None:
    msgs = [m for m in chamber_messages() if m[0] != MOTOR_CURRENT]
    path = write_chamber_bag(tmp_path / 'bag', msgs)
    bag = open_chamber_bag(path, {MOTOR_CURRENT: JOINT_STATES})
    arrays = bag.read_arrays()
    assert len(arrays.motor_current) == len(arrays.joint_states) == 6
    raw = list(bag.iter_raw([JOINT_STATES, MOTOR_CURRENT]))
    assert len(raw) == 12


def test_empty_required_topic_is_refused(tmp_path: Path) -> None:
    store = default_typestore()
    path = tmp_path / 'bag'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, msgtype, t, msg in chamber_messages():
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            if topic != TEMPERATURE:  # the connection exists, its messages do not
                writer.write(conns[topic], t, store.serialize_cdr(msg, msgtype))
    with pytest.raises(RecordingError, match=f'{TEMPERATURE} has no messages'):
        open_chamber_bag(path)


def random_joint_states(rng: np.random.Generator, n: int) -> list[tuple[str, str, int, object]]:
    """JointStates with varied frame ids, name sets and missing or short fields."""
    name_sets = [['elevation'], ['elevation', 'azimuth'], ['azimuth'], [], ['a' * 7, 'elevation', 'bb'],
                 ['elevation', 'azimuth', 'elevation']]  # a repeated name: its first value counts
    out = []
    for i in range(n):
        names = name_sets[int(rng.integers(len(name_sets)))]
        k = len(names)

        def field(k: int = k) -> np.ndarray | None:
            choice = rng.integers(4)
            if choice == 0:
                return None
            if choice == 1 and k:
                return rng.normal(size=int(rng.integers(0, k + 2)))  # short or long: malformed but seen
            return rng.normal(size=k)

        frame = 'f' * int(rng.integers(0, 9))
        msg = make_joint_state(T0 + 3 * i, names, field(), field(), field(), frame_id=frame)
        out.append((JOINT_STATES, JOINT_STATE_TYPE, T0 + 10 * i, msg))
    return out


def expected_joint_arrays(msgs: list[tuple[str, str, int, object]]) -> dict[str, dict[str, list[float]]]:
    order: list[str] = []
    for _, _, _, msg in msgs:
        for name in msg.name:  # type: ignore[attr-defined]
            if name not in order:
                order.append(name)
    fields = ('position', 'velocity', 'effort')
    out: dict[str, dict[str, list[float]]] = {f: {n: [] for n in order} for f in fields}
    for _, _, _, msg in msgs:
        for field in out:
            values = getattr(msg, field)
            for name in order:
                names = list(msg.name)  # type: ignore[attr-defined]
                j = names.index(name) if name in names else None
                out[field][name].append(float(values[j]) if j is not None and j < len(values) else NAN)
    return out


@pytest.mark.parametrize('little_endian', [True, False])
def test_fast_joint_state_decoder_matches_typestore(tmp_path: Path, little_endian: bool) -> None:
    rng = np.random.default_rng(7)
    js = random_joint_states(rng, 300)
    store = default_typestore()
    others = [m for m in chamber_messages() if m[0] != JOINT_STATES]
    path = tmp_path / 'bag'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, msgtype, t, msg in sorted(js + others, key=lambda x: x[2]):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], t, store.serialize_cdr(msg, msgtype, little_endian=little_endian))
    arrays = open_chamber_bag(path).read_arrays().joint_states
    expected = expected_joint_arrays(js)
    assert list(arrays.names) == list(expected['position'])
    np.testing.assert_array_equal(arrays.log_time_ns, [m[2] for m in js])
    np.testing.assert_array_equal(arrays.stamp_ns, [T0 + 3 * i for i in range(300)])
    for field in ('position', 'velocity', 'effort'):
        for name in arrays.names:
            np.testing.assert_array_equal(getattr(arrays, field)[name], expected[field][name], err_msg=field)


def test_write_chamber_bag_refusals(tmp_path: Path) -> None:
    path = write_chamber_bag(tmp_path / 'bag', chamber_messages())
    with pytest.raises(RecordingError, match='exists'):
        write_chamber_bag(path, chamber_messages())
    with pytest.raises(RecordingError, match='unknown bag storage'):
        write_chamber_bag(tmp_path / 'other', chamber_messages(), storage='rosbag1')
    with AnyReader([path]) as reader:  # what was written is a plain rosbag2 bag
        assert reader.message_count == 13


def test_message_helpers() -> None:
    temp = make_temperature(-1, 21.5)
    assert (temp.header.stamp.sec, temp.header.stamp.nanosec) == (-1, 999_999_999)  # type: ignore[attr-defined]
    assert temp.header.frame_id == 'gimbal'  # type: ignore[attr-defined]
    js = make_joint_state(3_000_000_001, ['elevation'], velocity=np.array([2.0]))
    assert js.position.dtype == np.float64 and js.position.size == 0  # type: ignore[attr-defined]
    assert (js.header.stamp.sec, js.header.stamp.nanosec) == (3, 1)  # type: ignore[attr-defined]
    arr = make_float64_multi_array([1, 2, 3], 'azimuth')
    assert arr.layout.dim[0].label == 'azimuth' and arr.layout.dim[0].size == 3  # type: ignore[attr-defined]
    store = default_typestore()
    back = store.deserialize_cdr(store.serialize_cdr(arr, FLOAT64_MULTI_ARRAY_TYPE), FLOAT64_MULTI_ARRAY_TYPE)
    np.testing.assert_array_equal(back.data, [1.0, 2.0, 3.0])  # type: ignore[attr-defined]


def bag_with_other_topics(tmp_path: Path) -> Path:
    """A chamber bag recorded with ``--all``: /rosout, a service event and a type no type store knows, in MCAP."""
    from mcap.writer import Writer as McapWriter

    store = default_typestore()
    path = tmp_path / 'all.mcap'
    with path.open('wb') as stream:
        writer = McapWriter(stream)
        writer.start(profile='ros2', library='test')
        channels = {}
        for topic, msgtype in (
            (TEMPERATURE, TEMPERATURE_TYPE), (JOINT_STATES, JOINT_STATE_TYPE), (MOTOR_CURRENT, JOINT_STATE_TYPE),
        ):
            text, _ = store.generate_msgdef(msgtype, ros_version=2)
            schema = writer.register_schema(msgtype, 'ros2msg', text.encode())
            channels[topic] = writer.register_channel(topic, 'cdr', schema)
        # a service event, as rosbag2 on Jazzy/Kilted records them with --all: the schema holds the raw .srv text
        # (ros2/rosbag2#2365), which is no message definition; and a custom message type on an unrelated topic
        event = writer.register_schema('my_pkg/srv/DoIt_Event', 'ros2msg', b'int64 a\nint64 b\n---\nint64 sum\n')
        custom = writer.register_schema('my_pkg/msg/Blob', 'ros2msg', b'my_pkg/Inner inner\nuint8[] data\n')
        meta = {'offered_qos_profiles': '', 'topic_type_hash': 'RIHS01_' + '0' * 64}  # as rosbag2 records them
        channels['/do_it/_service_event'] = writer.register_channel('/do_it/_service_event', 'cdr', event, meta)
        channels['/blob'] = writer.register_channel('/blob', 'cdr', custom, meta)
        for topic, msgtype, t, msg in chamber_messages():
            writer.add_message(channels[topic], t, bytes(store.serialize_cdr(msg, msgtype)), t)
        writer.add_message(channels['/do_it/_service_event'], T0 + 1, b'\x00\x01\x00\x00garbage', T0 + 1)
        writer.add_message(channels['/blob'], T0 + 2, b'\x00\x01\x00\x00\x01', T0 + 2)
        writer.finish()
    return path


def test_other_topics_of_any_type_are_ignored_and_listed(tmp_path: Path) -> None:
    bag = open_chamber_bag(bag_with_other_topics(tmp_path))
    assert bag.ignored_topics == {'/do_it/_service_event': 'my_pkg/srv/DoIt_Event', '/blob': 'my_pkg/msg/Blob'}
    assert bag.message_count == 13  # the three inputs
    assert {x.topic for x in bag.iter_raw()} == {TEMPERATURE, JOINT_STATES, MOTOR_CURRENT}
    seen = []
    arrays = bag.read_arrays(raw_sink=lambda batch: seen.extend(batch.topics[k][0] for k in batch.topic.tolist()))
    assert len(seen) == 13 and set(seen) == {TEMPERATURE, JOINT_STATES, MOTOR_CURRENT}
    assert len(arrays.joint_states) == 6
    assert [x.log_time_ns for x in bag.iter_raw(['/blob'])] == [T0 + 2]  # still readable by name
    notes = bag.describe(arrays).findings(['elevation'])
    assert any('not read' in n and '/do_it/_service_event' in n for n in notes)
    with pytest.raises(RecordingError, match='cannot decode /blob message'):
        list(bag.iter_decoded(['/blob']))


def test_joint_map_renames_the_recorded_joints(tmp_path: Path) -> None:
    path = write_chamber_bag(tmp_path / 'bag', chamber_messages())
    bag = open_chamber_bag(path, joint_map={'azimuth': 'yaw', 'elevation': 'pitch'})
    arrays = bag.read_arrays()
    assert arrays.joint_states.names == ('pitch', 'yaw')
    assert arrays.motor_current.names == ('pitch',)
    np.testing.assert_allclose(arrays.joint_states.velocity['pitch'], [0.5, 1.5, 2.5, NAN, 4.5, 5.5])
    described = bag.describe(arrays)
    assert [(j.name, j.recorded_name) for j in described.streams[JOINT_STATES].joints] == [
        ('pitch', 'elevation'), ('yaw', 'azimuth')]
    clash = open_chamber_bag(path, joint_map={'azimuth': 'elevation'})  # 'elevation' is recorded too
    with pytest.raises(RecordingError, match="joints 'elevation' and 'azimuth' would both be named 'elevation'"):
        clash.read_arrays()
    with pytest.raises(RecordingError, match='are all mapped to'):
        open_chamber_bag(path, joint_map={'azimuth': 'x', 'elevation': 'x'})
    with pytest.raises(RecordingError, match='non-empty'):
        open_chamber_bag(path, joint_map={'': 'x'})


def test_describe_explains_what_matches_nothing(tmp_path: Path) -> None:
    msgs = []
    for i in range(4):  # zero stamps, a robot joint name, no velocity, current on another joint
        t = T0 + i * 1_000_000
        msgs.append((TEMPERATURE, TEMPERATURE_TYPE, t, make_temperature(0, 20.0)))
        msgs.append((JOINT_STATES, JOINT_STATE_TYPE, t + 1, make_joint_state(0, ['joint_2'], position=[0.1])))
        msgs.append((MOTOR_CURRENT, JOINT_STATE_TYPE, t + 2, make_joint_state(t, ['joint_9'], effort=[1.0])))
    path = write_chamber_bag(tmp_path / 'bag', msgs)
    described = open_chamber_bag(path).describe()
    js = described.streams[JOINT_STATES]
    assert (js.messages, js.zero_stamps, js.first_log_ns, js.last_log_ns) == (4, 4, T0 + 1, T0 + 3_000_001)
    assert js.joints[0] == ('joint_2', 'joint_2', 4, 4, 0, 0)
    assert described.streams[MOTOR_CURRENT].zero_stamps == 0
    notes = described.findings(['elevation'])
    assert any("axis 'elevation' is not in /joint_states (joints seen: 'joint_2')" in n and '--joint' in n
               for n in notes)
    assert any('/joint_states: every header stamp is zero (4 messages)' in n for n in notes)
    assert any('/gimbal/temperature: every header stamp is zero' in n for n in notes)
    mapped = open_chamber_bag(path, joint_map={'joint_2': 'elevation'}).describe().findings(['elevation'])
    assert any("carries no velocity for 'elevation' (4 messages)" in n for n in mapped)
    assert any("/gimbal/motor_current (motor current) carries no effort for 'elevation'" in n for n in mapped)
    assert not any('is not in' in n for n in mapped)
    clean = open_chamber_bag(write_chamber_bag(tmp_path / 'clean', chamber_messages())).describe()
    assert clean.findings(['elevation']) == [
        "/joint_states: 1 of 6 messages carry no velocity for 'elevation'"]
    assert clean.joint_names(JOINT_STATES) == ('elevation', 'azimuth')


def test_a_truncated_or_corrupted_bag_points_to_recover(tmp_path: Path) -> None:
    path = write_chamber_bag(tmp_path / 'bag', chamber_messages())
    (mcap_file,) = path.glob('*.mcap')
    data = mcap_file.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match=r'cut.mcap: opening failed .*`gimbal-friction recover .*cut.mcap --out'):
        open_chamber_bag(cut)


@pytest.mark.parametrize('window', [1, 3, 40, 10**9])
def test_windows_together_equal_the_whole_bag(tmp_path: Path, window: int) -> None:
    """iter_arrays (the fleet's bounded-memory read) gives read_arrays cut in log-time order, never inside one log
    time (messages logged at the same time stay in one window, as one callback batch of a node)."""
    rng = np.random.default_rng(3)
    js = random_joint_states(rng, 120)
    js = [(topic, msgtype, T0 + 20 * (i // 3), msg) for i, (topic, msgtype, _, msg) in enumerate(js)]  # ties
    others = [(t, m, T0 + 20 * k + 20, msg) for k, (t, m, _, msg) in enumerate(
        x for x in chamber_messages() if x[0] != JOINT_STATES)]
    path = write_chamber_bag(tmp_path / 'bag', sorted(js + others, key=lambda x: x[2]))
    bag = open_chamber_bag(path)
    whole = bag.read_arrays()
    parts = list(bag.iter_arrays(window))
    assert len(parts) >= 1
    if window == 10**9:
        assert len(parts) == 1
    sizes = [len(p.temperature.log_time_ns) + len(p.joint_states) + len(p.motor_current) for p in parts]
    assert sum(sizes) == bag.message_count
    assert all(size >= window for size in sizes[:-1])
    for field in ('temperature', 'joint_states', 'motor_current'):
        logs = [np.asarray(getattr(p, field).log_time_ns) for p in parts]
        np.testing.assert_array_equal(np.concatenate(logs), getattr(whole, field).log_time_ns)
    ends = [int(np.max(np.concatenate([p.temperature.log_time_ns, p.joint_states.log_time_ns,
                                       p.motor_current.log_time_ns]))) for p in parts]
    starts = [int(np.min(np.concatenate([p.temperature.log_time_ns, p.joint_states.log_time_ns,
                                         p.motor_current.log_time_ns]))) for p in parts]
    assert all(e < s for e, s in zip(ends[:-1], starts[1:], strict=True))   # a log time is never split
    np.testing.assert_array_equal(np.concatenate([p.temperature.temperature_c for p in parts]),
                                  whole.temperature.temperature_c)
    for field in ('position', 'velocity', 'effort'):
        for name in whole.joint_states.names:
            joined = np.concatenate([getattr(p.joint_states, field).get(name, np.full(len(p.joint_states), NAN))
                                     for p in parts])
            np.testing.assert_array_equal(joined, getattr(whole.joint_states, field)[name], err_msg=field)
    with pytest.raises(ValueError, match='max_messages'):
        bag.iter_arrays(0)


# ---------------------------------------------------------------------------------------------- issue 19 (3, 4, 5)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_every_missing_topic_is_named_with_the_option_that_maps_it(tmp_path: Path, storage: str) -> None:
    """Two inputs recorded under other names: one refusal names both and ``--topic`` (with the likely bag topic)."""
    msgs = chamber_messages(joint_topic='/gimbal/joint_states', temperature_topic='/chamber/temp')
    path = write_chamber_bag(tmp_path / 'bag', msgs, storage=storage)
    with pytest.raises(RecordingError) as info:
        open_chamber_bag(path)
    text = str(info.value)
    assert '\n' not in text
    assert f'required topics {TEMPERATURE}, {JOINT_STATES} are missing' in text
    assert f'--topic {JOINT_STATES}=/gimbal/joint_states' in text
    assert f'--topic {TEMPERATURE}=/chamber/temp' in text  # the one Temperature topic of the bag
    assert '/chamber/temp (sensor_msgs/msg/Temperature)' in text  # what the bag holds, to pick from
    bag = open_chamber_bag(path, {JOINT_STATES: '/gimbal/joint_states', TEMPERATURE: '/chamber/temp'})
    assert len(bag.read_arrays().temperature) == 3


def test_the_refusal_suggests_the_topics_of_the_right_type_by_name(tmp_path: Path) -> None:
    """Issue 31 item 13: a bag whose one Temperature topic is /arm/bearing_temp and whose JointState topics are
    /arm/joints and /arm/drive_current: each missing input is given the topic of its type whose name is most like
    it (not a placeholder), a topic never for two inputs; with no topic of the type, the placeholder and why."""
    msgs = chamber_messages(joint_topic='/arm/joints', temperature_topic='/arm/bearing_temp',
                            current_topic='/arm/drive_current')
    path = write_chamber_bag(tmp_path / 'bag', msgs)
    with pytest.raises(RecordingError) as info:
        open_chamber_bag(path)
    text = str(info.value)
    assert (f'--topic {TEMPERATURE}=/arm/bearing_temp --topic {JOINT_STATES}=/arm/joints '
            f'--topic {MOTOR_CURRENT}=/arm/drive_current') in text
    assert 'BAG_TOPIC' not in text
    no_temp = write_chamber_bag(tmp_path / 'bag2', [m for m in msgs if m[0] != '/arm/bearing_temp'])
    with pytest.raises(RecordingError) as info:
        open_chamber_bag(no_temp, {JOINT_STATES: '/arm/joints', MOTOR_CURRENT: '/arm/drive_current'})
    text = str(info.value)
    assert f'--topic {TEMPERATURE}=BAG_TOPIC' in text
    assert f'no sensor_msgs/msg/Temperature topic in the bag for {TEMPERATURE}' in text


def robot_joint_bag(path: Path, *, effort: bool = True) -> Path:
    """Joint states and currents of a joint named 'joint_2' (no configured axis)."""
    msgs = []
    for i in range(6):
        t = T0 + i * 1_000_000
        msgs.append((TEMPERATURE, TEMPERATURE_TYPE, t, make_temperature(t, 20.0)))
        msgs.append((JOINT_STATES, JOINT_STATE_TYPE, t + 1,
                     make_joint_state(t, ['joint_2'], position=[0.01], velocity=[0.035])))
        msgs.append((MOTOR_CURRENT, JOINT_STATE_TYPE, t + 2,
                     make_joint_state(t, ['joint_2'], effort=[0.2] if effort else None, velocity=[0.0])))
    return write_chamber_bag(path, msgs)


def test_a_read_with_no_configured_axis_is_refused_naming_the_joints_and_the_mapping(tmp_path: Path) -> None:
    """The reader's rule (replay and fleet both read through it): no configured axis in the bag, or a --joint naming
    an absent joint, is an EmptyInputError naming the joints present, the mapping used and the fix."""
    path = robot_joint_bag(tmp_path / 'bag')
    for read in (lambda b: b.read_arrays(), lambda b: list(b.iter_arrays(4))):
        with pytest.raises(EmptyInputError) as info:
            read(open_chamber_bag(path, axes=['elevation']))
        text = str(info.value)
        assert "no configured axis is in /joint_states (axes: 'elevation'; joints recorded: 'joint_2'" in text
        assert 'joint map: none' in text and '--joint elevation=joint_2' in text and '\n' not in text
    with pytest.raises(EmptyInputError, match=r"--joint elevation=joint_7: no joint 'joint_7' in /joint_states .*"
                                              r"\(joints recorded: 'joint_2'\)"):
        open_chamber_bag(path, joint_map={'joint_7': 'elevation'}, axes=['elevation']).read_arrays()
    mapped = open_chamber_bag(path, joint_map={'joint_2': 'elevation'}, axes=['elevation']).read_arrays()
    assert mapped.joint_states.names == ('elevation',)
    assert open_chamber_bag(path).read_arrays().joint_states.names == ('joint_2',)  # no axes given: not checked
    # two axes, one present: a note of the replay, not a refusal
    assert len(open_chamber_bag(path, joint_map={'joint_2': 'elevation'}, axes=['elevation', 'azimuth'])
               .read_arrays().joint_states) == 6
    no_current = robot_joint_bag(tmp_path / 'no_current', effort=False)
    with pytest.raises(EmptyInputError, match=r'/gimbal/motor_current carries no motor current \(effort\) .*'
                                              r'joints with effort there: none; joint map: elevation=joint_2\).*'
                                              r'--topic /gimbal/motor_current='):
        open_chamber_bag(no_current, joint_map={'joint_2': 'elevation'}, axes=['elevation']).read_arrays()


def _retag_rosbag2(path: Path, fmt: str) -> Path:
    """A rosbag2 folder whose metadata (and sqlite3 topics table) say ``fmt`` instead of cdr."""
    meta = path / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('serialization_format: cdr', f'serialization_format: {fmt}'))
    for db3 in path.glob('*.db3'):
        with closing(sqlite3.connect(db3)) as con:
            con.execute('UPDATE topics SET serialization_format = ?', (fmt,))
            con.commit()
    return path


def _foreign_mcap(path: Path, encoding: str, profile: str) -> Path:
    """An MCAP file with the chamber topics in another message encoding (another middleware's bag)."""
    schema_encoding = {'json': 'jsonschema', 'protobuf': 'protobuf', 'ros1': 'ros1msg'}[encoding]
    with path.open('wb') as stream:
        writer = McapWriter(stream)
        writer.start(profile=profile, library='another middleware')
        channels = [writer.register_channel(topic, encoding, writer.register_schema(msgtype, schema_encoding, b'{}'))
                    for topic, msgtype in ((TEMPERATURE, TEMPERATURE_TYPE), (JOINT_STATES, JOINT_STATE_TYPE),
                                           (MOTOR_CURRENT, JOINT_STATE_TYPE))]
        for i in range(5):
            for channel in channels:
                writer.add_message(channel, T0 + i, b'{"x": 1}', T0 + i)
        writer.finish()
    return path


def _foreign_bag(tmp_path: Path, kind: str) -> tuple[Path, str]:
    if kind in ('mcap folder', 'sqlite3 folder'):
        storage = kind.split(maxsplit=1)[0]
        return _retag_rosbag2(write_chamber_bag(tmp_path / 'bag', chamber_messages(), storage=storage), 'json'), \
            'json'
    if kind == 'bare db3':
        folder = _retag_rosbag2(write_chamber_bag(tmp_path / 'bag', chamber_messages(), storage='sqlite3'), 'json')
        (db3,) = folder.glob('*.db3')
        return db3, 'json'
    encoding, profile = kind.split()[1:]
    return _foreign_mcap(tmp_path / 'foreign.mcap', encoding, '' if profile == '-' else profile), encoding


FOREIGN = ['mcap folder', 'sqlite3 folder', 'bare db3', 'mcap json -', 'mcap protobuf -', 'mcap ros1 -',
           'mcap json ros2']


@pytest.mark.parametrize('kind', FOREIGN)
def test_a_bag_not_in_cdr_is_named_unsupported_by_the_reader_and_by_recover(tmp_path: Path, kind: str) -> None:
    """Not 'damaged, use recover' (then 'nothing to recover'): both say what the bag is and that it is not
    supported, and recover writes nothing."""
    path, fmt = _foreign_bag(tmp_path, kind)
    assert foreign_serialization(path) is not None or kind == 'mcap json ros2'
    with pytest.raises(RecordingError) as info:
        open_chamber_bag(path)
    text = str(info.value)
    assert f"serialized as '{fmt}'" in text and 'not CDR: not supported' in text and '\n' not in text
    assert 'damaged or cut short' not in text and '--out NEW' not in text
    if kind.endswith(' -'):
        assert "profile '', not 'ros2'" in text
    if kind == 'mcap json ros2':
        return  # rosbags reads a ros2-profile MCAP whatever a channel's encoding: the reader refuses the topics
    with pytest.raises(RecordingError) as info:
        recover(path, tmp_path / 'recovered')
    text = str(info.value)
    assert text.startswith(f'recover: {path}: ') and f"serialized as '{fmt}'" in text and 'not supported' in text
    assert not (tmp_path / 'recovered').exists()
    assert not list(tmp_path.glob('.recovered*'))


def test_one_foreign_side_topic_refuses_an_mcap_bag_but_not_a_sqlite3_one(tmp_path: Path) -> None:
    """rosbags opens no MCAP file with a channel in another encoding (named, the CDR inputs aside); a sqlite3 bag
    with one is read (only the inputs are decoded)."""
    store = default_typestore()
    path = tmp_path / 'mixed.mcap'
    with path.open('wb') as stream:
        writer = McapWriter(stream)
        writer.start(profile='ros2', library='rosbag2 (imitated)')
        channels = {}
        for topic, msgtype in ((TEMPERATURE, TEMPERATURE_TYPE), (JOINT_STATES, JOINT_STATE_TYPE),
                               (MOTOR_CURRENT, JOINT_STATE_TYPE)):
            text, _ = store.generate_msgdef(msgtype, ros_version=2)
            channels[topic] = writer.register_channel(topic, 'cdr', writer.register_schema(msgtype, 'ros2msg',
                                                                                           text.encode()))
        notes = writer.register_channel('/annotations', 'json', writer.register_schema('Note', 'jsonschema', b'{}'))
        for topic, msgtype, t, msg in chamber_messages():
            writer.add_message(channels[topic], t, bytes(store.serialize_cdr(msg, msgtype)), t)
        writer.add_message(notes, T0, b'{}', T0)
        writer.finish()
    with pytest.raises(RecordingError, match=r"serialized as 'json' \(/annotations\), not CDR: not supported"):
        open_chamber_bag(path)
    msgs = [*chamber_messages(), ('/status', TEMPERATURE_TYPE, T0, make_temperature(T0, 1.0))]
    folder = write_chamber_bag(tmp_path / 'db3', msgs, storage='sqlite3')
    (db3,) = folder.glob('*.db3')
    with closing(sqlite3.connect(db3)) as con:
        con.execute("UPDATE topics SET serialization_format = 'json' WHERE name = '/status'")
        con.commit()
    assert foreign_serialization(db3) is None
    assert len(open_chamber_bag(db3).read_arrays().joint_states) == 6


def chunked_mcap(path: Path, messages: list[tuple[str, str, int, object]], chunk_size: int) -> Path:
    """A bare MCAP file of ``messages`` in the given order, in small zstd chunks (mcap's writer)."""
    store = default_typestore()
    with path.open('wb') as stream:
        writer = McapWriter(stream, chunk_size=chunk_size)
        writer.start(profile='ros2', library='test')
        channels: dict[str, int] = {}
        for topic, msgtype, t, msg in messages:
            if topic not in channels:
                text, _ = store.generate_msgdef(msgtype, ros_version=2)
                schema = writer.register_schema(msgtype, 'ros2msg', text.encode())
                channels[topic] = writer.register_channel(topic, 'cdr', schema)
            writer.add_message(channels[topic], t, bytes(store.serialize_cdr(msg, msgtype)), t)
        writer.finish()
    return path


@pytest.mark.parametrize('layout', ['chunks in log-time order', 'chunks overlapping in time', 'sqlite3'])
def test_bulk_read_equals_reading_message_by_message(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     layout: str) -> None:
    """read_arrays decodes a chunk at a time (MCAP chunks that follow each other in log time) or rosbags' messages
    in batches (anything else); either way the arrays and the raw messages handed to raw_sink are those of the
    type store, message by message, in rosbags' order (ties in log time included)."""
    import gimbal_friction.recording.bag as bag_module

    rng = np.random.default_rng(21)
    js = [(topic, msgtype, T0 + 1000 * (i // 2), msg) for i, (topic, msgtype, _, msg) in
          enumerate(random_joint_states(rng, 300))]
    cur = [(MOTOR_CURRENT, JOINT_STATE_TYPE, T0 + 1000 * i + 1000 * (i % 3 == 0),
            make_joint_state(T0 + 1000 * i, ['elevation', 'azimuth'], effort=[0.1 * i, -0.1 * i])) for i in range(150)]
    temp = [(TEMPERATURE, TEMPERATURE_TYPE, T0 + 7000 * i, make_temperature(T0 + 7000 * i - 3, -40.0 + i))
            for i in range(22)]
    messages = sorted(js + cur + temp, key=lambda x: x[2])
    if layout == 'sqlite3':
        path = write_chamber_bag(tmp_path / 'bag', messages, storage='sqlite3')
    else:
        if layout == 'chunks overlapping in time':  # a late batch of messages written after later ones
            messages = messages[:100] + messages[150:300] + messages[100:150] + messages[300:]
        path = chunked_mcap(tmp_path / 'bag.mcap', messages, chunk_size=700)
    scanned = []
    monkeypatch.setattr(bag_module, 'McapScanner', lambda p: scanned.append(p) or McapScanner(p))
    bag = open_chamber_bag(path)
    raw: list[tuple[str, int, bytes]] = []
    arrays = bag.read_arrays(raw_sink=lambda b: raw.extend(
        (b.topics[k][0], t, d) for k, t, d in zip(b.topic.tolist(), b.log_time.tolist(), b.datas(), strict=True)))
    assert bool(scanned) == (layout == 'chunks in log-time order')   # the chunk-at-a-time path, where it applies
    expected = [(m.topic, m.log_time_ns, m.data) for m in bag.iter_raw()]
    assert raw == expected
    decoded = {topic: [(m.log_time_ns, m.msg) for m in bag.iter_decoded([topic])] for topic in CHAMBER_TOPICS}
    temps = decoded[TEMPERATURE]
    np.testing.assert_array_equal(arrays.temperature.log_time_ns, [t for t, _ in temps])
    np.testing.assert_array_equal(arrays.temperature.temperature_c, [m.temperature for _, m in temps])
    for topic, data in ((JOINT_STATES, arrays.joint_states), (MOTOR_CURRENT, arrays.motor_current)):
        msgs = decoded[topic]
        np.testing.assert_array_equal(data.log_time_ns, [t for t, _ in msgs])
        np.testing.assert_array_equal(data.stamp_ns, [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                                                      for _, m in msgs])
        for field in ('position', 'velocity', 'effort'):
            for name, column in getattr(data, field).items():
                want = []
                for _, m in msgs:
                    values = getattr(m, field)
                    slot = list(m.name).index(name) if name in m.name else len(values)
                    want.append(values[slot] if slot < len(values) else NAN)
                np.testing.assert_array_equal(column, want, err_msg=f'{topic} {field} {name}')
    parts = list(bag.iter_arrays(37))   # windows cut inside the batches: together, the whole bag
    assert len(parts) > 5
    for field in ('temperature', 'joint_states', 'motor_current'):
        np.testing.assert_array_equal(np.concatenate([getattr(p, field).log_time_ns for p in parts]),
                                      getattr(arrays, field).log_time_ns)
    np.testing.assert_array_equal(np.concatenate([p.motor_current.effort['azimuth'] for p in parts]),
                                  arrays.motor_current.effort['azimuth'])
