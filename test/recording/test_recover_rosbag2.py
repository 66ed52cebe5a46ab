"""``recover`` on rosbag2's own test bags (test/data/rosbag2, Apache-2.0 copies): the metadata.yaml it writes is
read with the rules of rosbag2's YAML decoder, keeps the source's version, and keeps topics with no message.

The decoder rules mirrored here (rosbag2_storage/include/rosbag2_storage/yaml.hpp and src/rosbag2_storage/qos.cpp,
rosbag2 at 25304dd): ``version`` an int; ``storage_identifier``; ``duration.nanoseconds``;
``starting_time.nanoseconds_since_epoch``; ``message_count``; ``topics_with_message_count`` a sequence of
``{topic_metadata: {name, type, serialization_format, offered_qos_profiles, type_description_hash (version >= 7)},
message_count}``; ``offered_qos_profiles`` a YAML sequence of profiles for version >= 9, a *string* holding that
sequence for versions 4..8 (``node.as<std::string>()`` on a sequence throws a bad conversion); a profile's
``history`` is a number in 0..3 (then reliability, durability and liveliness are numbers too) or, from version 9, a
name; ``depth`` an int; ``deadline``, ``lifespan`` and ``liveliness_lease_duration`` ``{sec, nsec}`` unsigned;
``avoid_ros_namespace_conventions`` a bool; ``relative_file_paths`` strings; ``compression_format`` and
``compression_mode`` strings (version >= 3); ``files`` (version >= 5) ``{path, starting_time, duration,
message_count}``; ``custom_data`` a map of strings (version >= 6); ``ros_distro`` a string (version >= 8).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from rosbags.rosbag2 import Reader

from gimbal_friction.recording.recover import recover

DATA = Path(__file__).resolve().parents[1] / 'data' / 'rosbag2'
BAGS = {  # bag: (metadata version, topic with no message)
    'sqlite3/bag_with_topics_and_service_events': (8, '/events/write_split'),
    'sqlite3/cdr_test': (7, None),
    'sqlite3/talker': (4, '/parameter_events'),
    'mcap/bag_with_topics_and_service_events': (8, '/events/write_split'),
}
_NAMES = {'history': {'system_default', 'keep_last', 'keep_all', 'unknown'},
          'reliability': {'system_default', 'reliable', 'best_effort', 'unknown', 'best_available'},
          'durability': {'system_default', 'transient_local', 'volatile', 'unknown', 'best_available'},
          'liveliness': {'system_default', 'automatic', 'manual_by_topic', 'unknown', 'best_available'}}


class BadConversionError(AssertionError):
    """What yaml-cpp's ``as<T>()`` throws (YAML::TypedBadConversionError)."""


def _as(node: Any, kind: type | tuple[type, ...], where: str) -> Any:
    if isinstance(node, bool) and kind in (int, (int,)):
        raise BadConversionError(f'{where}: a bool, not an int')
    if not isinstance(node, kind):
        raise BadConversionError(f'{where}: {type(node).__name__} {node!r}, not {kind}')
    return node


def _uint(node: Any, where: str) -> int:
    value = _as(node, int, where)
    if value < 0:
        raise BadConversionError(f'{where}: negative')
    return int(value)


def _time(node: Any, where: str) -> None:
    _as(node, dict, where)
    _uint(node.get('sec'), f'{where}.sec')
    _uint(node.get('nsec'), f'{where}.nsec')


def _qos_profile(p: Any, where: str) -> None:
    """convert<rclcpp::QoS>::decode: the history's type tells numbers (<= 8) from names (9)."""
    _as(p, dict, where)
    history = p.get('history')
    numbers = isinstance(history, int) and not isinstance(history, bool) and 0 <= history <= 3
    for policy in ('history', 'reliability', 'durability', 'liveliness'):
        value = p.get(policy)
        if numbers:
            _as(value, int, f'{where}.{policy}')
        elif value not in _NAMES[policy]:
            raise BadConversionError(f'{where}.{policy}: {value!r} is no rmw policy name')
    if p.get('history') in (1, 'keep_last'):
        _as(p.get('depth'), int, f'{where}.depth')
    for name in ('deadline', 'lifespan', 'liveliness_lease_duration'):
        _time(p.get(name), f'{where}.{name}')
    _as(p.get('avoid_ros_namespace_conventions'), bool, f'{where}.avoid_ros_namespace_conventions')


def decode_metadata(text: str) -> dict[str, Any]:
    """metadata.yaml read as rosbag2's decoder reads it (the module notes); BadConversionError where it would throw.
    Returns ``{version, topics: {name: (message_count, [profiles])}, message_count}``."""
    info = _as(yaml.safe_load(text), dict, 'document')['rosbag2_bagfile_information']
    version = _as(info.get('version'), int, 'version')
    _as(info.get('storage_identifier'), str, 'storage_identifier')
    _uint(_as(info.get('duration'), dict, 'duration').get('nanoseconds'), 'duration.nanoseconds')
    _uint(_as(info.get('starting_time'), dict, 'starting_time').get('nanoseconds_since_epoch'), 'starting_time')
    total = _uint(info.get('message_count'), 'message_count')
    topics = {}
    for i, entry in enumerate(_as(info.get('topics_with_message_count'), list, 'topics_with_message_count')):
        where = f'topics_with_message_count[{i}]'
        meta = _as(_as(entry, dict, where).get('topic_metadata'), dict, f'{where}.topic_metadata')
        name = _as(meta.get('name'), str, f'{where}.name')
        _as(meta.get('type'), str, f'{where}.type')
        _as(meta.get('serialization_format'), str, f'{where}.serialization_format')
        profiles: list[Any] = []
        if version >= 9:
            profiles = _as(meta.get('offered_qos_profiles'), list, f'{where}.offered_qos_profiles (version 9)')
        elif version >= 4:
            text_qos = _as(meta.get('offered_qos_profiles'), str, f'{where}.offered_qos_profiles (version {version})')
            profiles = yaml.safe_load(text_qos) or []
            _as(profiles, list, f'{where}.offered_qos_profiles parsed')
        for k, p in enumerate(profiles):
            _qos_profile(p, f'{where}.offered_qos_profiles[{k}]')
        if version >= 7:
            _as(meta.get('type_description_hash'), str, f'{where}.type_description_hash')
        topics[name] = (_uint(entry.get('message_count'), f'{where}.message_count'), profiles)
    for k, path in enumerate(_as(info.get('relative_file_paths'), list, 'relative_file_paths')):
        _as(path, str, f'relative_file_paths[{k}]')
    if version >= 3:
        _as(info.get('compression_format'), str, 'compression_format')
        _as(info.get('compression_mode'), str, 'compression_mode')
    if version >= 5:
        for k, f in enumerate(_as(info.get('files'), list, 'files')):
            _as(_as(f, dict, f'files[{k}]').get('path'), str, f'files[{k}].path')
            _uint(_as(f.get('starting_time'), dict, 'x').get('nanoseconds_since_epoch'), f'files[{k}].starting_time')
            _uint(_as(f.get('duration'), dict, 'x').get('nanoseconds'), f'files[{k}].duration')
            _uint(f.get('message_count'), f'files[{k}].message_count')
    if version >= 6 and info.get('custom_data') is not None:   # (rosbag2's own bags write ~)
        for key, value in _as(info.get('custom_data'), dict, 'custom_data').items():
            _as(key, str, 'custom_data key')
            _as(value, str, f'custom_data.{key}')
    if version >= 8:
        _as(info.get('ros_distro'), str, 'ros_distro')
    return {'version': version, 'topics': topics, 'message_count': total}


@pytest.mark.parametrize('bag', sorted(BAGS))
def test_the_sources_read_by_the_rules(bag: str) -> None:
    """The checker reads rosbag2's own files (so it is not stricter than rosbag2)."""
    doc = decode_metadata((DATA / bag / 'metadata.yaml').read_text())
    assert doc['version'] == BAGS[bag][0]


def test_the_checker_refuses_a_list_where_the_version_needs_a_string() -> None:
    """What recover wrote before: version 9 with the old string, or an old version with a list."""
    text = (DATA / 'sqlite3/cdr_test/metadata.yaml').read_text()
    with pytest.raises(BadConversionError, match='version 9'):
        decode_metadata(text.replace('version: 7', 'version: 9'))
    doc = yaml.safe_load(text)
    for entry in doc['rosbag2_bagfile_information']['topics_with_message_count']:
        meta = entry['topic_metadata']
        meta['offered_qos_profiles'] = yaml.safe_load(meta['offered_qos_profiles'])
    with pytest.raises(BadConversionError, match='version 7'):
        decode_metadata(yaml.safe_dump(doc))


@pytest.mark.parametrize('bag', sorted(BAGS))
def test_recover_writes_metadata_rosbag2_reads_keeping_version_and_empty_topics(bag: str, tmp_path: Path) -> None:
    version, empty = BAGS[bag]
    source = decode_metadata((DATA / bag / 'metadata.yaml').read_text())
    out = tmp_path / 'recovered'
    result = recover(DATA / bag, out)
    assert result.messages == source['message_count']
    doc = decode_metadata((out / 'metadata.yaml').read_text())
    assert doc['version'] == version
    assert doc['message_count'] == source['message_count']
    assert {n: c for n, (c, _) in doc['topics'].items()} == {n: c for n, (c, _) in source['topics'].items()}
    for name, (_, profiles) in source['topics'].items():
        assert doc['topics'][name][1] == profiles, name   # the same QoS, in the form of the version
    if empty is not None:
        assert doc['topics'][empty][0] == 0
    # and rosbags' reader (its own metadata.yaml rules) opens it as it opens the source
    with Reader(DATA / bag) as before, Reader(out) as after:
        assert after.message_count == before.message_count
        assert sorted(c.topic for c in after.connections) == sorted(c.topic for c in before.connections)
        assert sum(1 for _ in after.messages()) == sum(1 for _ in before.messages())


def test_a_bag_whose_metadata_was_lost_gets_version_9_with_lists(tmp_path: Path) -> None:
    folder = tmp_path / 'no_meta'
    shutil.copytree(DATA / 'mcap/bag_with_topics_and_service_events', folder)
    (folder / 'metadata.yaml').unlink()
    recover(folder, tmp_path / 'out')
    doc = decode_metadata((tmp_path / 'out' / 'metadata.yaml').read_text())
    assert doc['version'] == 9
    assert doc['topics']['/events/write_split'][0] == 0 and doc['topics']['/test_topic1'][1]
