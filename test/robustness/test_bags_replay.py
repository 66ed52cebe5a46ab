"""Bags as robots and recorders really make them: recorded with ``--all`` (service events whose schema is raw
``.srv`` text, /rosout, /diagnostics, custom types), bare ``.db3`` files, joints named otherwise. Only the three
input topics are read and copied; bad options are one line."""

from __future__ import annotations

import json
from pathlib import Path

from mcap.writer import Writer as McapWriter

from gimbal_friction.recording.bag import open_chamber_bag
from gimbal_friction.recording.bag_write import write_chamber_bag
from gimbal_friction.recording.cdr import default_typestore
from gimbal_friction.recording.mcap_scan import McapScanner
from gimbal_friction.recording.topics import (
    CHAMBER_TOPICS,
    FEEDFORWARD,
    MEASURED,
    MEASURED_DETAIL,
    RESIDUAL,
    RESIDUAL_DETAIL,
)

GENERATED = {FEEDFORWARD, MEASURED, MEASURED_DETAIL, RESIDUAL, RESIDUAL_DETAIL}


def recorded_with_all(path: Path, rb) -> Path:
    """An MCAP bag as ``ros2 bag record --all`` leaves it on Jazzy/Kilted, with the chamber topics in it."""
    store = default_typestore()
    log_type = 'rcl_interfaces/msg/Log'
    with path.open('wb') as stream:
        writer = McapWriter(stream)
        writer.start(profile='ros2', library='rosbag2 (imitated)')
        channels = {}
        for topic, msgtype in [*CHAMBER_TOPICS.items(), ('/rosout', log_type),
                               ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')]:
            text, digest = store.generate_msgdef(msgtype, ros_version=2)
            schema = writer.register_schema(msgtype, 'ros2msg', text.encode())
            channels[topic] = writer.register_channel(topic, 'cdr', schema, {'topic_type_hash': digest})
        event = writer.register_schema('example_interfaces/srv/AddTwoInts_Event', 'ros2msg',
                                       b'int64 a\nint64 b\n---\nint64 sum\n')  # ros2/rosbag2#2365
        channels['/add/_service_event'] = writer.register_channel('/add/_service_event', 'cdr', event)
        custom = writer.register_schema('acme_msgs/msg/Frame', 'ros2msg', b'acme_msgs/Pixel[] pixels\n')
        channels['/camera/frame'] = writer.register_channel('/camera/frame', 'cdr', custom)
        log = store.types[log_type](stamp=store.types['builtin_interfaces/msg/Time'](sec=1, nanosec=0), level=20,
                                    name='n', msg='hello', file='f', function='g', line=1)
        for topic, msgtype, t, msg in rb.chamber():
            writer.add_message(channels[topic], t, bytes(store.serialize_cdr(msg, msgtype)), t)
            if t % 7 == 0:
                writer.add_message(channels['/rosout'], t, bytes(store.serialize_cdr(log, log_type)), t)
                writer.add_message(channels['/add/_service_event'], t, b'\x00\x01\x00\x00\x07', t)
                writer.add_message(channels['/camera/frame'], t, b'\x00\x01\x00\x00' + bytes(64), t)
        writer.finish()
    return path


def logged_topics(out: Path) -> set[str]:
    found: set[str] = set()
    for path in (out / 'residuals').glob('*.mcap'):
        scan = McapScanner(path)
        for block in scan.blocks():
            found.update(scan.channels[int(c)].topic for c in set(block.channel_id.tolist()))
    return found


def test_a_bag_recorded_with_all_replays_and_only_the_inputs_are_copied(tmp_path: Path, rb) -> None:
    bag = recorded_with_all(tmp_path / 'all.mcap', rb)
    run = rb.run('replay', str(bag), '--out', str(tmp_path / 'out'), '--format', 'json')
    assert run.code == 0, run.err
    inputs = sum(1 for m in rb.chamber())
    assert json.loads(run.out)['messages_in'] == inputs
    assert logged_topics(tmp_path / 'out') <= set(CHAMBER_TOPICS) | GENERATED
    assert set(CHAMBER_TOPICS) <= logged_topics(tmp_path / 'out')
    assert set(open_chamber_bag(bag).ignored_topics) == {'/rosout', '/diagnostics', '/add/_service_event',
                                                         '/camera/frame'}


def test_a_bare_db3_replays(tmp_path: Path, rb) -> None:
    bag = write_chamber_bag(tmp_path / 'bag', rb.chamber(), storage='sqlite3')
    (db3,) = bag.glob('*.db3')
    run = rb.run('replay', str(db3), '--out', str(tmp_path / 'out'), '--format', 'json')
    assert run.code == 0, run.err
    assert json.loads(run.out)['messages_in'] == len(rb.chamber())


def test_joint_and_topic_options_are_checked_on_one_line(tmp_path: Path, small_bag: Path, rb) -> None:
    out = str(tmp_path / 'out')
    assert 'CONFIGURED=RECORDED' in rb.refused(rb.run('replay', str(small_bag), '--out', out, '--joint',
                                                           'elevation'), 'replay')
    assert 'mapped twice' in rb.refused(rb.run('replay', str(small_bag), '--out', out, '--joint', 'elevation=a',
                                                    '--joint', 'elevation=b'), 'replay')
    assert 'mapped twice' in rb.refused(rb.run('replay', str(small_bag), '--out', out, '--joint', 'x=a',
                                                    '--joint', 'y=a'), 'replay')
    line = rb.refused(rb.run('replay', str(small_bag), '--out', out, '--topic', '/joint_states=/nope'), 'replay')
    assert '/joint_states (recorded as /nope) is missing' in line
    assert not (tmp_path / 'out').exists()
