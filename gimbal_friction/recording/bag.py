"""Chamber-test bags: open and check, read the three input streams into arrays, describe them (writing one:
:mod:`~gimbal_friction.recording.bag_write`).
One job in one module: the chamber-test bag (its checks, reading and the refusals of what it lacks share one view).

A chamber-test bag (docs/ros.md "Files") is a rosbag2 bag directory (MCAP or sqlite3 storage, whatever
wrote it) or a bare ``.mcap`` / ``.db3`` file that holds at least the topics of :data:`~.topics.CHAMBER_TOPICS`.
Opening goes through ``rosbags.rosbag2.Reader``. Reading the arrays takes the MCAP files of a bag a chunk at a time
(:class:`~.mcap_scan.McapScanner`) when their chunks follow each other in log time (what recorders write), and
``rosbags``' messages otherwise; either way in the order ``rosbags`` yields them. Only the chamber topics are read
and decoded, in bulk (with :mod:`~gimbal_friction.recording.cdr`), so other topics -- service events, ``/rosout``,
images, types no type store knows -- are listed (:meth:`ChamberBag.describe`) and otherwise ignored. No rclpy is
imported.

Names: every public function speaks *contract* topic names (``/joint_states``, ...). ``topic_map`` maps a contract
name to the name recorded in the bag (``{'/joint_states': '/gimbal/joint_states'}``), as ``--topic`` options do.
``joint_map`` maps a joint name recorded in the bag to the configured one (``{'joint_2': 'elevation'}``); the arrays
carry the configured names.

Times: ``log_time_ns`` is the bag's receive/log time [ns]; ``stamp_ns`` is ``header.stamp`` [ns]. Both are int64
and both are kept as recorded (a zero stamp stays zero: the rule that falls back to the log time is the core's).
"""

from __future__ import annotations

import difflib
import struct
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import yaml
from rosbags.rosbag2 import Reader
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError, get_types_from_idl, get_types_from_msg, get_typestore

from gimbal_friction.common.units import join_stamp
from gimbal_friction.recording.cdr import (
    DEFAULT_STORE,
    JointStateColumns,
    default_typestore,
    distinct,
    temperature_rows,
)
from gimbal_friction.recording.errors import LIBRARY_READ_ERRORS, EmptyInputError, RecordingError, recover_hint
from gimbal_friction.recording.mcap_scan import McapScanner, chunk_time_ranges
from gimbal_friction.recording.topics import (
    CHAMBER_TOPICS,
    JOINT_STATE_TYPE,
    JOINT_STATES,
    MOTOR_CURRENT,
    REFERENCE_VELOCITY,
    TEMPERATURE,
)
from gimbal_friction.streams.arrays import ChamberArrays, JointStateArrays, TemperatureArrays

if TYPE_CHECKING:
    import os
    from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
    from typing import TypeAlias

    from numpy.typing import NDArray
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    #: ``read_arrays`` raw-message callback: the input messages of a batch, as recorded
    RawSink: TypeAlias = Callable[['RawBatch'], None]

__all__ = [
    'BAG_SUFFIXES',
    'CDR',
    'DEFAULT_STORE',
    'BagDescription',
    'ChamberArrays',
    'ChamberBag',
    'DecodedMessage',
    'JointStateArrays',
    'JointSummary',
    'RawBatch',
    'RawMessage',
    'StreamSummary',
    'TemperatureArrays',
    'TopicInfo',
    'default_typestore',
    'foreign_serialization',
    'open_chamber_bag',
    'unsupported_serialization',
]

#: storage files a bag may be given as directly (a bare file)
BAG_SUFFIXES = ('.mcap', '.db3')
#: the fastest safe YAML loader (libyaml's when PyYAML has it)
_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
#: what decoding a message with the type store raises on bytes that are not that message
_DECODE_ERRORS = (SerdeError, TypesysError, KeyError, ValueError, IndexError, struct.error, AssertionError)


# ----------------------------------------------------------------------------------------------------------------
# records


class TopicInfo(NamedTuple):
    """One topic of a bag, under its contract name."""

    msgtype: str
    """Message type, e.g. ``sensor_msgs/msg/JointState`` ('' if the topic has several)."""
    messages: int
    """Number of messages [-]."""


class RawMessage(NamedTuple):
    """One serialized message as stored in the bag, for a node that republishes raw bytes."""

    topic: str
    """Contract topic name."""
    msgtype: str
    """Message type."""
    log_time_ns: int
    """Log (receive) time [ns]."""
    data: bytes
    """CDR bytes, encapsulation header included (what ``rclpy`` raw publishers take)."""


class DecodedMessage(NamedTuple):
    """One message decoded with the bag's type store (a rosbags message dataclass)."""

    topic: str
    """Contract topic name."""
    log_time_ns: int
    """Log (receive) time [ns]."""
    msg: object
    """rosbags message dataclass (``msg.header.stamp.sec`` ...)."""


class JointSummary(NamedTuple):
    """What a JointState topic carries for one joint."""

    name: str
    """Joint name as reported (after ``joint_map``)."""
    recorded_name: str
    """Joint name in the bag."""
    messages: int
    """Messages with at least one value for this joint [-]."""
    position: int
    """Messages with a position for this joint [-]."""
    velocity: int
    """Messages with a velocity for this joint [-]."""
    effort: int
    """Messages with an effort for this joint [-]."""


class StreamSummary(NamedTuple):
    """One input stream of a chamber-test bag, as read."""

    topic: str
    """Contract topic name."""
    bag_topic: str
    """Topic name in the bag."""
    msgtype: str
    """Message type."""
    messages: int
    """Messages [-]."""
    zero_stamps: int
    """Messages whose ``header.stamp`` is zero [-]."""
    first_log_ns: int
    """Log time of the first message [ns] (0 without messages)."""
    last_log_ns: int
    """Log time of the last message [ns] (0 without messages)."""
    joints: tuple[JointSummary, ...]
    """Per joint (JointState topics only), in the order first seen."""


class BagDescription(NamedTuple):
    """What a chamber-test bag holds: its three input streams as read, and the topics not read."""

    path: Path
    streams: dict[str, StreamSummary]
    """Contract topic name -> summary, for the three chamber topics."""
    ignored: dict[str, str]
    """Bag topic -> message type ('' for several), for the topics no input uses (not read)."""

    def joint_names(self, topic: str) -> tuple[str, ...]:
        """Joint names (reported) of a JointState input stream, in the order first seen."""
        return tuple(j.name for j in self.streams[topic].joints)

    def findings(self, axes: Sequence[str] = ()) -> list[str]:
        """One-line reasons why a replay of this bag for the configured ``axes`` may match nothing.

        Covers: an axis absent from ``/joint_states`` (with the joints seen), a joint state without velocity or
        position, a motor-current topic without effort for an axis, header stamps that are all (or partly) zero,
        and the topics that are not read. Empty when nothing looks wrong.
        """
        out: list[str] = []
        js = self.streams[JOINT_STATES]
        mc = self.streams[MOTOR_CURRENT]
        for axis in axes:
            seen = {j.name: j for j in js.joints}
            if axis not in seen:
                names = ', '.join(repr(j.recorded_name) for j in js.joints) or 'none'
                out.append(f'axis {axis!r} is not in {js.bag_topic} (joints seen: {names}); map a recorded joint '
                           f'to it with --joint {axis}=RECORDED_NAME')
                continue
            joint = seen[axis]
            if joint.velocity == 0:
                out.append(f'{js.bag_topic} carries no velocity for {axis!r} ({joint.messages} messages): the '
                           f'estimator and the feedforward need it')
            elif joint.velocity < joint.messages:
                out.append(f'{js.bag_topic}: {joint.messages - joint.velocity} of {joint.messages} messages carry '
                           f'no velocity for {axis!r}')
            current = {j.name: j for j in mc.joints}.get(axis)
            if current is None or current.effort == 0:
                names = ', '.join(f'{j.recorded_name!r} ({j.effort} with effort)' for j in mc.joints) or 'none'
                out.append(f'{mc.bag_topic} (motor current) carries no effort for {axis!r} (joints: {names}); '
                           f'is --topic {MOTOR_CURRENT}=... the right topic?')
        for stream in self.streams.values():
            if stream.messages and stream.zero_stamps == stream.messages:
                out.append(f'{stream.bag_topic}: every header stamp is zero ({stream.messages} messages); only the '
                           f'log time orders them')
            elif stream.zero_stamps:
                out.append(f'{stream.bag_topic}: {stream.zero_stamps} of {stream.messages} header stamps are zero')
        if self.ignored:
            listed = ', '.join(f'{t} ({m or "several types"})' for t, m in sorted(self.ignored.items()))
            out.append(f'not read (no input uses them): {listed}')
        return out


# ----------------------------------------------------------------------------------------------------------------
# opening


def _check_path(bag: Path) -> None:
    """Refuse what is not a bag directory or a bare storage file, with the reason."""
    if not bag.exists():
        msg = f'not a rosbag2 bag: {bag} (no such file or directory)'
        raise RecordingError(msg)
    if bag.is_dir():
        if (bag / 'metadata.yaml').is_file():
            return
        stored = sorted(p.name for p in bag.iterdir() if p.suffix in BAG_SUFFIXES)
        if stored:
            phrase = foreign_serialization(bag)
            if phrase is not None:
                raise unsupported_serialization(bag, phrase)
            msg = (f'not a rosbag2 bag: {bag} has {", ".join(stored[:3])}{" ..." if len(stored) > 3 else ""} but no '
                   f'metadata.yaml (a recording cut short?); {recover_hint(bag)}')
        else:
            msg = f'not a rosbag2 bag: {bag} (directory without metadata.yaml)'
        raise RecordingError(msg)
    if bag.suffix not in BAG_SUFFIXES:
        msg = f'not a rosbag2 bag: {bag} (expected a bag directory, a .mcap or a .db3 file)'
        raise RecordingError(msg)


def _read_error(bag: Path, doing: str, err: BaseException) -> RecordingError:
    """A one-line RecordingError for a library error met while reading ``bag``, with the way out."""
    text = str(err).strip().splitlines()[0] if str(err).strip() else ''
    reason = f'{type(err).__name__}: {text}' if text else type(err).__name__
    return RecordingError(f'bag {bag}: {doing} failed ({reason}): the bag is damaged or cut short; '
                          f'{recover_hint(bag)}')


def _name_likeness(contract: str, topic: str) -> tuple[bool, float, float]:
    """How much a bag topic's name looks like a contract topic's: the same last name, then the likeness of the last
    names, then of the whole names (:class:`difflib.SequenceMatcher` ratios, 0..1)."""
    leaf, tail = contract.rsplit('/', 1)[-1], topic.rsplit('/', 1)[-1]
    return (tail == leaf, difflib.SequenceMatcher(None, leaf, tail).ratio(),
            difflib.SequenceMatcher(None, contract, topic).ratio())


def suggest_topics(missing: Sequence[str], bag_topics: Mapping[str, tuple[str, int]], taken: Sequence[str] = ()
                   ) -> dict[str, list[str]]:
    """Per missing contract topic, the bag topics of its type (not ``taken`` by an input already found), the likely
    one first: each bag topic goes to at most one missing input, the pairs of most alike names first
    (:func:`_name_likeness`); the candidates no other input took follow, most alike first.

    >>> bag = {'/arm/bearing_temp': ('sensor_msgs/msg/Temperature', 9),
    ...        '/arm/joints': ('sensor_msgs/msg/JointState', 9),
    ...        '/arm/drive_current': ('sensor_msgs/msg/JointState', 9)}
    >>> wanted = ['/gimbal/temperature', '/joint_states', '/gimbal/motor_current']
    >>> for contract, found in suggest_topics(wanted, bag).items():
    ...     print(contract, found)
    /gimbal/temperature ['/arm/bearing_temp']
    /joint_states ['/arm/joints']
    /gimbal/motor_current ['/arm/drive_current']
    """
    free = {t: m for t, (m, _) in bag_topics.items() if t not in set(taken)}
    pairs = sorted(((_name_likeness(c, t), c, t) for c in missing for t, m in free.items() if m == CHAMBER_TOPICS[c]),
                   key=lambda p: p[0], reverse=True)
    chosen: dict[str, str] = {}
    used: set[str] = set()
    for _, contract, topic in pairs:
        if contract not in chosen and topic not in used:
            chosen[contract] = topic
            used.add(topic)
    out: dict[str, list[str]] = {}
    for contract in missing:
        rest = [t for _, c, t in pairs if c == contract and t not in used]
        out[contract] = ([chosen[contract]] if contract in chosen else []) + rest
    return out


def _missing_topics(bag: Path, missing: Sequence[str], mapping: Mapping[str, str],
                    bag_topics: Mapping[str, tuple[str, int]]) -> RecordingError:
    """The one-line refusal naming every missing input topic and the option that maps them (``--topic``), with the
    bag topics of the right type as the candidates, the likely one by name first (:func:`suggest_topics`)."""
    shown = [c if mapping.get(c, c) == c else f'{c} (recorded as {mapping[c]})' for c in missing]
    have = ', '.join(f'{t} ({m or "several types"})' for t, (m, _) in sorted(bag_topics.items())) or 'none'
    taken = [mapping.get(c, c) for c in CHAMBER_TOPICS if c not in missing]
    candidates = suggest_topics(missing, bag_topics, taken)
    examples, notes = [], []
    for contract in missing:
        found = candidates[contract]
        examples.append(f'--topic {contract}={found[0] if found else "BAG_TOPIC"}')
        if not found:
            notes.append(f'no {CHAMBER_TOPICS[contract]} topic in the bag for {contract}')
        elif len(found) > 1:
            notes.append(f'other {CHAMBER_TOPICS[contract]} topics for {contract}: {", ".join(found[1:])}')
    what = f'required topic {shown[0]} is' if len(shown) == 1 else f'required topics {", ".join(shown)} are'
    return RecordingError(f'bag {bag}: {what} missing (topics in bag: {have}); map each to the topic it was '
                          f'recorded under with {" ".join(examples)}{" (" + "; ".join(notes) + ")" if notes else ""} '
                          f'(chamber_replay: the same CONTRACT=BAG entries in its parameter topic_map)')


#: the one message serialization the readers decode: ROS 2's CDR, what ``ros2 bag record`` writes
CDR = 'cdr'
_ROS2_PROFILE = 'ros2'


def _formats_phrase(formats: Mapping[str, str]) -> str:
    """``{topic: format}`` -> "serialized as 'json' (/a, /b), not CDR"."""
    by_format: dict[str, list[str]] = {}
    for topic, fmt in sorted(formats.items()):
        by_format.setdefault(fmt, []).append(topic)
    parts = [f'{fmt!r} ({", ".join(t[:3])}{" ..." if len(t) > 3 else ""})' for fmt, t in by_format.items()]
    return f'its messages are serialized as {" and ".join(parts)}, not CDR'


def unsupported_serialization(path: object, phrase: str, *, prefix: str = 'bag') -> RecordingError:
    """The one-line refusal of a bag that is not damaged but in a serialization the readers do not decode
    (``phrase``: what :func:`foreign_serialization` says; ``prefix``: what the line starts with)."""
    return RecordingError(f'{prefix} {path}: {phrase}: not supported (gimbal-friction reads ROS 2 bags whose '
                          f'messages are CDR, as ros2 bag record writes them); it is not damaged (nothing for '
                          f'recover to do): record it, or convert it, as a ROS 2 (CDR) bag')


def foreign_serialization(path: str | os.PathLike[str]) -> str | None:
    """Why a bag (folder, ``.mcap`` or ``.db3``) is one the readers cannot decode, as a phrase; None if its
    serialization is CDR or cannot be told (a damaged file: then recovery may help).

    Not decodable (rosbags refuses to open the whole bag): rosbag2 metadata listing a topic whose
    ``serialization_format`` is not ``cdr``; an MCAP file whose profile is not ``ros2`` or with a channel whose
    ``message_encoding`` is not ``cdr``; and a sqlite3 file none of whose topics is CDR (rosbags opens one with
    some foreign topics, and only the inputs are decoded). A few records are read: the metadata, the MCAP header
    and summary (or first chunk), the sqlite3 ``topics`` table.
    """
    bag = Path(path)
    if bag.is_dir():
        meta = _metadata_formats(bag / 'metadata.yaml')
        foreign = {t: f for t, f in (meta or {}).items() if f != CDR}
        if foreign:
            return _formats_phrase(foreign)
        files = sorted(p for p in bag.iterdir() if p.suffix in BAG_SUFFIXES and p.is_file())
        for file in files:
            phrase = _file_serialization(file)
            if phrase is not None:
                return f'{file.name}: {phrase}' if len(files) > 1 else phrase
        return None
    return _file_serialization(bag) if bag.is_file() else None


def _metadata_formats(path: Path) -> dict[str, str] | None:
    """Topic -> serialization format of a rosbag2 metadata.yaml (None if absent or unreadable)."""
    import yaml

    try:
        entries = yaml.safe_load(path.read_text(encoding='utf-8'))['rosbag2_bagfile_information'][
            'topics_with_message_count']
        return {str(e['topic_metadata']['name']): str(e['topic_metadata']['serialization_format'])
                for e in entries}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError, IndexError):
        return None


def _file_serialization(path: Path) -> str | None:
    """:func:`foreign_serialization` of one storage file."""
    if path.suffix == '.mcap':
        from gimbal_friction.recording.mcap_scan import McapScanner

        scan = McapScanner(path)
        blocks = scan.blocks()
        try:
            next(blocks, None)  # the header, the summary (complete file) or the first chunk's channels
        except RecordingError:
            return None
        finally:
            blocks.close()
        formats = {c.topic: c.message_encoding for c in scan.channels.values()}
        profile = scan.report.profile
        if profile is not None and profile != _ROS2_PROFILE:
            shown = f', {_formats_phrase(formats)}' if formats else ''
            return f'an MCAP file of profile {profile!r}, not {_ROS2_PROFILE!r}{shown}'
        foreign = {t: f for t, f in formats.items() if f != CDR}
        return _formats_phrase(foreign) if foreign else None  # rosbags opens no MCAP with a foreign channel
    if path.suffix == '.db3':
        import sqlite3
        from urllib.parse import quote

        try:
            con = sqlite3.connect(f'file:{quote(str(path.resolve()))}?mode=ro&immutable=1', uri=True)
            try:
                rows = con.execute('SELECT name, serialization_format FROM topics').fetchall()
            finally:
                con.close()
        except (sqlite3.Error, OSError):
            return None
        formats = {str(name): str(fmt) for name, fmt in rows}
        if formats and all(f != CDR for f in formats.values()):
            return _formats_phrase(formats)
    return None


def open_chamber_bag(
    path: str | os.PathLike[str],
    topic_map: Mapping[str, str] | None = None,
    *,
    joint_map: Mapping[str, str] | None = None,
    typestore: Typestore | None = None,
    axes: Sequence[str] | None = None,
) -> ChamberBag:
    """Open a chamber-test bag and check it holds the contract's input topics with the right types.

    Args:
        path: rosbag2 bag directory (MCAP or sqlite3 storage) or a bare ``.mcap`` or ``.db3`` file.
        topic_map: contract topic name -> topic name in the bag, for bags recorded under other names.
        joint_map: joint name recorded in the bag -> configured joint name; the arrays carry the configured names.
        typestore: type store for the messages the fast decoders do not read (default :data:`DEFAULT_STORE`).
        axes: the configured axes (joint names after ``joint_map``). Given, a read of the arrays
            (:meth:`~ChamberBag.read_arrays`, the end of :meth:`~ChamberBag.iter_arrays`) that finds none of them
            with both a joint state and a motor current raises :class:`~.errors.EmptyInputError`.

    Raises:
        RecordingError: not a bag, unreadable (cut short or damaged: the message names ``gimbal-friction recover``),
            not CDR (:func:`foreign_serialization`: not supported, recovery would not help), required topics
            missing (all named, with ``--topic``), empty or of another type (the message names the topic), or a bad
            map.
    """
    bag = Path(path)
    _check_path(bag)
    mapping = dict(topic_map or {})
    for contract, recorded in mapping.items():
        if not contract or not recorded:
            msg = f'topic map entry {contract!r} -> {recorded!r}: both names must be non-empty'
            raise RecordingError(msg)
    joints = dict(joint_map or {})
    for recorded, configured in joints.items():
        if not recorded or not configured:
            msg = f'joint map entry {recorded!r} -> {configured!r}: both names must be non-empty'
            raise RecordingError(msg)
    targets = list(joints.values())
    for name in set(targets):
        if targets.count(name) > 1:
            sources = ', '.join(repr(k) for k, v in joints.items() if v == name)
            msg = f'joint map: recorded joints {sources} are all mapped to {name!r}; map one joint to each name'
            raise RecordingError(msg)
    try:
        with Reader(bag) as reader:
            bag_topics: dict[str, tuple[str, int]] = {}
            for name, info in reader.topics.items():
                bag_topics[name] = (info.msgtype or '', int(info.msgcount))
            formats = {c.topic: str(getattr(c.ext, 'serialization_format', CDR) or CDR) for c in reader.connections}
            count = reader.message_count
            start_ns = reader.start_time if count else 0
            duration_ns = max(0, reader.end_time - 1 - reader.start_time) if count else 0
    except LIBRARY_READ_ERRORS as err:
        phrase = foreign_serialization(bag)  # not damaged: another format (recover would not help)
        if phrase is not None:
            raise unsupported_serialization(bag, phrase) from err
        raise _read_error(bag, 'opening', err) from err

    # contract name -> bag name for every visible topic: mapped ones; the input topics under their own name
    # when not remapped (even if another input is mapped onto the same bag topic); then other bag topics under
    # their own name unless already mapped or shadowed by a remapped contract name
    contract_to_bag: dict[str, str] = {}
    for contract, recorded in mapping.items():
        if recorded in bag_topics:
            contract_to_bag[contract] = recorded
    for contract in CHAMBER_TOPICS:
        if contract not in mapping and contract in bag_topics:
            contract_to_bag[contract] = contract
    mapped_bag_names = set(contract_to_bag.values())
    for name in bag_topics:
        if name not in mapping and name not in mapped_bag_names:
            contract_to_bag[name] = name

    missing = [c for c in CHAMBER_TOPICS if c not in contract_to_bag]
    if missing:
        raise _missing_topics(bag, missing, mapping, bag_topics)
    for contract, want in CHAMBER_TOPICS.items():
        recorded = mapping.get(contract, contract)
        shown = contract if recorded == contract else f'{contract} (recorded as {recorded})'
        msgtype, n = bag_topics[contract_to_bag[contract]]
        if msgtype != want:
            got = msgtype or 'several types'
            msg = f'bag {bag}: required topic {shown} has type {got}, expected {want}'
            raise RecordingError(msg)
        if n <= 0:
            msg = f'bag {bag}: required topic {shown} has no messages'
            raise RecordingError(msg)

    read = [*CHAMBER_TOPICS, *([REFERENCE_VELOCITY] if REFERENCE_VELOCITY in contract_to_bag else [])]
    foreign = {contract_to_bag[c]: formats.get(contract_to_bag[c], CDR) for c in read}
    foreign = {t: f for t, f in foreign.items() if f != CDR}
    if foreign:
        raise unsupported_serialization(bag, _formats_phrase(foreign))

    topics = {contract: TopicInfo(*bag_topics[recorded]) for contract, recorded in contract_to_bag.items()}
    return ChamberBag(
        path=bag,
        topic_map=contract_to_bag,
        topics=topics,
        start_ns=int(start_ns),
        duration_ns=int(duration_ns),
        typestore=typestore,
        joint_map=joints,
        axes=axes,
    )


# ----------------------------------------------------------------------------------------------------------------
# the bag


class ChamberBag:
    """A checked chamber-test bag; every read opens (and always closes) its own reader.

    Built by :func:`open_chamber_bag`. Topics are named by their contract name. Reads default to the three input
    topics (:data:`~.topics.CHAMBER_TOPICS`); others are read only when asked for by name.
    """

    def __init__(
        self,
        *,
        path: Path,
        topic_map: dict[str, str],
        topics: dict[str, TopicInfo],
        start_ns: int,
        duration_ns: int,
        typestore: Typestore | None,
        joint_map: dict[str, str] | None = None,
        axes: Sequence[str] | None = None,
    ) -> None:
        """Hold what :func:`open_chamber_bag` found (use that function, not this constructor)."""
        self.path = path
        #: contract topic name -> topic name in the bag, for every visible topic
        self.topic_map = topic_map
        #: contract topic name -> (msgtype, message count), for every visible topic
        self.topics = topics
        #: log time of the first message of the bag [ns]
        self.start_ns = start_ns
        #: log time of the last message minus that of the first [ns]
        self.duration_ns = duration_ns
        self._typestore = typestore
        #: recorded joint name -> configured joint name
        self.joint_map = dict(joint_map or {})
        #: configured axes a read of the arrays must find (empty: not checked)
        self.axes = tuple(axes or ())
        self._bag_to_contracts: dict[str, list[str]] = {}
        for contract, recorded in topic_map.items():
            self._bag_to_contracts.setdefault(recorded, []).append(contract)
        self._private_store: Typestore | None = None

    @property
    def typestore(self) -> Typestore:
        """The type store for the messages the fast decoders do not read: the one given to
        :func:`open_chamber_bag`, else :func:`~.cdr.default_typestore` (built on first use: a bag of plain CDR
        messages is read without one)."""
        return self._typestore if self._typestore is not None else default_typestore()

    def __repr__(self) -> str:
        """Path and topics."""
        return f'ChamberBag({str(self.path)!r}, topics={self.topics!r})'

    @property
    def message_count(self) -> int:
        """Messages on the three input topics [-] (what a replay reads)."""
        counts = {self.topic_map[t]: self.topics[t].messages for t in CHAMBER_TOPICS}  # a bag topic counted once
        return sum(counts.values())

    @property
    def end_ns(self) -> int:
        """Log time of the last message [ns]."""
        return self.start_ns + self.duration_ns

    @property
    def ignored_topics(self) -> dict[str, str]:
        """Bag topic -> message type ('' for several) of the topics no input uses (not read by default)."""
        used = {self.topic_map[t] for t in CHAMBER_TOPICS}
        if self.has_reference:
            used.add(self.topic_map[REFERENCE_VELOCITY])
        out = {}
        for contract, recorded in self.topic_map.items():
            if recorded not in used:
                out[recorded] = self.topics[contract].msgtype
        return out

    # -- iteration -------------------------------------------------------------------------------------------

    def _select(self, topics: Iterable[str] | None) -> dict[str, list[str]]:
        """Bag topic name -> requested contract names (the three input topics for None)."""
        wanted = list(CHAMBER_TOPICS) if topics is None else [topics] if isinstance(topics, str) else list(topics)
        selected: dict[str, list[str]] = {}
        for name in wanted:
            if name not in self.topic_map:
                have = ', '.join(sorted(self.topic_map)) or 'none'
                msg = f'bag {self.path}: no topic {name} (topics: {have})'
                raise RecordingError(msg)
            contracts = selected.setdefault(self.topic_map[name], [])
            if name not in contracts:
                contracts.append(name)
        return selected

    def _messages(self, selected: Mapping[str, Sequence[str]]) -> Iterator[tuple[Connection, int, bytes]]:
        """Raw messages of the selected bag topics in log-time order (per storage file, as recorded)."""
        try:
            with Reader(self.path) as reader:
                conns = [c for c in reader.connections if c.topic in selected]
                if not conns:  # an empty list would mean "every connection" to rosbags
                    return
                yield from reader.messages(connections=conns)
        except LIBRARY_READ_ERRORS as err:
            raise _read_error(self.path, 'reading', err) from err

    def iter_raw(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Serialized messages ``(contract_topic, msgtype, log_time_ns, cdr_bytes)`` in log-time order.

        A bag topic mapped to two contract topics yields each message once per contract topic.

        Args:
            topics: contract (or other bag) topic names to read (default: the three input topics).
        """
        selected = self._select(topics)
        for conn, log_time, data in self._messages(selected):
            for topic in selected[conn.topic]:
                yield RawMessage(topic, conn.msgtype, log_time, data)

    def iter_decoded(self, topics: Iterable[str] | None = None) -> Iterator[DecodedMessage]:
        """Decoded messages ``(contract_topic, log_time_ns, msg)`` in log-time order (rosbags dataclasses).

        Args:
            topics: contract (or other bag) topic names to read (default: the three input topics). A type the
                type store lacks is taken from the bag's message definition.
        """
        selected = self._select(topics)
        for conn, log_time, data in self._messages(selected):
            message = self._decode(data, conn, log_time)
            for topic in selected[conn.topic]:
                yield DecodedMessage(topic, log_time, message)

    # -- arrays ----------------------------------------------------------------------------------------------

    @property
    def has_reference(self) -> bool:
        """The bag holds ``/gimbal/reference_velocity`` as sensor_msgs/JointState (read by :meth:`read_arrays`)."""
        info = self.topics.get(REFERENCE_VELOCITY)
        return info is not None and info.msgtype == JOINT_STATE_TYPE and info.messages > 0

    def read_arrays(self, raw_sink: RawSink | None = None) -> ChamberArrays:
        """Decode the three input topics, and ``/gimbal/reference_velocity`` if recorded, into numpy arrays (one
        pass over the bag).

        JointState and Temperature messages are parsed directly from their CDR bytes (plain little-endian, the
        usual case), a batch at a time (the messages of an MCAP chunk), and fall back to the type store for
        anything else. Joint names are renamed by ``joint_map``.

        Args:
            raw_sink: called with a :class:`RawBatch` for every batch of messages of the three input topics (not
                the reference velocity, which the nodes do not log), in the order :meth:`iter_raw` yields them,
                during the same pass (without reading the bag twice).

        Raises:
            RecordingError: the bag cannot be read, a message cannot be decoded, or the joint map would give two
                joints one name.
            EmptyInputError: a ``joint_map`` entry names a joint the bag does not record, or none of :attr:`axes`
                has both a joint state and a motor current (the joints present and the option that fixes it).
        """
        return next(self._windows(None, raw_sink))

    def iter_arrays(self, max_messages: int) -> Iterator[ChamberArrays]:
        """:meth:`read_arrays` in consecutive windows of about ``max_messages`` messages (memory bounded by the
        window whatever the bag's length), in log-time order. A window ends only where
        the log time changes, so feeding the windows one after another to the nodes' logic (as a node gets its
        callback batches) gives what one call on the whole bag gives. At least one window is yielded.

        Raises:
            ValueError: ``max_messages`` < 1.
            RecordingError: as :meth:`read_arrays` (an :class:`~.errors.EmptyInputError` instead of the last
                window).
        """
        if max_messages < 1:
            msg = f'max_messages must be >= 1, not {max_messages}'
            raise ValueError(msg)
        return self._windows(max_messages, None)

    def _windows(self, max_messages: int | None, raw_sink: RawSink | None) -> Iterator[ChamberArrays]:
        """The one decoding loop of :meth:`read_arrays` (``max_messages`` None: one window) and
        :meth:`iter_arrays`: batches of messages (:meth:`_batches`) decoded in bulk."""
        inputs = self._select(None)
        bag_reference = self.topic_map[REFERENCE_VELOCITY] if self.has_reference else None
        selected = inputs if bag_reference is None else self._select([*CHAMBER_TOPICS, REFERENCE_VELOCITY])
        window = _Window(self, bag_reference)
        seen = _JointsSeen()
        last_log: int | None = None
        for batch in self._batches(selected):
            n = batch.log_time.shape[0]
            pos = 0
            while pos < n:
                end = n if max_messages is None else _window_end(batch.log_time, pos, max_messages - window.count,
                                                                 last_log)
                if end > pos:
                    if raw_sink is not None:
                        raw_sink(_raw_batch(batch, pos, end, inputs))
                    window.add(batch, pos, end)
                    last_log = int(batch.log_time[end - 1])
                    pos = end
                if end < n:
                    yield seen.add(window)
                    window = _Window(self, bag_reference)
        last = seen.add(window)
        self._require_axes(seen)
        yield last

    def _require_axes(self, seen: _JointsSeen) -> None:
        """Refuse a read in which a ``joint_map`` entry names a joint the bag does not record, or none of
        :attr:`axes` has both a joint state and a motor current (effort): the one rule of "the bag holds nothing
        for the configured axes", with the joints present, the mapping used and the option that fixes it."""
        inverse = {v: k for k, v in self.joint_map.items()}
        js_topic, mc_topic = self.topic_map[JOINT_STATES], self.topic_map[MOTOR_CURRENT]
        recorded = ', '.join(repr(n) for n in seen.recorded_joints) or 'none'
        for bag_name, axis in self.joint_map.items():
            if bag_name not in seen.recorded:
                msg = (f'bag {self.path}: --joint {axis}={bag_name}: no joint {bag_name!r} in {js_topic} or '
                       f'{mc_topic} (joints recorded: {recorded}); name a recorded joint')
                raise EmptyInputError(msg)
        if not self.axes or any(a in seen.joints and a in seen.currents for a in self.axes):
            return
        axes = ', '.join(repr(a) for a in self.axes)
        mapping = ', '.join(f'{v}={k}' for k, v in self.joint_map.items()) or 'none'
        if not any(a in seen.joints for a in self.axes):
            names = list(seen.recorded_joints)
            example = (f'--joint {self.axes[0]}={names[0]}' if len(self.axes) == 1 and len(names) == 1
                       else '--joint AXIS=RECORDED')
            msg = (f'bag {self.path}: no configured axis is in {js_topic} (axes: {axes}; joints recorded: '
                   f'{recorded}; joint map: {mapping}): map each axis to its recorded joint with {example}, or '
                   f'set the parameter axes to the recorded names (--config)')
        else:
            currents = ', '.join(repr(inverse.get(n, n)) for n in seen.currents) or 'none'
            msg = (f'bag {self.path}: {mc_topic} carries no motor current (effort) for the configured axes '
                   f'(axes: {axes}; joints with effort there: {currents}; joint map: {mapping}): map the topic '
                   f'that carries it with --topic {MOTOR_CURRENT}=BAG_TOPIC')
        raise EmptyInputError(msg)

    def _batches(self, selected: Mapping[str, Sequence[str]]) -> Iterator[_Batch]:
        """The messages of the selected bag topics in batches, in the order of ``rosbags``' reader (log-time order
        per storage file, ties in file order).

        The MCAP files of a bag whose chunks follow each other in log time (what recorders write) are read a chunk
        at a time (:class:`~.mcap_scan.McapScanner`): one batch per chunk, no per-message work. Other bags (sqlite3,
        compressed files, overlapping chunks) are read through ``rosbags``, in batches of :data:`_BATCH_MESSAGES`.
        """
        try:
            with Reader(self.path) as reader:
                conns = [c for c in reader.connections if c.topic in selected]
                if not conns:  # an empty list would mean "every connection" to rosbags
                    return
                files = self._chunked_mcap_files(reader)
                if files is None:
                    yield from _batched(conns, reader.messages(connections=conns))
                    return
        except LIBRARY_READ_ERRORS as err:
            raise _read_error(self.path, 'reading', err) from err
        for path in files:
            yield from self._mcap_batches(path, conns)

    def _chunked_mcap_files(self, reader: Reader) -> list[Path] | None:
        """The bag's MCAP files if each one's chunks follow each other in log time (else None: read with rosbags)."""
        if self.path.is_file():
            paths = [self.path] if self.path.suffix == '.mcap' else []
        elif reader.compression_mode:
            return None
        else:
            try:
                text = (self.path / 'metadata.yaml').read_text()
                info = yaml.load(text, Loader=_YAML_LOADER)['rosbag2_bagfile_information']  # noqa: S506  # a safe loader
                if info.get('storage_identifier') != 'mcap':
                    return None
                paths = [self.path / PurePath(x).name for x in info['relative_file_paths']]
            except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError):
                return None
        for path in paths:
            ranges = chunk_time_ranges(path)
            if not ranges:
                return None
            latest = ranges[0][0]
            for first, last in ranges:
                if first < latest:
                    return None
                latest = max(latest, last)
        return paths or None

    def _mcap_batches(self, path: Path, conns: list[Connection]) -> Iterator[_Batch]:
        """One batch per chunk of an MCAP file whose chunks follow each other in log time."""
        topic_count: dict[str, int] = {}
        for conn in conns:
            topic_count[conn.topic] = topic_count.get(conn.topic, 0) + 1
        by_key = {(c.topic, c.msgtype if topic_count[c.topic] > 1 else ''): k for k, c in enumerate(conns)}
        scanner = McapScanner(path)
        channel_conn: dict[int, int] = {}
        for block in scanner.blocks():
            if scanner.report.problems:
                break
            present = distinct(block.channel_id)
            for cid in present:
                if cid not in channel_conn:
                    channel = scanner.channels.get(cid)
                    schema = scanner.schemas.get(channel.schema_id) if channel is not None else None
                    if channel is None:
                        channel_conn[cid] = -1
                    else:
                        msgtype = schema.name if schema is not None and topic_count.get(channel.topic, 0) > 1 else ''
                        channel_conn[cid] = by_key.get((channel.topic, msgtype), -1)
            lut = np.full(max(present) + 1, -1, dtype=np.int64)
            lut[present] = [channel_conn[c] for c in present]
            conn_index = lut[block.channel_id]
            keep = np.flatnonzero(conn_index >= 0)
            if keep.shape[0] == 0:
                continue
            order = keep[np.argsort(block.log_time[keep], kind='stable')]  # as rosbags: a chunk sorted by log time
            yield _Batch(conns, conn_index[order], block.log_time[order], block.buffer, block.data_start[order],
                         block.data_length[order])
        if scanner.report.problems or scanner.report.truncated:
            problem = scanner.report.problems[0] if scanner.report.problems else 'cut short'
            msg = (f'bag {self.path}: reading failed ({problem}): the bag is damaged or cut short; '
                   f'{recover_hint(self.path)}')
            raise RecordingError(msg)

    def describe(self, arrays: ChamberArrays | None = None) -> BagDescription:
        """What the three input streams hold (counts, joints and their fields, zero stamps) and what is not read.

        Args:
            arrays: the result of :meth:`read_arrays` if already read (otherwise the bag is read).
        """
        if arrays is None:
            arrays = self.read_arrays()
        inverse = {v: k for k, v in self.joint_map.items()}
        streams: dict[str, StreamSummary] = {}
        for topic, data in ((TEMPERATURE, arrays.temperature), (JOINT_STATES, arrays.joint_states),
                            (MOTOR_CURRENT, arrays.motor_current)):
            log = np.asarray(data.log_time_ns, dtype=np.int64)
            stamps = np.asarray(data.stamp_ns, dtype=np.int64)
            joints: tuple[JointSummary, ...] = ()
            if isinstance(data, JointStateArrays):
                joints = tuple(_joint_summary(data, name, inverse.get(name, name)) for name in data.names)
            streams[topic] = StreamSummary(
                topic=topic,
                bag_topic=self.topic_map[topic],
                msgtype=self.topics[topic].msgtype,
                messages=int(log.shape[0]),
                zero_stamps=int(np.count_nonzero(stamps == 0)),
                first_log_ns=int(log[0]) if log.shape[0] else 0,
                last_log_ns=int(log[-1]) if log.shape[0] else 0,
                joints=joints,
            )
        return BagDescription(self.path, streams, self.ignored_topics)

    # -- decoding ----------------------------------------------------------------------------------------------

    def _store_for(self, conn: Connection) -> Typestore:
        """The type store that knows ``conn.msgtype``: the default one, else a private one fed from the bag."""
        if conn.msgtype in self.typestore.types:
            return self.typestore
        if self._private_store is None:
            self._private_store = get_typestore(DEFAULT_STORE)
        store = self._private_store
        if conn.msgtype not in store.types:
            fmt = getattr(conn.msgdef.format, 'name', '')
            try:
                if fmt == 'MSG':
                    store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
                elif fmt == 'IDL':
                    store.register(get_types_from_idl(conn.msgdef.data))
            except (TypesysError, ValueError, KeyError) as err:
                msg = f'bag {self.path}: topic {conn.topic}: cannot parse the definition of {conn.msgtype}: {err}'
                raise RecordingError(msg) from err
            if conn.msgtype not in store.types:
                msg = (f'bag {self.path}: topic {conn.topic}: message type {conn.msgtype} is unknown and the bag '
                       f'has no definition of it')
                raise RecordingError(msg)
        return store

    def _decode(self, data: bytes, conn: Connection, log_time: int) -> object:
        """Deserialize one message with the type store, errors naming the topic."""
        try:
            return self._store_for(conn).deserialize_cdr(data, conn.msgtype)
        except _DECODE_ERRORS as err:
            topic = ' / '.join(self._bag_to_contracts.get(conn.topic, [conn.topic]))
            msg = f'bag {self.path}: cannot decode {topic} message at log time {log_time} ns: {err!r}'
            raise RecordingError(msg) from err


def _joint_summary(data: JointStateArrays, name: str, recorded: str) -> JointSummary:
    def present(values: dict[str, NDArray[np.float64]]) -> NDArray[np.bool_]:
        column = values.get(name)
        if column is None:
            return np.zeros(len(data), dtype=bool)
        return ~np.isnan(np.asarray(column, dtype=np.float64))

    pos, vel, eff = present(data.position), present(data.velocity), present(data.effort)
    return JointSummary(name, recorded, int(np.count_nonzero(pos | vel | eff)), int(np.count_nonzero(pos)),
                        int(np.count_nonzero(vel)), int(np.count_nonzero(eff)))


class _JointsSeen:
    """Joint names met over the windows of one read: in the joint states, and with effort in the motor current."""

    def __init__(self) -> None:
        self.joints: dict[str, None] = {}    # an ordered set (names after the joint map)
        self.currents: dict[str, None] = {}
        self.recorded: set[str] = set()      # names as recorded, on both topics
        self.recorded_joints: dict[str, None] = {}  # names as recorded in the joint states, in order

    def add(self, window: _Window) -> ChamberArrays:
        """Finish one window and note its names; returns its arrays."""
        bag = window.bag
        for topic in (bag.topic_map[MOTOR_CURRENT], bag.topic_map[JOINT_STATES]):
            for names in window.joint_collectors[topic].name_sets:
                self.recorded.update(names)
                if topic == bag.topic_map[JOINT_STATES]:
                    self.recorded_joints.update(dict.fromkeys(names))
        arrays = window.finish()
        self.joints.update(dict.fromkeys(arrays.joint_states.names))
        effort = arrays.motor_current.effort
        self.currents.update(dict.fromkeys(n for n in arrays.motor_current.names
                                           if n in effort and not np.all(np.isnan(effort[n]))))
        return arrays


class _Batch(NamedTuple):
    """Messages of the selected bag topics, in reading order, as arrays over one buffer."""

    conns: list[Connection]
    """The selected connections."""
    conn: NDArray[np.int64]
    """Index into ``conns`` of each message."""
    log_time: NDArray[np.int64]
    """Log time of each message [ns]."""
    buffer: bytes
    start: NDArray[np.int64]
    """Offset of each message's CDR bytes in ``buffer`` [B]."""
    length: NDArray[np.int64]
    """Length of each message's CDR bytes [B]."""


class RawBatch(NamedTuple):
    """Input messages of the bag as recorded, for :meth:`ChamberBag.read_arrays`' ``raw_sink``: one entry per
    message and contract topic (a bag topic feeding two contract topics gives each message twice, in turn)."""

    topics: list[tuple[str, str]]
    """``(contract topic, msgtype)`` pairs."""
    topic: NDArray[np.int64]
    """Index into ``topics`` of each entry."""
    log_time: NDArray[np.int64]
    """Log time of each entry [ns]."""
    buffer: bytes
    start: NDArray[np.int64]
    """Offset of each entry's CDR bytes (encapsulation header included) in ``buffer`` [B]."""
    length: NDArray[np.int64]
    """Length of each entry's CDR bytes [B]."""

    def datas(self) -> list[bytes]:
        """The CDR bytes of each entry."""
        buffer = self.buffer
        return [buffer[a : a + n] for a, n in zip(self.start.tolist(), self.length.tolist(), strict=True)]


#: messages per batch read through rosbags (sqlite3 bags, MCAP files whose chunks overlap in time)
_BATCH_MESSAGES = 8192


def _batched(conns: list[Connection], messages: Iterable[tuple[Connection, int, bytes]]) -> Iterator[_Batch]:
    """``rosbags`` messages gathered into batches of :data:`_BATCH_MESSAGES`."""
    index = {id(c): k for k, c in enumerate(conns)}
    by_topic = {(c.topic, c.msgtype): k for k, c in enumerate(conns)}
    ids: list[int] = []
    logs: list[int] = []
    datas: list[bytes] = []

    def batch() -> _Batch:
        length = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
        start = np.zeros_like(length)
        np.cumsum(length[:-1], out=start[1:])
        return _Batch(conns, np.asarray(ids, dtype=np.int64), np.asarray(logs, dtype=np.int64), b''.join(datas),
                      start, length)

    for conn, log_time, data in messages:
        k = index.get(id(conn))
        ids.append(by_topic[(conn.topic, conn.msgtype)] if k is None else k)
        logs.append(log_time)
        datas.append(data)
        if len(datas) >= _BATCH_MESSAGES:
            yield batch()
            ids, logs, datas = [], [], []
    if datas:
        yield batch()


def _window_end(log_time: NDArray[np.int64], pos: int, room: int, last_log: int | None) -> int:
    """Where a window that has ``room`` messages left ends in ``log_time[pos:]``: at the first message past the room
    whose log time differs from the one before it (``last_log`` before ``pos``); ``len(log_time)`` if none does."""
    first = pos + max(room, 0)
    n = log_time.shape[0]
    if first >= n:
        return n
    before = (last_log if first == pos else int(log_time[first - 1]))
    if before is None:
        return first
    changed = np.flatnonzero(log_time[first:] != np.concatenate(([before], log_time[first : n - 1])))
    return first + int(changed[0]) if changed.shape[0] else n


def _raw_batch(batch: _Batch, pos: int, end: int, inputs: Mapping[str, Sequence[str]]) -> RawBatch:
    """The input messages of ``batch[pos:end]`` as :class:`RawBatch` entries (one per contract topic fed)."""
    pairs: list[tuple[str, str]] = []
    table = np.full((len(batch.conns), max((len(v) for v in inputs.values()), default=0) + 1), -1, dtype=np.int64)
    fed = np.zeros(len(batch.conns), dtype=np.int64)
    for k, conn in enumerate(batch.conns):
        for j, topic in enumerate(inputs.get(conn.topic, ())):
            table[k, j] = len(pairs)
            pairs.append((topic, conn.msgtype))
        fed[k] = len(inputs.get(conn.topic, ()))
    counts = fed[batch.conn[pos:end]]
    message = np.repeat(np.arange(pos, end, dtype=np.int64), counts)
    nth = np.arange(message.shape[0], dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    return RawBatch(pairs, table[batch.conn[message], nth], batch.log_time[message], batch.buffer,
                    batch.start[message], batch.length[message])


class _Window:
    """The messages of one window of :meth:`ChamberBag._windows`, being collected."""

    def __init__(self, bag: ChamberBag, bag_reference: str | None) -> None:
        self.bag = bag
        self.bag_reference = bag_reference
        self.bag_temperature = bag.topic_map[TEMPERATURE]
        # one collector per bag topic: a bag topic may feed both joint-state inputs
        self.joint_collectors = {
            bag.topic_map[JOINT_STATES]: JointStateColumns(),
            bag.topic_map[MOTOR_CURRENT]: JointStateColumns(),
        }
        if bag_reference is not None and bag_reference not in self.joint_collectors:
            self.joint_collectors[bag_reference] = JointStateColumns()
        self.t_log: list[NDArray[np.int64]] = []
        self.t_stamp: list[NDArray[np.int64]] = []
        self.t_value: list[NDArray[np.float64]] = []
        self.count = 0

    def add(self, batch: _Batch, pos: int, end: int) -> None:
        """Decode the messages ``pos:end`` of ``batch`` (in bulk; the type store for what is not plain CDR)."""
        conn_of = batch.conn[pos:end]
        buffer = batch.buffer
        for k in distinct(conn_of):
            sel = pos + np.flatnonzero(conn_of == k)
            conn = batch.conns[k]
            logs, starts, lengths = batch.log_time[sel], batch.start[sel], batch.length[sel]

            def decode(i: int, conn: Connection = conn, logs: NDArray[np.int64] = logs,
                       starts: NDArray[np.int64] = starts, lengths: NDArray[np.int64] = lengths) -> object:
                a = int(starts[i])
                return self.bag._decode(buffer[a : a + int(lengths[i])], conn, int(logs[i]))  # noqa: SLF001  # its bag's decoder

            collector = self.joint_collectors.get(conn.topic)
            if collector is not None:
                collector.add_batch(logs, buffer, starts, lengths, decode)
            elif conn.topic == self.bag_temperature:
                rows = temperature_rows(buffer, starts, lengths)
                stamps = np.zeros(sel.shape[0], dtype=np.int64)
                values = np.zeros(sel.shape[0], dtype=np.float64)
                stamps[rows.decoded] = rows.stamp_ns
                values[rows.decoded] = rows.temperature_c
                for i in rows.others.tolist():
                    message = decode(i)
                    stamp = message.header.stamp  # type: ignore[attr-defined]  # a Temperature of the type store (no stubs)
                    stamps[i] = join_stamp(stamp.sec, stamp.nanosec)
                    values[i] = float(message.temperature)  # type: ignore[attr-defined]  # a Temperature of the type store (no stubs)
                self.t_log.append(logs)
                self.t_stamp.append(stamps)
                self.t_value.append(values)
            else:
                continue
            self.count += sel.shape[0]

    def finish(self) -> ChamberArrays:
        bag = self.bag
        temperature = TemperatureArrays(
            np.concatenate([np.zeros(0, dtype=np.int64), *self.t_log]),
            np.concatenate([np.zeros(0, dtype=np.int64), *self.t_stamp]),
            np.concatenate([np.zeros(0, dtype=np.float64), *self.t_value]),
        )
        try:
            finished = {name: c.finish(bag.joint_map) for name, c in self.joint_collectors.items()}
        except ValueError as err:
            msg = f'bag {bag.path}: joint map: {err}'
            raise RecordingError(msg) from err
        reference = None
        if self.bag_reference is not None:  # a message whose velocities do not match its names is not used
            reference = finished[self.bag_reference]
            # (not NamedTuple._replace: JointStateArrays' __len__ counts messages, which _replace's check trips on)
            bad = self.joint_collectors[self.bag_reference].mismatched(1)
            if bad.any():
                reference = type(reference)(**{**reference._asdict(), 'velocity': {
                    n: np.where(bad, np.nan, v) for n, v in reference.velocity.items()}})
            # positions (a learned correction's position map) only from a message with one per name, as the node
            no_position = self.joint_collectors[self.bag_reference].mismatched(0)
            if no_position.any():
                reference = type(reference)(**{**reference._asdict(), 'position': {
                    n: np.where(no_position, np.nan, p) for n, p in reference.position.items()}})
        return ChamberArrays(
            temperature=temperature,
            joint_states=finished[bag.topic_map[JOINT_STATES]],
            motor_current=finished[bag.topic_map[MOTOR_CURRENT]],
            reference_velocity=reference,
        )
