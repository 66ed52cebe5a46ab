"""chamber_replay with real rclpy and DDS: only the three input topics go into the live graph by default (not the
bag's /rosout or /diagnostics), others by name or '*', and bad parameters or bags end in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from gimbal_friction.recording import topics

from .test_bags_replay import recorded_with_all

pytestmark = pytest.mark.ros


def publishers_of(probe, node: str) -> dict[str, list[str]]:
    return dict(probe.node.get_publisher_names_and_types_by_node(node, '/'))


def wait_for_publishers(probe, node: str, names: set[str]) -> dict[str, list[str]]:
    probe.spin_until(lambda: node in probe.node.get_node_names() and names <= set(publishers_of(probe, node)),
                     what=f'{node} publishing {sorted(names)}')
    return publishers_of(probe, node)


def playing(out: str) -> set[str]:
    """The topics chamber_replay says it plays (its log line 'playing BAG at Rx: /topic (n), ...')."""
    line = next(x for x in out.splitlines() if 'playing ' in x)
    return {part.strip().split(' ')[0] for part in line.split('x: ', 1)[1].split(', ')}


@pytest.mark.slow
def test_only_the_inputs_are_published_by_default(tmp_path: Path, spawn, probe, rb) -> None:
    bag = recorded_with_all(tmp_path / 'all.mcap', rb)
    node = spawn('chamber_replay', '--ros-args', '-p', f'bag:={bag}', '-p', 'loop:=true', '-p', 'rate:=0.2')
    published = wait_for_publishers(probe, 'chamber_replay', set(topics.CHAMBER_TOPICS))
    assert '/add/_service_event' not in published  # (/diagnostics: its own status only, not the bag's)
    probe.spin_until(lambda: 'not published' in node.output(), what='the playing log lines')
    code, out = node.stop()
    assert code == 0, out
    assert playing(out) == set(topics.CHAMBER_TOPICS)
    assert 'not published: /add/_service_event, /camera/frame, /diagnostics, /rosout' in out


@pytest.mark.slow
def test_other_topics_by_name_or_star_and_excluded_ones(tmp_path: Path, spawn, probe, rb) -> None:
    bag = recorded_with_all(tmp_path / 'all.mcap', rb)
    node = spawn('chamber_replay', '--ros-args', '-p', f'bag:={bag}', '-p', 'loop:=true', '-p', 'rate:=0.2',
                 '-p', "topics:=['*']", '-p', f"exclude_topics:=['{topics.TEMPERATURE}']")
    published = wait_for_publishers(probe, 'chamber_replay', {'/diagnostics', topics.JOINT_STATES})
    assert published['/diagnostics'] == ['diagnostic_msgs/msg/DiagnosticArray']
    probe.spin_until(lambda: 'not published' in node.output(), what='the playing log lines')
    code, out = node.stop()
    assert code == 0, out
    # acme_msgs and the service event type are not installed; /rosout was asked for with '*'
    assert playing(out) == {topics.JOINT_STATES, topics.MOTOR_CURRENT, '/rosout', '/diagnostics'}


@pytest.mark.parametrize(('param', 'expected'), [
    ('rate:=fast', "parameter 'rate': must be a number"),
    ('topics:=[/nope]', 'no topic /nope in the bag'),
    ("topics:=['/camera/frame']", 'acme_msgs/msg/Frame of /camera/frame is not installed'),
    # used to play nothing and exit 0 / be accepted without comment: refused with the valid range
    ('start_offset_s:=1000.0', "parameter 'start_offset_s' = 1000.0: is beyond the end of the bag: must be from 0 "
     'to '),
    ('wait_for_subscribers:=-1', "parameter 'wait_for_subscribers' = -1: must be >= 0 subscribers (0 = do not wait)"),
    ('wait_timeout_s:=0.0', "parameter 'wait_timeout_s' = 0.0: must be > 0 [s]"),
])
@pytest.mark.slow
def test_bad_parameters_are_one_line(tmp_path: Path, spawn, rb, param: str, expected: str) -> None:
    bag = recorded_with_all(tmp_path / 'all.mcap', rb)
    code, out = spawn('chamber_replay', '--ros-args', '-p', f'bag:={bag}', '-p', param).wait()
    lines = out.strip().splitlines()
    assert code == 1 and len(lines) == 1 and lines[0].startswith('chamber_replay: error: '), out
    assert expected in lines[0]


@pytest.mark.slow
def test_a_cut_bag_is_one_line_pointing_to_recover(tmp_path: Path, spawn, rb) -> None:
    bag = recorded_with_all(tmp_path / 'all.mcap', rb)
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 2])
    code, out = spawn('chamber_replay', '--ros-args', '-p', f'bag:={bag}').wait()
    assert code == 1 and len(out.strip().splitlines()) == 1, out
    assert f'gimbal-friction recover {bag} --out NEW' in out
