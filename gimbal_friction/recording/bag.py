"""Chamber-test bags: open, check, iterate and decode into numpy arrays; write small bags for tests and synth.

A chamber-test bag (CONTRACT.md "Bags and logs") is a rosbag2 bag directory (MCAP or sqlite3 storage, whatever
wrote it) or a bare ``.mcap`` file that holds at least the topics of :data:`~.topics.CHAMBER_TOPICS`. Reading goes
through ``rosbags.highlevel.AnyReader``; no rclpy is imported.

Topic names: every public function speaks *contract* names (``/joint_states``, ...). ``topic_map`` maps a contract
name to the name recorded in the bag (``{'/joint_states': '/gimbal/joint_states'}``), as ``--topic`` options do.

Times: ``log_time_ns`` is the bag's receive/log time [ns]; ``stamp_ns`` is ``header.stamp`` [ns]. Both are int64.
"""

from __future__ import annotations

import functools
import math
import struct
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_typestore

from gimbal_friction.core.arrays import ChamberArrays, JointStateArrays, TemperatureArrays
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.topics import (
    CHAMBER_TOPICS,
    FLOAT64_MULTI_ARRAY_TYPE,
    JOINT_STATE_TYPE,
    JOINT_STATES,
    MOTOR_CURRENT,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)

if TYPE_CHECKING:
    import os
    from collections.abc import Iterable, Iterator, Mapping, Sequence

    from numpy.typing import ArrayLike, NDArray
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

__all__ = [
    'DEFAULT_STORE',
    'ChamberArrays',
    'ChamberBag',
    'DecodedMessage',
    'JointStateArrays',
    'RawMessage',
    'TemperatureArrays',
    'TopicInfo',
    'default_typestore',
    'make_float64_multi_array',
    'make_header',
    'make_joint_state',
    'make_temperature',
    'open_chamber_bag',
    'write_chamber_bag',
]

#: the type store matching the ROS 2 wheels of this project (ROS2_SETUP.md §6)
DEFAULT_STORE = Stores.ROS2_KILTED

_NS_PER_S = 1_000_000_000
_STORAGE_PLUGINS = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
#: what writing a bag raises on bad input or I/O (wrong message objects surface as AttributeError etc.)
_WRITE_ERRORS = (WriterError, SerdeError, TypesysError, OSError, KeyError, AttributeError, TypeError, struct.error)


@functools.lru_cache(maxsize=1)
def default_typestore() -> Typestore:
    """The shared ``rosbags`` type store of :data:`DEFAULT_STORE`.

    Shared and cached: use it to build, serialize and deserialize standard messages, do not ``register`` types
    into it (make your own with ``get_typestore(DEFAULT_STORE)`` for that).
    """
    return get_typestore(DEFAULT_STORE)


# ----------------------------------------------------------------------------------------------------------------
# records


class TopicInfo(NamedTuple):
    """One topic of a bag, under its contract name."""

    msgtype: str
    """Message type, e.g. ``sensor_msgs/msg/JointState``."""
    count: int
    """Number of messages [-]."""


#: ``read_arrays`` raw-message callback: (contract topics, msgtype, log time [ns], CDR bytes)
RawSink = 'Callable[[Sequence[str], str, int, bytes], None]'


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


# ----------------------------------------------------------------------------------------------------------------
# message helpers


def make_header(stamp_ns: int, frame_id: str = '') -> object:
    """A ``std_msgs/Header`` with ``stamp`` = ``stamp_ns`` [ns] (floor-split into sec and nanosec)."""
    types = default_typestore().types
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    stamp = types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    return types['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)


def make_temperature(
    stamp_ns: int, temperature_c: float, frame_id: str = 'gimbal', variance: float = 0.0
) -> object:
    """A ``sensor_msgs/Temperature``: ``temperature_c`` [degC] at ``stamp_ns`` [ns], ``variance`` [degC^2]."""
    cls = default_typestore().types[TEMPERATURE_TYPE]
    return cls(header=make_header(stamp_ns, frame_id), temperature=float(temperature_c), variance=float(variance))


def _f64(values: ArrayLike | None) -> NDArray[np.float64]:
    """A 1-D contiguous float64 array (empty for None)."""
    if values is None:
        return np.empty(0, dtype=np.float64)
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1))


def make_joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: ArrayLike | None = None,
    velocity: ArrayLike | None = None,
    effort: ArrayLike | None = None,
    frame_id: str = '',
) -> object:
    """A ``sensor_msgs/JointState``; a field left as None is an empty array (ROS: "not provided").

    Args:
        stamp_ns: ``header.stamp`` [ns].
        names: joint names.
        position: joint positions [rad], one per name, or None.
        velocity: joint velocities [rad/s], one per name, or None.
        effort: efforts [N*m] (or motor currents [A]), one per name, or None.
        frame_id: ``header.frame_id``.
    """
    cls = default_typestore().types[JOINT_STATE_TYPE]
    return cls(
        header=make_header(stamp_ns, frame_id),
        name=[str(x) for x in names],
        position=_f64(position),
        velocity=_f64(velocity),
        effort=_f64(effort),
    )


def make_float64_multi_array(values: ArrayLike, label: str) -> object:
    """A ``std_msgs/Float64MultiArray`` holding ``values`` as one row, ``layout.dim[0].label`` = ``label``."""
    types = default_typestore().types
    data = _f64(values)
    dim = types['std_msgs/msg/MultiArrayDimension'](label=str(label), size=data.shape[0], stride=data.shape[0])
    layout = types['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)
    return types[FLOAT64_MULTI_ARRAY_TYPE](layout=layout, data=data)


# ----------------------------------------------------------------------------------------------------------------
# writing


def write_chamber_bag(
    path: str | os.PathLike[str],
    messages: Iterable[tuple[str, str, int, object]],
    *,
    storage: str = 'mcap',
    typestore: Typestore | None = None,
) -> Path:
    """Write a rosbag2 bag directory (version 9) from ``(topic, msgtype, log_time_ns, msg)`` tuples.

    Args:
        path: bag directory to create; must not exist.
        messages: ``msg`` is a rosbags message object (see :func:`make_joint_state` ...), ``log_time_ns`` [ns].
        storage: ``'mcap'`` or ``'sqlite3'``.
        typestore: type store to serialize with (default :func:`default_typestore`).

    Returns:
        The bag directory.

    Raises:
        RecordingError: the path exists, the storage is unknown, a message does not serialize, or I/O fails.
    """
    bag = Path(path)
    if storage not in _STORAGE_PLUGINS:
        msg = f'unknown bag storage {storage!r}; expected one of {sorted(_STORAGE_PLUGINS)}'
        raise RecordingError(msg)
    store = typestore or default_typestore()
    connections: dict[tuple[str, str], Connection] = {}
    try:
        with Writer(bag, version=9, storage_plugin=_STORAGE_PLUGINS[storage]) as writer:
            for topic, msgtype, log_time_ns, message in messages:
                key = (topic, msgtype)
                conn = connections.get(key)
                if conn is None:
                    conn = writer.add_connection(topic, msgtype, typestore=store)
                    connections[key] = conn
                writer.write(conn, int(log_time_ns), store.serialize_cdr(message, msgtype))
    except _WRITE_ERRORS as err:
        msg = f'writing bag {bag}: {err!r}'
        raise RecordingError(msg) from err
    return bag


# ----------------------------------------------------------------------------------------------------------------
# reading


def open_chamber_bag(
    path: str | os.PathLike[str],
    topic_map: Mapping[str, str] | None = None,
    *,
    typestore: Typestore | None = None,
) -> ChamberBag:
    """Open a chamber-test bag and check it holds the contract's input topics with the right types.

    Args:
        path: rosbag2 bag directory (MCAP or sqlite3 storage) or bare ``.mcap`` file.
        topic_map: contract topic name -> topic name in the bag, for bags recorded under other names.
        typestore: type store for bags without embedded message definitions (default :data:`DEFAULT_STORE`).

    Raises:
        RecordingError: not a bag, unreadable, or a required topic is missing, empty or of another type (the
            message names the topic).
    """
    bag = Path(path)
    if not bag.exists():
        msg = f'not a rosbag2 bag or MCAP file: {bag} (no such file or directory)'
        raise RecordingError(msg)
    if bag.is_dir():
        if not (bag / 'metadata.yaml').is_file():
            msg = f'not a rosbag2 bag or MCAP file: {bag} (directory without metadata.yaml)'
            raise RecordingError(msg)
    elif bag.suffix != '.mcap':
        msg = f'not a rosbag2 bag or MCAP file: {bag} (expected a bag directory or a .mcap file)'
        raise RecordingError(msg)
    mapping = dict(topic_map or {})
    for contract, recorded in mapping.items():
        if not contract or not recorded:
            msg = f'topic map entry {contract!r} -> {recorded!r}: both names must be non-empty'
            raise RecordingError(msg)
    store = typestore or default_typestore()

    try:
        with AnyReader([bag], default_typestore=store) as reader:
            bag_topics = {name: (info.msgtype, info.msgcount) for name, info in reader.topics.items()}
            count = reader.message_count
            start_ns = reader.start_time if count else 0
            duration_ns = max(0, reader.end_time - 1 - reader.start_time) if count else 0
    except (AnyReaderError, SerdeError, TypesysError, OSError, ValueError, KeyError) as err:
        hint = 'an MCAP file cut short by a killed recorder can be rewritten with residual_log.recover_mcap'
        msg = f'not a rosbag2 bag or MCAP file: {bag}: {err} ({hint})'
        raise RecordingError(msg) from err

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

    for contract, want in CHAMBER_TOPICS.items():
        recorded = mapping.get(contract, contract)
        shown = contract if recorded == contract else f'{contract} (recorded as {recorded})'
        if contract not in contract_to_bag:
            have = ', '.join(sorted(bag_topics)) or 'none'
            msg = f'bag {bag}: required topic {shown} is missing (topics in bag: {have})'
            raise RecordingError(msg)
        msgtype, n = bag_topics[contract_to_bag[contract]]
        if msgtype != want:
            got = msgtype if msgtype else 'several types'
            msg = f'bag {bag}: required topic {shown} has type {got}, expected {want}'
            raise RecordingError(msg)
        if n <= 0:
            msg = f'bag {bag}: required topic {shown} has no messages'
            raise RecordingError(msg)

    topics = {
        contract: TopicInfo(bag_topics[recorded][0] or '', int(bag_topics[recorded][1]))
        for contract, recorded in contract_to_bag.items()
    }
    return ChamberBag(
        path=bag,
        topic_map=contract_to_bag,
        topics=topics,
        start_ns=int(start_ns),
        duration_ns=int(duration_ns),
        typestore=store,
    )


class ChamberBag:
    """A checked chamber-test bag; every read opens (and always closes) its own reader.

    Built by :func:`open_chamber_bag`. Topics are named by their contract name.
    """

    def __init__(
        self,
        *,
        path: Path,
        topic_map: dict[str, str],
        topics: dict[str, TopicInfo],
        start_ns: int,
        duration_ns: int,
        typestore: Typestore,
    ) -> None:
        """Hold what :func:`open_chamber_bag` found (use that function, not this constructor)."""
        self.path = path
        #: contract topic name -> topic name in the bag, for every visible topic
        self.topic_map = topic_map
        #: contract topic name -> (msgtype, message count)
        self.topics = topics
        #: log time of the first message [ns]
        self.start_ns = start_ns
        #: log time of the last message minus that of the first [ns]
        self.duration_ns = duration_ns
        self.typestore = typestore
        self._bag_to_contracts: dict[str, list[str]] = {}
        for contract, recorded in topic_map.items():
            self._bag_to_contracts.setdefault(recorded, []).append(contract)

    def __repr__(self) -> str:
        """Path and topics."""
        return f'ChamberBag({str(self.path)!r}, topics={self.topics!r})'

    @property
    def message_count(self) -> int:
        """Messages on the visible topics [-]."""
        return sum(info.count for info in self.topics.values())

    @property
    def end_ns(self) -> int:
        """Log time of the last message [ns]."""
        return self.start_ns + self.duration_ns

    # -- iteration -------------------------------------------------------------------------------------------

    def _select(self, topics: Iterable[str] | None) -> dict[str, list[str]]:
        """Bag topic name -> requested contract names (every visible topic for None)."""
        if topics is None:
            return self._bag_to_contracts
        wanted = [topics] if isinstance(topics, str) else list(topics)
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

    def _messages(
        self, selected: Mapping[str, Sequence[str]]
    ) -> Iterator[tuple[Connection, int, bytes, Typestore]]:
        """Raw messages of the selected bag topics in log-time order, with the reader's type store."""
        try:
            with AnyReader([self.path], default_typestore=self.typestore) as reader:
                conns = [c for c in reader.connections if c.topic in selected]
                if not conns:
                    return
                for conn, log_time, data in reader.messages(connections=conns):
                    yield conn, log_time, data, reader.typestore
        except (AnyReaderError, OSError, ValueError, KeyError) as err:
            msg = f'reading bag {self.path}: {err}'
            raise RecordingError(msg) from err

    def iter_raw(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Serialized messages ``(contract_topic, msgtype, log_time_ns, cdr_bytes)`` in log-time order.

        A bag topic mapped to two contract topics yields each message once per contract topic.

        Args:
            topics: contract topic names to read (default: every visible topic of the bag).
        """
        selected = self._select(topics)
        for conn, log_time, data, _ in self._messages(selected):
            for topic in selected[conn.topic]:
                yield RawMessage(topic, conn.msgtype, log_time, data)

    def iter_decoded(self, topics: Iterable[str] | None = None) -> Iterator[DecodedMessage]:
        """Decoded messages ``(contract_topic, log_time_ns, msg)`` in log-time order (rosbags dataclasses).

        Args:
            topics: contract topic names to read (default: every visible topic of the bag).
        """
        selected = self._select(topics)
        for conn, log_time, data, store in self._messages(selected):
            message = self._decode(store, data, conn, log_time)
            for topic in selected[conn.topic]:
                yield DecodedMessage(topic, log_time, message)

    # -- arrays ----------------------------------------------------------------------------------------------

    def read_arrays(self, raw_sink: RawSink | None = None) -> ChamberArrays:
        """Decode the three input topics into numpy arrays (one pass over the bag).

        JointState messages are parsed directly from their CDR bytes (little-endian, the usual case) and fall
        back to the type store for anything else; temperatures go through the type store.

        Args:
            raw_sink: called as ``raw_sink(contract_topics, msgtype, log_time_ns, cdr_bytes)`` for every visible
                message of the bag, in log-time order, during the same pass (what :meth:`iter_raw` yields,
                without reading the bag twice); ``contract_topics`` lists the contract names the bag topic feeds.
        """
        bag_temperature = self.topic_map[TEMPERATURE]
        # one collector per bag topic: a bag topic may feed both joint-state inputs
        joint_collectors = {
            self.topic_map[JOINT_STATES]: _JointStateCollector(),
            self.topic_map[MOTOR_CURRENT]: _JointStateCollector(),
        }
        t_log: list[int] = []
        t_stamp: list[int] = []
        t_value: list[float] = []
        selected = self._select(None if raw_sink is not None else [TEMPERATURE, JOINT_STATES, MOTOR_CURRENT])
        for conn, log_time, data, store in self._messages(selected):
            if raw_sink is not None:
                raw_sink(selected[conn.topic], conn.msgtype, log_time, data)
            collector = joint_collectors.get(conn.topic)
            if collector is not None:
                if not collector.add_cdr(log_time, data):
                    collector.add_message(log_time, self._decode(store, data, conn, log_time))
            elif conn.topic == bag_temperature:
                message = self._decode(store, data, conn, log_time)
                stamp = message.header.stamp  # type: ignore[attr-defined]
                t_log.append(log_time)
                t_stamp.append(stamp.sec * _NS_PER_S + stamp.nanosec)
                t_value.append(message.temperature)  # type: ignore[attr-defined]
        temperature = TemperatureArrays(
            np.array(t_log, dtype=np.int64),
            np.array(t_stamp, dtype=np.int64),
            np.array(t_value, dtype=np.float64),
        )
        finished = {name: collector.finish() for name, collector in joint_collectors.items()}
        return ChamberArrays(
            temperature=temperature,
            joint_states=finished[self.topic_map[JOINT_STATES]],
            motor_current=finished[self.topic_map[MOTOR_CURRENT]],
        )

    def _decode(self, store: Typestore, data: bytes, conn: Connection, log_time: int) -> object:
        """Deserialize one message with the bag's type store, errors naming the topic."""
        try:
            return store.deserialize_cdr(data, conn.msgtype)
        except (SerdeError, TypesysError, KeyError) as err:
            topic = ' / '.join(self._bag_to_contracts.get(conn.topic, [conn.topic]))
            msg = f'bag {self.path}: cannot decode {topic} message at log time {log_time} ns: {err}'
            raise RecordingError(msg) from err


# ----------------------------------------------------------------------------------------------------------------
# JointState decoding


_UNPACK_STAMP = struct.Struct('<iI').unpack_from  # stamp.sec, stamp.nanosec
_UNPACK_U32 = struct.Struct('<I').unpack_from
_EMPTY = b''


class _JointStateCollector:
    """Accumulates JointState messages as raw little-endian float64 bytes, assembled once at the end.

    Per message it keeps the log time, the stamp, the index of its name list and, per field, the value count and
    the values' bytes. :meth:`finish` scatters them into per-joint arrays with NaN where a value is missing.
    """

    def __init__(self) -> None:
        self.log_time: list[int] = []
        self.stamp: list[int] = []
        self.name_index: list[int] = []
        self.counts: tuple[list[int], list[int], list[int]] = ([], [], [])
        self.values: tuple[list[bytes], list[bytes], list[bytes]] = ([], [], [])
        self.name_sets: list[tuple[str, ...]] = []
        self._by_names: dict[tuple[str, ...], int] = {}
        self._by_raw_names: dict[bytes, int] = {}
        # cached layout of the last parsed message: bytes from frame_id length to the end of the names
        self._layout_prefix = b''
        self._layout_pos = 0
        self._layout_index = 0

    def _names_index(self, names: tuple[str, ...]) -> int:
        index = self._by_names.get(names)
        if index is None:
            index = len(self.name_sets)
            self.name_sets.append(names)
            self._by_names[names] = index
        return index

    def add_cdr(self, log_time: int, raw: bytes) -> bool:
        """Parse one CDR-encoded JointState; False (and nothing stored) if it needs the generic decoder.

        Layout (XCDR1, offsets relative to the byte after the 4-byte encapsulation header; sequences of float64
        are aligned to 8 only when non-empty, as rosbags and Fast CDR do): int32 sec, uint32 nanosec,
        string frame_id, string[] name, float64[] position, velocity, effort. The bytes from frame_id to the end
        of the names are usually the same from message to message, so their parse is cached.
        """
        if not isinstance(raw, bytes):
            raw = bytes(raw)
        try:
            if raw[1] != 1 or raw[0] != 0:  # plain CDR, little endian only
                return False
            if self._layout_prefix and raw.startswith(self._layout_prefix, 12):
                pos = self._layout_pos
                index = self._layout_index
            else:
                pos, index = self._parse_layout(raw)
            sec, nanosec = _UNPACK_STAMP(raw, 4)
            # position
            pos = (pos + 3) & ~3
            (n_pos,) = _UNPACK_U32(raw, pos + 4)
            pos += 4
            if n_pos:
                pos = (pos + 7) & ~7
                end = pos + 8 * n_pos
                b_pos = raw[pos + 4 : end + 4]
                pos = end
            else:
                b_pos = _EMPTY
            # velocity
            pos = (pos + 3) & ~3
            (n_vel,) = _UNPACK_U32(raw, pos + 4)
            pos += 4
            if n_vel:
                pos = (pos + 7) & ~7
                end = pos + 8 * n_vel
                b_vel = raw[pos + 4 : end + 4]
                pos = end
            else:
                b_vel = _EMPTY
            # effort
            pos = (pos + 3) & ~3
            (n_eff,) = _UNPACK_U32(raw, pos + 4)
            pos += 4
            if n_eff:
                pos = (pos + 7) & ~7
                end = pos + 8 * n_eff
                b_eff = raw[pos + 4 : end + 4]
                pos = end
            else:
                b_eff = _EMPTY
            if pos + 4 > len(raw):  # a value slice ran past the end
                return False
        except (struct.error, ValueError, IndexError):
            return False
        self.log_time.append(log_time)
        self.stamp.append(sec * _NS_PER_S + nanosec)
        self.name_index.append(index)
        counts = self.counts
        values = self.values
        counts[0].append(n_pos)
        counts[1].append(n_vel)
        counts[2].append(n_eff)
        values[0].append(b_pos)
        values[1].append(b_vel)
        values[2].append(b_eff)
        return True

    def _parse_layout(self, raw: bytes) -> tuple[int, int]:
        """Parse frame_id and the names; cache them; return (payload offset after the names, name-set index)."""
        (flen,) = _UNPACK_U32(raw, 12)
        pos = (12 + flen + 3) & ~3
        names_start = pos
        (n_names,) = _UNPACK_U32(raw, pos + 4)
        pos += 4
        for _ in range(n_names):
            pos = (pos + 3) & ~3
            (slen,) = _UNPACK_U32(raw, pos + 4)
            pos += 4 + slen
        if pos + 4 > len(raw):
            msg = 'names run past the end of the message'
            raise ValueError(msg)
        names_key = raw[names_start + 4 : pos + 4]
        index = self._by_raw_names.get(names_key)
        if index is None:
            index = self._names_index(self._parse_names(raw, names_start, n_names))
            self._by_raw_names[names_key] = index
        self._layout_prefix = raw[12 : pos + 4]
        self._layout_pos = pos
        self._layout_index = index
        return pos, index

    @staticmethod
    def _parse_names(raw: bytes, names_start: int, n_names: int) -> tuple[str, ...]:
        pos = names_start + 4
        names = []
        for _ in range(n_names):
            pos = (pos + 3) & ~3
            (slen,) = _UNPACK_U32(raw, pos + 4)
            if slen < 1:
                msg = 'string without terminator'
                raise ValueError(msg)
            names.append(bytes(raw[pos + 8 : pos + 8 + slen - 1]).decode('utf-8'))
            pos += 4 + slen
        return tuple(names)

    def add_message(self, log_time: int, message: object) -> None:
        """Store one JointState decoded by the type store."""
        stamp = message.header.stamp  # type: ignore[attr-defined]
        self.log_time.append(log_time)
        self.stamp.append(stamp.sec * _NS_PER_S + stamp.nanosec)
        self.name_index.append(self._names_index(tuple(message.name)))  # type: ignore[attr-defined]
        for field, attr in enumerate(('position', 'velocity', 'effort')):
            arr = np.asarray(getattr(message, attr), dtype='<f8').reshape(-1)
            self.counts[field].append(int(arr.shape[0]))
            self.values[field].append(arr.tobytes())

    def finish(self) -> JointStateArrays:
        """Assemble the per-joint arrays."""
        n_msgs = len(self.log_time)
        order: dict[str, int] = {}
        for names in self.name_sets:
            for name in names:
                order.setdefault(name, len(order))
        n_joints = len(order)
        # lookup: (name set, value position) -> joint column, -1 past the names of that set
        width = max((len(x) for x in self.name_sets), default=0)
        lookup = np.full((max(len(self.name_sets), 1), width + 1), -1, dtype=np.int64)
        for row, names in enumerate(self.name_sets):
            lookup[row, : len(names)] = [order[x] for x in names]
        name_index = np.asarray(self.name_index, dtype=np.int64)
        fields = []
        for field in range(3):
            counts = np.asarray(self.counts[field], dtype=np.int64)
            flat = np.frombuffer(b''.join(self.values[field]), dtype='<f8')
            out = np.full((n_msgs, n_joints), math.nan, dtype=np.float64)
            if flat.size and n_joints:
                msg_of_value = np.repeat(np.arange(n_msgs), counts)
                starts = np.cumsum(counts) - counts
                slot = np.arange(flat.size) - starts[msg_of_value]
                slot = np.minimum(slot, width)  # values beyond the names: column -1, dropped
                column = lookup[name_index[msg_of_value], slot]
                keep = column >= 0
                out[msg_of_value[keep], column[keep]] = flat[keep]
            fields.append({name: np.ascontiguousarray(out[:, col]) for name, col in order.items()})
        return JointStateArrays(
            log_time_ns=np.asarray(self.log_time, dtype=np.int64),
            stamp_ns=np.asarray(self.stamp, dtype=np.int64),
            names=tuple(order),
            position=fields[0],
            velocity=fields[1],
            effort=fields[2],
        )
