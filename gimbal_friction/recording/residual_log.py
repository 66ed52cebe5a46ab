"""The residual log: a folder of MCAP files written directly with ``mcap``, readable after a crash.

CONTRACT.md "Bags and logs": ROS 2 profile, ``ros2msg`` schemas, CDR messages, standard message types only,
rotated by size or duration; closed cleanly, the folder also has a rosbag2 ``metadata.yaml`` (version 9) so
``ros2 bag info`` and ``rosbags.highlevel.AnyReader`` open it. Chunks are small and flushed on a timer, so a
process killed with SIGKILL leaves files whose completed chunks are read back by :func:`read_residual_log`
(ROS2_SETUP.md §6: the rosbags writer leaves nothing readable in that case).

Times: ``log_time_ns`` is the log (receive, or for ``replay`` the bag's) time [ns]. Sizes in bytes [B].
"""

from __future__ import annotations

import contextlib
import io
import itertools
import math
import operator
import os
import re
import struct
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, NamedTuple

import numpy as np
import yaml
from mcap.exceptions import EndOfFile, InvalidMagic, McapError, RecordLengthLimitExceeded
from mcap.opcode import Opcode
from mcap.records import Channel, Header, Message, MessageIndex, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError, get_types_from_msg, get_typestore

from gimbal_friction.recording.bag import DEFAULT_STORE, default_typestore
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.core.residual_row import RESIDUAL_FIELDS_V1, ResidualRows, rows_from_detail
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL, RESIDUAL_DETAIL, TEMPERATURE

try:  # the chunk builder of mcap's writer (internal; see _BulkChunk)
    from mcap._chunk_builder import ChunkBuilder
except ImportError:  # pragma: no cover - another mcap layout: write_raw_many uses add_message
    ChunkBuilder = None  # type: ignore[assignment,misc]

try:  # chunk decompression errors of a torn last chunk
    from zstandard import ZstdError as _ZstdError
except ImportError:  # pragma: no cover - zstandard is a dependency of mcap's zstd support
    _ZstdError = RuntimeError  # type: ignore[assignment,misc]

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator, Sequence
    from types import TracebackType

    from mcap.data_stream import RecordBuilder

    from numpy.typing import ArrayLike, NDArray
    from rosbags.typesys.store import Typestore

__all__ = [
    'DEFAULT_CHUNK_SIZE',
    'MESSAGE_ENCODING',
    'PROFILE',
    'RESIDUAL_LOG_TOPICS',
    'SCHEMA_ENCODING',
    'LogMessage',
    'RecoveryResult',
    'ResidualArrays',
    'ResidualLog',
    'ResidualLogStats',
    'ResidualLogWriter',
    'iter_residual_log',
    'read_residual_log',
    'recover_mcap',
    'residual_log_files',
]

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
#: default chunk size [B]: small, so little is lost when the process is killed
DEFAULT_CHUNK_SIZE = 64 * 1024
#: a folder (or file) is a residual log if it holds at least one of these topics
RESIDUAL_LOG_TOPICS = (RESIDUAL, RESIDUAL_DETAIL)
LIBRARY = 'gimbal_friction residual_log (mcap-python)'

_NS_PER_S = 1_000_000_000
_COMPRESSION = {'none': CompressionType.NONE, 'lz4': CompressionType.LZ4, 'zstd': CompressionType.ZSTD}
#: channel metadata as rosbag2 (version 9) writes it; '[]' = no recorded QoS offers (a YAML sequence)
_NO_QOS = '[]'
#: errors met when a file ends inside a record or a chunk (torn tail after SIGKILL or a full disk)
_TAIL_ERRORS = (EndOfFile, RecordLengthLimitExceeded, struct.error, ValueError, EOFError, _ZstdError, RuntimeError)
_FILE_INDEX = re.compile(r'^(?P<stem>.*?)(?:_(?P<index>\d+))?$')


# ----------------------------------------------------------------------------------------------------------------
# records


class ResidualLogStats(NamedTuple):
    """State of a :class:`ResidualLogWriter`, e.g. for diagnostics."""

    messages: int
    """Messages written [-]."""
    flushed_messages: int
    """Messages handed to the operating system by the last flush or rotation [-]."""
    bytes: int
    """Bytes written so far over all files [B] (the open chunk not included)."""
    current_file: Path | None
    """File being written, None once closed."""
    files: tuple[Path, ...]
    """Every file of this log so far, in order."""


class LogMessage(NamedTuple):
    """One decoded message of a residual log."""

    topic: str
    msgtype: str
    log_time_ns: int
    """Log time [ns]."""
    msg: object
    """rosbags message dataclass."""


class ResidualArrays(NamedTuple):
    """The ``/gimbal/friction/residual_detail`` rows of a residual log, sorted by log time.

    One array per field of :data:`~.topics.RESIDUAL_FIELDS` (same names, same SI units), plus the log time and
    the joint name of each row. A row shorter than RESIDUAL_FIELDS is padded with NaN.
    """

    log_time_ns: NDArray[np.int64]
    """Log time [ns]."""
    joint: NDArray[np.str_]
    """Joint name (``layout.dim[0].label``)."""
    stamp_s: NDArray[np.float64]
    """Stamp of the measured sample [s]."""
    temperature_c: NDArray[np.float64]
    """Bearing temperature used for the prediction [degC]."""
    position_rad: NDArray[np.float64]
    """Joint position [rad]."""
    velocity_rad_s: NDArray[np.float64]
    """Joint velocity [rad/s]."""
    current_a: NDArray[np.float64]
    """Motor current [A]."""
    measured_nm: NDArray[np.float64]
    """Measured friction, signed [N*m]."""
    predicted_nm: NDArray[np.float64]
    """Model feedforward, signed [N*m]."""
    m_rolling_nm: NDArray[np.float64]
    """Model M_R magnitude [N*m]."""
    m_sliding_nm: NDArray[np.float64]
    """Model M_S magnitude [N*m]."""
    m_viscous_nm: NDArray[np.float64]
    """Model M_L magnitude [N*m]."""
    residual_nm: NDArray[np.float64]
    """Measured - predicted [N*m]."""

    def __len__(self) -> int:  # type: ignore[override]
        """Number of rows [-] (not the number of fields)."""
        return int(self.log_time_ns.shape[0])


class ResidualLog(NamedTuple):
    """What :func:`read_residual_log` found."""

    detail: ResidualRows | None
    """The residual detail rows of every file."""
    files: tuple[Path, ...]
    """Files read, in order."""
    truncated_files: tuple[Path, ...]
    """Files without a valid end (killed writer); their completed chunks were read."""
    topic_counts: dict[str, int]
    """Messages per topic over all files [-]."""


class RecoveryResult(NamedTuple):
    """Outcome of :func:`recover_mcap`."""

    messages: int
    """Messages copied [-]."""
    truncated: bool
    """True if the source ended without a footer (or with a torn record)."""


class _FileInfo(NamedTuple):
    """A finished file of the log, for metadata.yaml."""

    path: Path
    start_ns: int
    duration_ns: int
    messages: int


# ----------------------------------------------------------------------------------------------------------------
# writer


class _OpenFile:
    """One MCAP file being written: its stream, mcap writer, ids, counts and size estimate."""

    def __init__(
        self, path: Path, chunk_size: int, compression: CompressionType, opener: Callable[[Path], BinaryIO]
    ) -> None:
        self.path = path
        self.stream = opener(path)
        try:
            self.writer = McapWriter(self.stream, chunk_size=chunk_size, compression=compression)
            self.writer.start(profile=PROFILE, library=LIBRARY)
        except BaseException:
            self.stream.close()
            raise
        self.schema_ids: dict[str, int] = {}
        self.channel_ids: dict[str, int] = {}
        self.sequence: dict[int, int] = {}
        self.messages = 0
        self.first_ns = 0
        self.min_ns = 0
        self.max_ns = 0
        self.last_tell = self.stream.tell()
        self.pending = 0  # bytes in the open chunk (estimate) [B]

    def size(self) -> int:
        """Bytes in the file so far, open chunk included (estimate) [B]."""
        return self.last_tell + self.pending

    def info(self) -> _FileInfo:
        return _FileInfo(self.path, self.min_ns, self.max_ns - self.min_ns, self.messages)


class ResidualLogWriter:
    """Writes a residual-log folder of MCAP files ``<prefix>_<index>.mcap`` (index from 0).

    Lifecycle: construct (creates the folder and the first file), :meth:`write` / :meth:`write_raw` /
    :meth:`write_raw_many`, :meth:`flush` from a timer, :meth:`close` from the shutdown path (SIGINT/SIGTERM,
    ``destroy_node``, ``finally:``). Also a context manager. Thread-safe (one lock).

    Args:
        folder: folder to write; created if missing; must not already hold a log with this prefix.
        prefix: file name prefix.
        chunk_size: uncompressed chunk size [B] at which a chunk is written out.
        flush_interval_s: on :meth:`write`, flush if this long has passed since the last flush [s];
            None: only explicit flushes (a quiet logger is flushed only by :meth:`flush` or :meth:`close`).
        max_bytes: start a new file once the current one reaches this size [B] (None: never).
        max_duration_s: start a new file once the current one spans this much log time [s] (None: never).
        compression: chunk compression, ``'zstd'``, ``'lz4'`` or ``'none'``.
        fsync: also ``os.fsync`` on every flush and close (survives power loss, not only a killed process).
        typestore: rosbags type store for serialization and schemas (default :func:`.bag.default_typestore`).
        clock: monotonic clock for the flush interval [s].
        opener: opens a new file for writing (default: exclusive create, ``open(path, 'xb')``); a seam for
            tests (e.g. a stream that fails like a full disk).

    Raises:
        RecordingError: bad arguments, an existing log in the folder, or the folder is not writable.
    """

    def __init__(
        self,
        folder: str | os.PathLike[str],
        *,
        prefix: str = 'residuals',
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float | None = 1.0,
        max_bytes: int | None = None,
        max_duration_s: float | None = None,
        compression: str = 'zstd',
        fsync: bool = False,
        typestore: Typestore | None = None,
        clock: Callable[[], float] = time.monotonic,
        opener: Callable[[Path], BinaryIO] | None = None,
    ) -> None:
        self.folder = Path(folder)
        if not prefix or '/' in prefix or os.sep in prefix:
            msg = f'residual log prefix {prefix!r}: must be a plain, non-empty file name prefix'
            raise RecordingError(msg)
        if chunk_size <= 0:
            msg = f'residual log chunk_size = {chunk_size}: must be positive [B]'
            raise RecordingError(msg)
        if flush_interval_s is not None and not (flush_interval_s >= 0.0 and math.isfinite(flush_interval_s)):
            msg = f'residual log flush_interval_s = {flush_interval_s}: must be finite and >= 0 [s], or None'
            raise RecordingError(msg)
        if max_bytes is not None and max_bytes <= 0:
            msg = f'residual log max_bytes = {max_bytes}: must be positive [B], or None'
            raise RecordingError(msg)
        if max_duration_s is not None and not (max_duration_s > 0.0 and math.isfinite(max_duration_s)):
            msg = f'residual log max_duration_s = {max_duration_s}: must be finite and positive [s], or None'
            raise RecordingError(msg)
        if compression not in _COMPRESSION:
            msg = f'residual log compression {compression!r}: expected one of {sorted(_COMPRESSION)}'
            raise RecordingError(msg)
        self.prefix = prefix
        self.chunk_size = int(chunk_size)
        self.flush_interval_s = flush_interval_s
        self.max_bytes = max_bytes
        self.max_duration_ns = None if max_duration_s is None else round(max_duration_s * _NS_PER_S)
        self.fsync = fsync
        self._compression = _COMPRESSION[compression]
        self._typestore = typestore or default_typestore()
        self._clock = clock
        self._opener = opener or _open_exclusive
        self._lock = threading.RLock()
        self._msgdefs: dict[str, tuple[bytes, str]] = {}  # msgtype -> (schema text, RIHS01 hash)
        self._topic_types: dict[str, str] = {}
        self._topic_counts: dict[str, int] = {}
        self._finished: list[_FileInfo] = []
        self._finished_bytes = 0
        self._messages = 0
        self._flushed = 0
        self._index = 0
        self._failed: str | None = None
        self._closed = False
        self._file: _OpenFile | None = None

        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            existing = sorted(
                p.name for p in self.folder.iterdir() if p.name == 'metadata.yaml' or _is_log_file(p, prefix)
            )
        except OSError as err:
            msg = f'residual log folder {self.folder}: cannot create or list it: {err}'
            raise RecordingError(msg) from err
        if existing:
            names = ', '.join(existing)
            msg = f'residual log folder {self.folder} already holds a log ({names}); not overwriting'
            raise RecordingError(msg)
        self._file = self._open_next()
        self._last_flush = self._clock()

    # -- public API ------------------------------------------------------------------------------------------

    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: object) -> None:
        """Serialize a rosbags message object with the type store and log it.

        Args:
            topic: topic name (contract name, e.g. ``/gimbal/friction/residual``).
            msgtype: message type, e.g. ``sensor_msgs/msg/JointState``.
            log_time_ns: log time [ns].
            msg: rosbags message dataclass (see :mod:`.bag` ``make_*`` helpers).

        Raises:
            RecordingError: serialization or I/O failed, or the topic was logged before with another type.
        """
        try:
            data = bytes(self._typestore.serialize_cdr(msg, msgtype))
        except (SerdeError, TypesysError, KeyError, AttributeError, TypeError, ValueError, struct.error) as err:
            text = f'residual log: cannot serialize {topic} message as {msgtype}: {err!r}'
            raise RecordingError(text) from err
        self._add(topic, msgtype, int(log_time_ns), data)

    def write_raw(
        self, topic: str, msgtype: str, log_time_ns: int, cdr_bytes: bytes | bytearray | memoryview
    ) -> None:
        """Log an already-serialized CDR message (encapsulation header included, e.g. from a raw subscription).

        Args:
            topic: topic name.
            msgtype: message type.
            log_time_ns: log time [ns].
            cdr_bytes: serialized message.

        Raises:
            RecordingError: I/O failed, the bytes are not CDR, or the topic was logged before with another type.
        """
        data = cdr_bytes if isinstance(cdr_bytes, bytes) else bytes(cdr_bytes)
        if len(data) < 4 or data[0] != 0 or data[1] > 1:
            msg = f'residual log: {topic} message is not plain CDR (encapsulation header {data[:4]!r})'
            raise RecordingError(msg)
        self._add(topic, msgtype, int(log_time_ns), data)

    def write_raw_many(
        self,
        topics: Sequence[tuple[str, str]],
        topic_ids: ArrayLike,
        log_times_ns: ArrayLike,
        datas: Sequence[bytes | bytearray | memoryview],
    ) -> None:
        """Log many already-serialized CDR messages, in the given order, with little overhead per message.

        Message ``k`` is ``datas[k]`` on ``topics[topic_ids[k]]`` (a ``(topic, msgtype)`` pair) at
        ``log_times_ns[k]``. The files written are the same, byte for byte, as from calling :meth:`write_raw` for
        each message in turn (rotation, chunking, channel ids, sequence numbers, statistics and indexes
        included), except that every message is checked before the first is written: on a bad one, nothing of the
        batch is logged. With a ``flush_interval_s`` (a clock read per message) the messages go through
        :meth:`write_raw` one by one; otherwise whole runs of messages are appended to the open MCAP chunk at once.

        Args:
            topics: ``(topic, msgtype)`` pairs.
            topic_ids: (n,) index into ``topics`` of each message.
            log_times_ns: (n,) log times [ns], 0 <= t < 2**63.
            datas: n serialized messages (encapsulation header included).

        Raises:
            RecordingError: a bad batch (lengths, indexes, log times, not plain CDR, a topic with two types, an
                unknown type) before anything is written; I/O failed (the writer then refuses further writes).
        """
        pairs = [(str(topic), str(msgtype)) for topic, msgtype in topics]
        ids = np.asarray(topic_ids, dtype=np.int64).reshape(-1)
        try:
            logs = np.asarray(log_times_ns, dtype=np.int64).reshape(-1)
        except (OverflowError, ValueError, TypeError) as err:
            msg = f'residual log: log times must be integers in [0, 2**63) [ns]: {err}'
            raise RecordingError(msg) from err
        n = len(datas)
        if ids.shape[0] != n or logs.shape[0] != n:
            msg = f'residual log: {n} messages but {ids.shape[0]} topic ids and {logs.shape[0]} log times'
            raise RecordingError(msg)
        if n == 0:
            return
        if ids.min() < 0 or ids.max() >= len(pairs):
            msg = f'residual log: topic ids must index the {len(pairs)} topics given'
            raise RecordingError(msg)
        if logs.min() < 0:
            msg = f'residual log: log time {int(logs.min())} ns is negative'
            raise RecordingError(msg)
        if set(map(type, datas)) != {bytes}:
            datas = [d if isinstance(d, bytes) else bytes(d) for d in datas]
        heads = set(map(_CDR_HEAD, datas))
        if not heads <= _CDR_HEADS:
            k = next(k for k, d in enumerate(datas) if d[:2] not in _CDR_HEADS or len(d) < 4)
            msg = f'residual log: {pairs[ids[k]][0]} message is not plain CDR (encapsulation header {datas[k][:4]!r})'
            raise RecordingError(msg)
        lengths = np.fromiter(map(len, datas), dtype=np.int64, count=n)
        if lengths.min() < 4:
            k = int(np.argmax(lengths < 4))
            msg = f'residual log: {pairs[ids[k]][0]} message is not plain CDR (encapsulation header {datas[k][:4]!r})'
            raise RecordingError(msg)
        canonical: dict[tuple[str, str], int] = {}
        remap = np.array([canonical.setdefault(pair, k) for k, pair in enumerate(pairs)], dtype=np.int64)
        if len(canonical) != len(pairs):  # one id per (topic, msgtype)
            ids = remap[ids]
        used = np.unique(ids).tolist()
        with self._lock:
            self._check_usable()
            types: dict[str, str] = {}
            for t in used:
                topic, msgtype = pairs[t]
                known = self._topic_types.get(topic, types.get(topic))
                if known is not None and known != msgtype:
                    msg = f'residual log: topic {topic} was logged as {known}, not {msgtype}'
                    raise RecordingError(msg)
                types[topic] = msgtype
                self._msgdef(msgtype)  # refuse unknown types before touching the file
            current = self._file
            assert current is not None
            if self.flush_interval_s is not None or _BulkChunk.of(current.writer) is None:
                for k, t, log_ns in zip(range(n), ids.tolist(), logs.tolist()):
                    self._add(pairs[t][0], pairs[t][1], log_ns, datas[k])
                return
            self._add_many(pairs, ids, logs, datas, lengths, used)

    def flush(self) -> None:
        """Write the open chunk out and flush the file (``os.fsync`` too with ``fsync=True``).

        What was flushed survives the process being killed.

        Raises:
            RecordingError: I/O failed (the writer then refuses further writes; data flushed before stays).
        """
        with self._lock:
            self._check_usable()
            current = self._file
            assert current is not None
            try:
                _flush_writer(current.writer)
                if self.fsync:
                    os.fsync(current.stream.fileno())
            except OSError as err:
                self._fail(current.path, 'flushing', err)
            current.last_tell = current.stream.tell()
            current.pending = 0
            self._flushed = self._messages
            self._last_flush = self._clock()

    def close(self) -> None:
        """Finish the open file, then write the folder's ``metadata.yaml``. Idempotent.

        After a failed write or flush, the files are only closed (no footer, no metadata.yaml): their completed
        chunks stay readable with :func:`read_residual_log`.

        Raises:
            RecordingError: finishing the file or writing metadata.yaml failed.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            current, self._file = self._file, None
            if current is None:
                return
            if self._failed is not None:
                with contextlib.suppress(OSError):
                    current.stream.close()
                return
            try:
                self._finish(current)
                self._flushed = self._messages
                self._write_metadata()
            except OSError as err:
                with contextlib.suppress(OSError):
                    current.stream.close()
                self._failed = f'closing: {err}'
                msg = f'residual log {self.folder}: closing failed: {err}'
                raise RecordingError(msg) from err

    @property
    def stats(self) -> ResidualLogStats:
        """Messages, bytes and files so far."""
        with self._lock:
            current = self._file
            files = [x.path for x in self._finished]
            size = self._finished_bytes
            if current is not None:
                files.append(current.path)
                with contextlib.suppress(OSError, ValueError):
                    size += current.stream.tell()
            return ResidualLogStats(
                messages=self._messages,
                flushed_messages=self._flushed,
                bytes=size,
                current_file=None if current is None else current.path,
                files=tuple(files),
            )

    @property
    def failed(self) -> str | None:
        """Why the writer stopped accepting messages (None while healthy)."""
        return self._failed

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    def __enter__(self) -> ResidualLogWriter:
        """Return self."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        """Close; when an exception is already propagating, a failing close does not hide it."""
        if exc_type is None:
            self.close()
        else:
            with contextlib.suppress(RecordingError):
                self.close()

    # -- internals -------------------------------------------------------------------------------------------

    def _check_usable(self) -> None:
        if self._failed is not None:
            msg = f'residual log {self.folder}: writer stopped after an earlier error ({self._failed})'
            raise RecordingError(msg)
        if self._closed:
            msg = f'residual log {self.folder}: writer is closed'
            raise RecordingError(msg)

    def _fail(self, path: Path, doing: str, err: OSError) -> None:
        """Remember an I/O error and raise it as RecordingError (files on disk are left as they are)."""
        self._failed = f'{doing} {path.name}: {err}'
        msg = f'residual log {self.folder}: {doing} {path.name} failed: {err}'
        raise RecordingError(msg) from err

    def _msgdef(self, msgtype: str) -> tuple[bytes, str]:
        known = self._msgdefs.get(msgtype)
        if known is None:
            try:
                text, _ = self._typestore.generate_msgdef(msgtype, ros_version=2)
                digest = self._typestore.hash_rihs01(msgtype)
            except (TypesysError, KeyError) as err:
                msg = f'residual log: unknown message type {msgtype!r} (standard message types only): {err}'
                raise RecordingError(msg) from err
            known = (text.encode('utf-8'), digest)
            self._msgdefs[msgtype] = known
        return known

    def _open_next(self) -> _OpenFile:
        path = self.folder / f'{self.prefix}_{self._index}.mcap'
        try:
            opened = _OpenFile(path, self.chunk_size, self._compression, self._opener)
        except OSError as err:
            self._failed = f'creating {path.name}: {err}'
            msg = f'residual log {self.folder}: cannot create {path.name}: {err}'
            raise RecordingError(msg) from err
        self._index += 1
        return opened

    def _finish(self, current: _OpenFile) -> None:
        """Finish (footer, summary) and close one file; OSError propagates."""
        current.writer.finish()
        current.stream.flush()
        if self.fsync:
            os.fsync(current.stream.fileno())
        size = current.stream.tell()
        current.stream.close()
        self._finished.append(current.info())
        self._finished_bytes += size

    def _rotate(self, current: _OpenFile) -> _OpenFile:
        try:
            self._finish(current)
        except OSError as err:
            self._fail(current.path, 'finishing', err)
        self._flushed = self._messages
        self._last_flush = self._clock()
        self._file = None
        self._file = self._open_next()
        return self._file

    def _channel(self, current: _OpenFile, topic: str, msgtype: str) -> int:
        channel_id = current.channel_ids.get(topic)
        if channel_id is None:
            schema_text, digest = self._msgdef(msgtype)
            schema_id = current.schema_ids.get(msgtype)
            if schema_id is None:
                schema_id = current.writer.register_schema(msgtype, SCHEMA_ENCODING, schema_text)
                current.schema_ids[msgtype] = schema_id
            metadata = {'offered_qos_profiles': _NO_QOS, 'topic_type_hash': digest}
            channel_id = current.writer.register_channel(topic, MESSAGE_ENCODING, schema_id, metadata)
            current.channel_ids[topic] = channel_id
            current.sequence[channel_id] = 0
        return channel_id

    def _add(self, topic: str, msgtype: str, log_time_ns: int, data: bytes) -> None:
        with self._lock:
            self._check_usable()
            known = self._topic_types.get(topic)
            if known is not None and known != msgtype:
                msg = f'residual log: topic {topic} was logged as {known}, not {msgtype}'
                raise RecordingError(msg)
            self._msgdef(msgtype)  # refuse unknown types before touching the file
            current = self._file
            assert current is not None
            if current.messages and (
                (self.max_bytes is not None and current.size() >= self.max_bytes)
                or (self.max_duration_ns is not None and log_time_ns - current.first_ns >= self.max_duration_ns)
            ):
                current = self._rotate(current)
            try:
                channel_id = self._channel(current, topic, msgtype)
                sequence = current.sequence[channel_id] = (current.sequence[channel_id] + 1) & 0xFFFFFFFF
                current.writer.add_message(channel_id, log_time_ns, data, log_time_ns, sequence)
                tell = current.stream.tell()
            except OSError as err:
                self._fail(current.path, 'writing', err)
            self._topic_types[topic] = msgtype
            self._topic_counts[topic] = self._topic_counts.get(topic, 0) + 1
            self._messages += 1
            if current.messages == 0:
                current.first_ns = current.min_ns = current.max_ns = log_time_ns
            else:
                current.min_ns = min(current.min_ns, log_time_ns)
                current.max_ns = max(current.max_ns, log_time_ns)
            current.messages += 1
            if tell != current.last_tell:  # a chunk went out, this message included
                current.last_tell = tell
                current.pending = 0
            else:
                current.pending += len(data) + 31  # message record: opcode, length, 22-byte header
            if self.flush_interval_s is not None and self._clock() - self._last_flush >= self.flush_interval_s:
                self.flush()

    def _add_many(
        self,
        pairs: list[tuple[str, str]],
        ids: NDArray[np.int64],
        logs: NDArray[np.int64],
        datas: Sequence[bytes],
        lengths: NDArray[np.int64],
        used: list[int],
    ) -> None:
        """:meth:`write_raw_many` without a flush interval: runs of messages appended to the chunk at once.

        A run starts at message ``i`` (rotation check and channel registration as :meth:`_add` does them) and
        ends before the first later message that needs one of these steps: a topic without a channel in this
        file, a rotation, or the message after the one that fills the chunk (which mcap then writes out).
        """
        n = ids.shape[0]
        record = lengths + _MESSAGE_OVERHEAD  # message record size [B]: what _add adds to `pending`
        csum = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(record, out=csum[1:])
        where = {t: np.flatnonzero(ids == t) for t in used}
        id_list = ids.tolist()
        i = 0
        while i < n:
            current = self._file
            assert current is not None
            log_i = int(logs[i])
            if current.messages and (
                (self.max_bytes is not None and current.size() >= self.max_bytes)
                or (self.max_duration_ns is not None and log_i - current.first_ns >= self.max_duration_ns)
            ):
                current = self._rotate(current)
            topic, msgtype = pairs[id_list[i]]
            try:
                self._channel(current, topic, msgtype)
                tell = current.stream.tell()
            except OSError as err:
                self._fail(current.path, 'writing', err)
            bulk = _BulkChunk.of(current.writer)
            assert bulk is not None
            # end of the run: the message that fills the chunk (included) ...
            room = self.chunk_size - bulk.count()
            stop = min(n, i + max(room, 0) // _MESSAGE_OVERHEAD + 2)
            over = np.flatnonzero(csum[i + 1 : stop + 1] - csum[i] > room)
            j = i + int(over[0]) + 1 if over.shape[0] else stop
            # ... a topic without a channel in this file ...
            for t in used:
                if pairs[t][0] not in current.channel_ids:
                    pos = where[t]
                    q = int(np.searchsorted(pos, i + 1))
                    if q < pos.shape[0]:
                        j = min(j, int(pos[q]))
            # ... a rotation (checked before each message, as in _add; no chunk goes out inside the run)
            flushed_at_i = tell != current.last_tell  # registering the channel wrote a chunk out
            pending_i = 0 if flushed_at_i else current.pending + int(record[i])
            first_ns = current.first_ns if current.messages else log_i
            if j > i + 1 and self.max_duration_ns is not None:
                late = np.flatnonzero(logs[i + 1 : j] - first_ns >= self.max_duration_ns)
                if late.shape[0]:
                    j = i + 1 + int(late[0])
            if j > i + 1 and self.max_bytes is not None:
                size = tell + pending_i + (csum[i + 1 : j] - csum[i + 1])
                big = np.flatnonzero(size >= self.max_bytes)
                if big.shape[0]:
                    j = i + 1 + int(big[0])
            self._append_run(current, bulk, pairs, ids[i:j], logs[i:j], datas[i:j], csum[i : j + 1] - csum[i])
            try:
                bulk.maybe_finalize()
                tell_after = current.stream.tell()
            except OSError as err:
                self._fail(current.path, 'writing', err)
            if tell_after != tell:  # the chunk went out with the run's last message
                current.last_tell = tell_after
                current.pending = 0
            elif flushed_at_i:
                current.last_tell = tell
                current.pending = int(csum[j] - csum[i + 1])
            else:
                current.pending += int(csum[j] - csum[i])
            i = j

    def _append_run(
        self,
        current: _OpenFile,
        bulk: _BulkChunk,
        pairs: list[tuple[str, str]],
        ids: NDArray[np.int64],
        logs: NDArray[np.int64],
        datas: Sequence[bytes],
        offsets: NDArray[np.int64],
    ) -> None:
        """Append messages whose channels exist to the open chunk; update sequences and counts."""
        m = ids.shape[0]
        channel = np.zeros(m, dtype=np.int64)
        sequence = np.zeros(m, dtype=np.int64)
        runs = []  # (channel id, mask), in order of first appearance (as add_message meets them)
        present, first = np.unique(ids, return_index=True)
        for t in present[np.argsort(first)].tolist():
            topic, msgtype = pairs[t]
            channel_id = current.channel_ids[topic]
            mask = ids == t
            count = int(mask.sum())
            base = current.sequence[channel_id]
            channel[mask] = channel_id
            sequence[mask] = (base + np.arange(1, count + 1, dtype=np.int64)) & 0xFFFFFFFF
            current.sequence[channel_id] = (base + count) & 0xFFFFFFFF
            runs.append((channel_id, mask))
            self._topic_types[topic] = msgtype
            self._topic_counts[topic] = self._topic_counts.get(topic, 0) + count
        header = np.empty(m, dtype=_MESSAGE_HEADER)
        header['opcode'] = _OPCODE_MESSAGE
        header['length'] = offsets[1:] - offsets[:-1] - 9  # record length after opcode and length
        header['channel'] = channel
        header['sequence'] = sequence
        header['log_time'] = logs
        header['publish_time'] = logs
        try:
            bulk.append(header, datas, logs, runs, offsets[:-1])
        except OSError as err:
            self._fail(current.path, 'writing', err)
        log_min, log_max = int(logs.min()), int(logs.max())
        self._messages += m
        if current.messages == 0:
            current.first_ns = int(logs[0])
            current.min_ns, current.max_ns = log_min, log_max
        else:
            current.min_ns = min(current.min_ns, log_min)
            current.max_ns = max(current.max_ns, log_max)
        current.messages += m

    def _write_metadata(self) -> None:
        """Write ``metadata.yaml`` (rosbag2 version 9, storage mcap) atomically; OSError propagates."""
        files = self._finished
        with_messages = [x for x in files if x.messages]
        start = min((x.start_ns for x in with_messages), default=0)
        end = max((x.start_ns + x.duration_ns for x in with_messages), default=0)
        info = {
            'version': 9,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': end - start},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': sum(x.messages for x in files),
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': topic,
                        'type': msgtype,
                        'serialization_format': MESSAGE_ENCODING,
                        'offered_qos_profiles': [],
                        'type_description_hash': self._msgdefs[msgtype][1],
                    },
                    'message_count': self._topic_counts[topic],
                }
                for topic, msgtype in self._topic_types.items()
            ],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [x.path.name for x in files],
            'files': [
                {
                    'path': x.path.name,
                    'starting_time': {'nanoseconds_since_epoch': x.start_ns},
                    'duration': {'nanoseconds': x.duration_ns},
                    'message_count': x.messages,
                }
                for x in files
            ],
            'custom_data': {'writer': LIBRARY},
            'ros_distro': os.environ.get('ROS_DISTRO', ''),
        }
        text = yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False, default_flow_style=False)
        path = self.folder / 'metadata.yaml'
        tmp = path.with_name('metadata.yaml.tmp')
        with tmp.open('w', encoding='utf-8') as out:
            out.write(text)
            out.flush()
            if self.fsync:
                os.fsync(out.fileno())
        tmp.replace(path)


#: bytes of a message record besides its data: opcode, length, channel id, sequence, log and publish time
_MESSAGE_OVERHEAD = 31
_OPCODE_MESSAGE = 0x05
_MESSAGE_HEADER = np.dtype([('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'), ('sequence', '<u4'),
                            ('log_time', '<u8'), ('publish_time', '<u8')])
assert _MESSAGE_HEADER.itemsize == _MESSAGE_OVERHEAD
_MESSAGE_RECORD_HEAD = np.dtype(f'V{_MESSAGE_OVERHEAD}')
_CDR_HEADS = frozenset({b'\x00\x00', b'\x00\x01'})  # CDR big or little endian (what write_raw accepts)
_CDR_HEAD = operator.itemgetter(slice(0, 2))  # the first two bytes of a message


class _PackedMessageIndex(MessageIndex):
    """A ``MessageIndex`` whose (log time, offset) entries are kept packed (``<u8`` pairs), as it writes them.

    :meth:`add_packed` appends a block of entries; tuples that ``ChunkBuilder.add_message`` appends to
    ``records`` meanwhile are packed first, so the entries stay in order. Writes the bytes of ``MessageIndex``.
    """

    def __init__(self, channel_id: int, records: list[tuple[int, int]]) -> None:
        super().__init__(channel_id=channel_id, records=records)
        self.packed: list[bytes] = []

    def _pack_records(self) -> None:
        records = self.records
        if records:
            self.packed.append(struct.pack(f'<{2 * len(records)}Q', *itertools.chain.from_iterable(records)))
            records.clear()

    def add_packed(self, entries: bytes) -> None:
        self._pack_records()
        self.packed.append(entries)

    def write(self, stream: RecordBuilder) -> None:
        self._pack_records()
        entries = b''.join(self.packed)
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(entries))
        stream.write(entries)
        stream.finish_record()


class _BulkChunk:
    """Appends message records to the open chunk of an ``mcap`` writer, as ``Writer.add_message`` would.

    Goes below mcap's public API (pinned mcap 1.6.0: ``Writer`` keeps a ``ChunkBuilder`` whose ``RecordBuilder``
    writes to a ``BytesIO``, per-channel ``MessageIndex`` records and a ``Statistics`` record). :meth:`of` checks
    that structure and returns None for a writer that does not have it (another mcap version, no chunking);
    callers then use ``add_message``. The result is the file ``add_message`` would have written, byte for byte
    (``test/recording/test_residual_log_bulk.py``).
    """

    def __init__(self, writer: McapWriter, builder: ChunkBuilder, stats: object) -> None:
        self._writer = writer
        self._builder = builder
        self._stats = stats

    @staticmethod
    def of(writer: McapWriter) -> _BulkChunk | None:
        builder = getattr(writer, '_Writer__chunk_builder', None)
        stats = getattr(writer, '_Writer__statistics', None)
        finalize = getattr(writer, '_Writer__maybe_finalize_chunk', None)
        if ChunkBuilder is None or not isinstance(builder, ChunkBuilder) or not callable(finalize):
            return None
        record_writer = getattr(builder, 'record_writer', None)
        if not isinstance(getattr(record_writer, '_buffer', None), io.BytesIO):
            return None
        if not isinstance(getattr(builder, 'message_indices', None), dict) or not all(
            isinstance(getattr(builder, name, None), int)
            for name in ('num_messages', 'message_start_time', 'message_end_time')
        ):
            return None
        if not isinstance(getattr(stats, 'channel_message_counts', None), dict) or not all(
            isinstance(getattr(stats, name, None), int)
            for name in ('message_count', 'message_start_time', 'message_end_time')
        ):
            return None
        return _BulkChunk(writer, builder, stats)

    def count(self) -> int:
        """Bytes in the open chunk [B]."""
        return int(self._builder.count)

    def append(
        self,
        header: np.ndarray,
        datas: Sequence[bytes],
        logs: NDArray[np.int64],
        channels: list[tuple[int, NDArray[np.bool_]]],
        offsets: NDArray[np.int64],
    ) -> None:
        """Append message records (``header[k]`` + ``datas[k]``); ``channels`` in order of first appearance."""
        builder = self._builder
        stats = self._stats
        buffer = builder.record_writer._buffer  # noqa: SLF001
        start = buffer.tell()
        m = header.shape[0]
        parts: list[bytes] = [b''] * (2 * m)
        parts[0::2] = header.view(_MESSAGE_RECORD_HEAD).tolist()  # bytes objects (a void dtype keeps NULs)
        parts[1::2] = datas
        buffer.write(b''.join(parts))
        positions = offsets + start
        indices = builder.message_indices
        for channel_id, mask in channels:
            index = indices.get(channel_id)
            if not isinstance(index, _PackedMessageIndex):  # new, or begun by add_message (same place in the dict)
                index = indices[channel_id] = _PackedMessageIndex(channel_id, [] if index is None else index.records)
            entries = np.empty((int(mask.sum()), 2), dtype='<u8')
            entries[:, 0] = logs[mask]
            entries[:, 1] = positions[mask]
            index.add_packed(entries.tobytes())
            counts = stats.channel_message_counts  # type: ignore[attr-defined]
            counts[channel_id] = counts.get(channel_id, 0) + int(mask.sum())
        log_min, log_max = int(logs.min()), int(logs.max())
        if builder.num_messages == 0:
            builder.message_start_time = log_min
        else:
            builder.message_start_time = min(builder.message_start_time, log_min)
        builder.message_end_time = max(builder.message_end_time, log_max)
        builder.num_messages += m
        if stats.message_count == 0:  # type: ignore[attr-defined]
            stats.message_start_time = log_min  # type: ignore[attr-defined]
        else:
            stats.message_start_time = min(stats.message_start_time, log_min)  # type: ignore[attr-defined]
        stats.message_end_time = max(stats.message_end_time, log_max)  # type: ignore[attr-defined]
        stats.message_count += m  # type: ignore[attr-defined]

    def maybe_finalize(self) -> None:
        """Write the chunk out if it is full (as ``add_message`` does after each message)."""
        self._writer._Writer__maybe_finalize_chunk()  # type: ignore[attr-defined]  # noqa: SLF001


def _flush_writer(writer: McapWriter) -> None:
    """End the open chunk (if it holds messages), write it out and flush the stream; OSError propagates."""
    flush = getattr(writer, 'flush', None)
    if flush is not None:  # mcap >= 1.2: public
        flush()
        return
    # older mcap: the same steps through the name-mangled internals  # pragma: no cover
    writer._Writer__finalize_chunk()  # type: ignore[attr-defined]  # noqa: SLF001
    writer._Writer__flush()  # type: ignore[attr-defined]  # noqa: SLF001
    writer._Writer__stream.flush()  # type: ignore[attr-defined]  # noqa: SLF001


def _open_exclusive(path: Path) -> BinaryIO:
    """Create ``path`` for writing; fail if it exists."""
    return path.open('xb')


def _is_log_file(path: Path, prefix: str) -> bool:
    """True for ``<prefix>_<index>.mcap``."""
    return path.suffix == '.mcap' and re.fullmatch(re.escape(prefix) + r'_\d+', path.stem) is not None


# ----------------------------------------------------------------------------------------------------------------
# reading


def residual_log_files(path: str | os.PathLike[str]) -> list[Path]:
    """The MCAP files of a residual-log folder in write order (``name_2`` before ``name_10``); a file: itself.

    Raises:
        RecordingError: the path does not exist or holds no ``.mcap`` file ("not a residual log: ...").
    """
    where = Path(path)
    if where.is_file():
        if where.suffix != '.mcap':
            msg = f'not a residual log: {where} (not an .mcap file)'
            raise RecordingError(msg)
        return [where]
    if not where.is_dir():
        msg = f'not a residual log: {where} (no such file or directory)'
        raise RecordingError(msg)
    try:
        files = [p for p in where.iterdir() if p.suffix == '.mcap' and p.is_file()]
    except OSError as err:
        msg = f'not a residual log: {where} ({err})'
        raise RecordingError(msg) from err
    if not files:
        msg = f'not a residual log: {where} (no .mcap files)'
        raise RecordingError(msg)

    def key(p: Path) -> tuple[str, int, str]:
        match = _FILE_INDEX.match(p.stem)
        assert match is not None
        index = match.group('index')
        return (match.group('stem'), -1 if index is None else int(index), p.name)

    return sorted(files, key=key)


class _Scan:
    """Streams the messages of one MCAP file, complete or torn; remembers how it ended."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.truncated = False
        self.header: Header | None = None
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}

    def records(self) -> Iterator[Schema | Channel | Message]:
        """Schema, Channel and Message records in file order, stopping cleanly at a torn tail.

        Every record of a chunk is parsed (and its CRC checked) before the first is yielded, so a torn chunk
        contributes nothing.
        """
        try:
            stream = self.path.open('rb')
        except OSError as err:
            msg = f'cannot open {self.path}: {err}'
            raise RecordingError(msg) from err
        with stream:
            reader = StreamReader(stream, validate_crcs=True)
            records = iter(reader.records)
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    return
                except InvalidMagic as err:
                    if self.header is None:
                        msg = f'not an MCAP file: {self.path} ({err})'
                        raise RecordingError(msg) from err
                    self.truncated = True  # torn end magic
                    return
                except _TAIL_ERRORS:
                    self.truncated = True
                    return
                except (McapError, OSError) as err:
                    msg = f'cannot read {self.path}: {err}'
                    raise RecordingError(msg) from err
                if isinstance(record, Header):
                    self.header = record
                elif isinstance(record, Schema):
                    self.schemas[record.id] = record
                    yield record
                elif isinstance(record, Channel):
                    self.channels[record.id] = record
                    yield record
                elif isinstance(record, Message):
                    yield record
                # a Footer ends the records; the next step checks the end magic (torn if it is short)


class _Decoder:
    """Deserializes CDR with a private type store, registering types a file defines that the store lacks."""

    def __init__(self) -> None:
        self.store = get_typestore(DEFAULT_STORE)

    def ensure(self, schema: Schema | None, msgtype: str, where: Path) -> None:
        if msgtype in self.store.types:
            return
        if schema is None or schema.encoding != SCHEMA_ENCODING:
            msg = f'{where}: message type {msgtype!r} is unknown and the file has no ros2msg schema for it'
            raise RecordingError(msg)
        try:
            self.store.register(get_types_from_msg(schema.data.decode('utf-8'), msgtype))
        except (TypesysError, UnicodeDecodeError) as err:
            msg = f'{where}: cannot parse the schema of {msgtype!r}: {err}'
            raise RecordingError(msg) from err

    def decode(self, data: bytes, msgtype: str, topic: str, log_time: int, where: Path) -> object:
        try:
            return self.store.deserialize_cdr(data, msgtype)
        except (SerdeError, TypesysError, KeyError) as err:
            msg = f'{where}: cannot decode {topic} message at log time {log_time} ns: {err}'
            raise RecordingError(msg) from err


class _ReadReport:
    """Collects what a read went through."""

    def __init__(self) -> None:
        self.files: list[Path] = []
        self.truncated: list[Path] = []
        self.topic_counts: dict[str, int] = {}


def _as_paths(folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[Path]:
    if isinstance(folders, (str, os.PathLike)):
        return [Path(folders)]
    paths = [Path(x) for x in folders]
    if not paths:
        msg = 'not a residual log: no folder given'
        raise RecordingError(msg)
    return paths


def _iter_log(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    topics: Iterable[str] | None,
    report: _ReadReport,
) -> Iterator[LogMessage]:
    wanted = None if topics is None else ({topics} if isinstance(topics, str) else set(topics))
    decoder = _Decoder()
    for folder in _as_paths(folders):
        files = residual_log_files(folder)
        seen: set[str] = set()
        for path in files:
            scan = _Scan(path)
            report.files.append(path)
            for record in scan.records():
                if not isinstance(record, Message):
                    continue
                channel = scan.channels.get(record.channel_id)
                if channel is None:
                    msg = f'{path}: message on unknown channel {record.channel_id}'
                    raise RecordingError(msg)
                topic = channel.topic
                seen.add(topic)
                report.topic_counts[topic] = report.topic_counts.get(topic, 0) + 1
                if wanted is not None and topic not in wanted:
                    continue
                if channel.message_encoding != MESSAGE_ENCODING:
                    msg = f'{path}: topic {topic} has message encoding {channel.message_encoding!r}, not cdr'
                    raise RecordingError(msg)
                schema = scan.schemas.get(channel.schema_id)
                msgtype = schema.name if schema is not None else ''
                decoder.ensure(schema, msgtype, path)
                msg_obj = decoder.decode(record.data, msgtype, topic, record.log_time, path)
                yield LogMessage(topic, msgtype, record.log_time, msg_obj)
            seen.update(x.topic for x in scan.channels.values())
            if scan.truncated:
                report.truncated.append(path)
        if not seen.intersection(RESIDUAL_LOG_TOPICS):
            have = ', '.join(sorted(seen)) or 'no topics'
            need = ' or '.join(RESIDUAL_LOG_TOPICS)
            msg = f'not a residual log: {folder} (holds {have}; expected {need})'
            raise RecordingError(msg)


def iter_residual_log(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    topics: Iterable[str] | None = None,
) -> Iterator[LogMessage]:
    """Decoded messages of one or more residual-log folders (or single ``.mcap`` files), in file order.

    Files are read in write order (``residuals_0``, ``residuals_1``, ...); a file without a footer (killed
    writer) yields the messages of its completed chunks. The check that a folder holds a residual topic is made
    once its files are read, so the error comes after that folder's messages.

    Args:
        folders: folder(s) or file(s).
        topics: only these topics (default: all).

    Raises:
        RecordingError: no MCAP files, none of :data:`RESIDUAL_LOG_TOPICS`, unreadable or undecodable data.
    """
    yield from _iter_log(folders, topics, _ReadReport())


def read_residual_rows(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
) -> tuple[ResidualRows, ResidualLog]:
    """The residual rows of one or more residual-log folders (sorted by log time), and what was read.

    Raises:
        RecordingError: see :func:`iter_residual_log`; or rows of an unknown layout.
    """
    report = _ReadReport()
    log_times: list[int] = []
    joints: list[str] = []
    rows: list[np.ndarray] = []
    for item in _iter_log(folders, [RESIDUAL_DETAIL], report):
        if item.msgtype != FLOAT64_MULTI_ARRAY_TYPE:
            msg = f'{RESIDUAL_DETAIL} has type {item.msgtype}, expected {FLOAT64_MULTI_ARRAY_TYPE}'
            raise RecordingError(msg)
        data = np.asarray(item.msg.data, dtype=np.float64)  # type: ignore[attr-defined]
        dims = item.msg.layout.dim  # type: ignore[attr-defined]
        log_times.append(item.log_time_ns)
        joints.append(dims[0].label if len(dims) else '')
        rows.append(data)
    order = np.argsort(np.asarray(log_times, dtype=np.int64), kind='stable')
    widths = {r.shape[0] for r in rows}
    if len(widths) > 1:
        msg = f'residual log rows of mixed layouts ({sorted(widths)} values)'
        raise RecordingError(msg)
    try:
        table = np.vstack(rows)[order] if rows else np.empty((0, len(RESIDUAL_FIELDS_V1) + 1))
        detail = rows_from_detail(np.asarray(joints, dtype=np.str_)[order] if joints else np.empty(0, dtype=str),
                                  table)
    except ValueError as err:
        raise RecordingError(f'residual log: {err}') from None
    log = ResidualLog(detail=None, files=tuple(report.files), truncated_files=tuple(report.truncated),
                      topic_counts=dict(report.topic_counts))
    return detail, log


def read_temperature_stream(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The bearing temperatures logged as inputs: times [s] (stamp, or log time if the stamp is zero) and values
    [°C]; empty arrays if the inputs were not logged."""
    times: list[float] = []
    values: list[float] = []
    for item in _iter_log(folders, [TEMPERATURE], _ReadReport()):
        stamp = item.msg.header.stamp  # type: ignore[attr-defined]
        ns = stamp.sec * _NS_PER_S + stamp.nanosec
        times.append((ns or item.log_time_ns) / _NS_PER_S)
        values.append(float(item.msg.temperature))  # type: ignore[attr-defined]
    return np.asarray(times, dtype=np.float64), np.asarray(values, dtype=np.float64)


def read_residual_log(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
) -> ResidualLog:
    """:func:`read_residual_rows` as one record (``detail`` = the rows)."""
    rows, log = read_residual_rows(folders)
    return log._replace(detail=rows)


def recover_mcap(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    compression: str = 'zstd',
) -> RecoveryResult:
    """Rewrite an MCAP file, torn or not, into a valid one holding every message of its completed chunks.

    Schemas, channels (with metadata), log/publish times and sequence numbers are kept; the profile comes from
    the source header.

    Args:
        src: MCAP file to read.
        dst: file to create; must not exist.
        chunk_size: chunk size of the new file [B].
        compression: ``'zstd'``, ``'lz4'`` or ``'none'``.

    Raises:
        RecordingError: ``dst`` exists, ``src`` is not MCAP, or I/O fails.
    """
    source = Path(src)
    target = Path(dst)
    if compression not in _COMPRESSION:
        msg = f'compression {compression!r}: expected one of {sorted(_COMPRESSION)}'
        raise RecordingError(msg)
    if target.exists():
        msg = f'recover_mcap: {target} exists already, not overwriting'
        raise RecordingError(msg)
    if not source.is_file():
        msg = f'recover_mcap: {source} is not a file'
        raise RecordingError(msg)
    scan = _Scan(source)
    count = 0
    try:
        with target.open('xb') as stream:
            writer = McapWriter(stream, chunk_size=chunk_size, compression=_COMPRESSION[compression])
            started = False
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}
            for record in scan.records():
                if not started:
                    header = scan.header
                    profile = header.profile if header is not None else PROFILE
                    library = f'{LIBRARY} recover_mcap' + (f' from {header.library}' if header else '')
                    writer.start(profile=profile, library=library)
                    started = True
                if isinstance(record, Schema):  # the summary repeats schemas and channels: keep the first
                    if record.id not in schema_ids:
                        schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
                elif isinstance(record, Channel):
                    if record.id in channel_ids:
                        continue
                    schema_id = schema_ids.get(record.schema_id, 0)
                    channel_ids[record.id] = writer.register_channel(
                        record.topic, record.message_encoding, schema_id, record.metadata
                    )
                elif record.channel_id in channel_ids:
                    writer.add_message(
                        channel_ids[record.channel_id], record.log_time, record.data, record.publish_time,
                        record.sequence,
                    )
                    count += 1
            if not started:
                writer.start(profile=scan.header.profile if scan.header else PROFILE, library=LIBRARY)
            writer.finish()
    except RecordingError:
        with contextlib.suppress(OSError):
            target.unlink()
        raise
    except OSError as err:
        msg = f'recover_mcap: writing {target}: {err}'
        raise RecordingError(msg) from err
    return RecoveryResult(messages=count, truncated=scan.truncated)
