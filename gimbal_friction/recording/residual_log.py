"""The residual log writer: a folder of MCAP files written with mcap's public writer API, readable after a crash.
One job in one module: the writer (rotation, chunking, crash safety and the closing metadata share its state).

docs/ros.md "Files": ROS 2 profile, ``ros2msg`` schemas, CDR messages, standard message types only,
rotated by size or duration; closed cleanly, the folder also has a rosbag2 ``metadata.yaml`` (version 9) so
``ros2 bag info`` and ``rosbags.highlevel.AnyReader`` open it. Chunks are small and flushed on a timer, so a
process killed with SIGKILL leaves files whose completed chunks are read back by :mod:`.residual_read`, and
rewritten into complete files by ``gimbal-friction recover`` (:mod:`.recover`); ROS2_SETUP.md §6: the rosbags
writer leaves nothing readable in that case.

Messages go through ``mcap.writer.Writer.add_message``; :meth:`ResidualLogWriter.write_raw_many` appends whole runs
of messages through :mod:`.mcap_bulk` when the installed mcap allows it (same bytes, faster; without rotation by
size, a full chunk is compressed in a worker thread while the next run is appended).

Reading is :mod:`.residual_read` (``read_residual_rows``, ``iter_residual_rows``, ``iter_residual_log``),
recovery :mod:`.recover`.

Times: ``log_time_ns`` is the log (receive, or for ``replay`` the bag's) time [ns]. Sizes in bytes [B].
"""

from __future__ import annotations

import contextlib
import math
import operator
import os
import re
import struct
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, NamedTuple, cast

import numpy as np
import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError

from gimbal_friction.common.files import write_bytes_atomic
from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.recording import mcap_bulk
from gimbal_friction.recording.cdr import default_typestore, distinct
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.schemas import SCHEMAS
from gimbal_friction.recording.topics import MCAP_PROFILE, MESSAGE_ENCODING, SCHEMA_ENCODING

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from types import TracebackType

    from numpy.typing import ArrayLike, NDArray
    from rosbags.typesys.store import Typestore

__all__ = [
    'DEFAULT_CHUNK_SIZE',
    'MESSAGE_ENCODING',
    'PROFILE',
    'SCHEMA_ENCODING',
    'ResidualLogStats',
    'ResidualLogWriter',
]

PROFILE = MCAP_PROFILE
#: default chunk size [B]: small, so little is lost when the process is killed
DEFAULT_CHUNK_SIZE = 64 * 1024
LIBRARY = 'gimbal_friction residual_log (mcap-python)'

_COMPRESSION = {'none': CompressionType.NONE, 'lz4': CompressionType.LZ4, 'zstd': CompressionType.ZSTD}
#: channel metadata as rosbag2 (version 9) writes it; '[]' = no recorded QoS offers (a YAML sequence)
_NO_QOS = '[]'
_CDR_HEADS = frozenset({b'\x00\x00', b'\x00\x01'})  # CDR big or little endian (what write_raw accepts)
_CDR_HEAD = operator.itemgetter(slice(0, 2))  # the first two bytes of a message
_MESSAGE_OVERHEAD = mcap_bulk.MESSAGE_OVERHEAD


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
        self.max_duration_ns = None if max_duration_s is None else round(max_duration_s * NS_PER_S)
        self.fsync = fsync
        self._compression = _COMPRESSION[compression]
        self._own_typestore = typestore   # (None: the default store, built only if a message object is written)
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
            data = bytes(self._typestore().serialize_cdr(msg, msgtype))
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
        *,
        lengths: ArrayLike | None = None,
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
            lengths: (n,) ``len`` of each message, from a caller that knows them and has checked the messages'
                encapsulation headers itself (``replay``: the rows it serialized, and the bag's messages as they
                were read): the per-message checks of type, header and length, three passes over the messages,
                are then skipped. Every run of messages appended is checked against its lengths; a mismatch fails
                the writer (RecordingError) instead of writing a wrong file.

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
        if lengths is not None:   # the caller's lengths, its headers checked (see the docstring)
            given = np.asarray(lengths, dtype=np.int64).reshape(-1)
            if given.shape[0] != n or (n and given.min() < 4):
                msg = f'residual log: {given.shape[0]} lengths for {n} messages, or a message under 4 bytes'
                raise RecordingError(msg)
            given_blobs = cast('Sequence[bytes]', datas)
            self._write_many(pairs, ids, logs, given_blobs, given)
            return
        blobs: Sequence[bytes] = (
            cast('Sequence[bytes]', datas) if set(map(type, datas)) == {bytes}
            else [d if isinstance(d, bytes) else bytes(d) for d in datas]
        )
        heads = set(map(_CDR_HEAD, blobs))
        if not heads <= _CDR_HEADS:
            k = next(k for k, d in enumerate(blobs) if d[:2] not in _CDR_HEADS or len(d) < 4)
            msg = f'residual log: {pairs[ids[k]][0]} message is not plain CDR (encapsulation header {blobs[k][:4]!r})'
            raise RecordingError(msg)
        sizes = np.fromiter(map(len, blobs), dtype=np.int64, count=n)
        if sizes.min() < 4:
            k = int(np.argmax(sizes < 4))
            msg = f'residual log: {pairs[ids[k]][0]} message is not plain CDR (encapsulation header {blobs[k][:4]!r})'
            raise RecordingError(msg)
        self._write_many(pairs, ids, logs, blobs, sizes)

    def _write_many(self, pairs: list[tuple[str, str]], ids: NDArray[np.int64], logs: NDArray[np.int64],
                    blobs: Sequence[bytes], lengths: NDArray[np.int64]) -> None:
        """:meth:`write_raw_many` once the messages are checked: topics and types, then the runs."""
        n = ids.shape[0]
        canonical: dict[tuple[str, str], int] = {}
        remap = np.array([canonical.setdefault(pair, k) for k, pair in enumerate(pairs)], dtype=np.int64)
        if len(canonical) != len(pairs):  # one id per (topic, msgtype)
            ids = remap[ids]
        used = distinct(ids)
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
            assert current is not None  # noqa: S101  # narrowing for the type checker: a file is open here
            if self.flush_interval_s is not None or mcap_bulk.bulk_chunk(current.writer) is None:
                for k, t, log_ns in zip(range(n), ids.tolist(), logs.tolist(), strict=True):
                    self._add(pairs[t][0], pairs[t][1], log_ns, blobs[k])
                return
            self._add_many(pairs, ids, logs, blobs, lengths, used)

    def flush(self) -> None:
        """Write the open chunk out and flush the file (``os.fsync`` too with ``fsync=True``).

        What was flushed survives the process being killed.

        Raises:
            RecordingError: I/O failed (the writer then refuses further writes; data flushed before stays).
        """
        with self._lock:
            self._check_usable()
            current = self._file
            assert current is not None  # noqa: S101  # narrowing for the type checker: a file is open here
            try:
                current.writer.flush()  # type: ignore[no-untyped-call]  # mcap's Writer.flush is unannotated
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
        chunks stay readable with :func:`~.residual_read.read_residual_rows`.

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
            except (OSError, RecordingError) as err:
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

    def __enter__(self) -> ResidualLogWriter:  # noqa: PYI034  # typing.Self needs Python 3.11; not subclassed
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

    def _fail(self, path: Path, doing: str, err: OSError | ValueError) -> None:
        """Remember an I/O error and raise it as RecordingError (files on disk are left as they are)."""
        self._failed = f'{doing} {path.name}: {err}'
        msg = f'residual log {self.folder}: {doing} {path.name} failed: {err}'
        raise RecordingError(msg) from err

    def _typestore(self) -> Typestore:
        """The type store given, else the default one (built on first use)."""
        return self._own_typestore if self._own_typestore is not None else default_typestore()

    def _msgdef(self, msgtype: str) -> tuple[bytes, str]:
        """The schema (message definition, RIHS01 hash) of ``msgtype``: from :data:`.schemas.SCHEMAS` with the
        default store (no type store built), else generated by the type store."""
        known = self._msgdefs.get(msgtype)
        if known is None and self._own_typestore is None and msgtype in SCHEMAS:
            text, digest = SCHEMAS[msgtype]
            known = self._msgdefs[msgtype] = (text.encode('utf-8'), digest)
        if known is None:
            store = self._typestore()
            try:
                text, _ = store.generate_msgdef(msgtype, ros_version=2)
                digest = store.hash_rihs01(msgtype)
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
        current.writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish is unannotated
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
            assert current is not None  # noqa: S101  # narrowing for the type checker: a file is open here
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
        # without rotation by size, a full chunk is compressed in a worker thread while the next run is appended
        # (the size of the file is then known only once the chunk is written out)
        pipelined = self.max_bytes is None
        bulk: mcap_bulk.BulkChunk | None = None
        i = 0
        while i < n:
            current = self._file
            assert current is not None  # noqa: S101  # narrowing for the type checker: a file is open here
            log_i = int(logs[i])
            if current.messages and (
                (self.max_bytes is not None and current.size() >= self.max_bytes)
                or (self.max_duration_ns is not None and log_i - current.first_ns >= self.max_duration_ns)
            ):
                if bulk is not None:
                    self._finish_pending(current, bulk)
                    bulk = None
                current = self._rotate(current)
            topic, msgtype = pairs[id_list[i]]
            if bulk is not None and topic not in current.channel_ids:  # registering may write a chunk out
                self._finish_pending(current, bulk)
            try:
                self._channel(current, topic, msgtype)
                # (pipelined: unused, and a tell per run is a system call that hands the GIL to the worker)
                tell = 0 if pipelined else current.stream.tell()
            except OSError as err:
                self._fail(current.path, 'writing', err)
            if bulk is None:
                bulk = mcap_bulk.bulk_chunk(current.writer)
            assert bulk is not None  # noqa: S101  # narrowing for the type checker: set with the file
            # end of the run: the message that fills the chunk (included) ...
            room = self.chunk_size - bulk.pending()
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
            if pipelined:
                try:
                    closed = bulk.maybe_finalize_pipelined()
                except OSError as err:
                    self._fail(current.path, 'writing', err)
                current.pending = 0 if closed else current.pending + int(csum[j] - csum[i])
                i = j
                continue
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
        if bulk is not None:
            assert self._file is not None  # noqa: S101  # narrowing for the type checker: bulk is set with the file
            self._finish_pending(self._file, bulk)

    def _finish_pending(self, current: _OpenFile, bulk: mcap_bulk.BulkChunk) -> None:
        """Write out the chunks being compressed in the worker thread, if any."""
        try:
            bulk.finish_pending()
            current.last_tell = current.stream.tell()
        except OSError as err:
            self._fail(current.path, 'writing', err)

    def _append_run(
        self,
        current: _OpenFile,
        bulk: mcap_bulk.BulkChunk,
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
        # the topics of the run in order of first appearance, as add_message meets them (a bincount and one mask
        # per topic: a few topics in runs of thousands of messages, where np.unique sorts the run)
        tally = np.bincount(ids, minlength=len(pairs))
        masks = {t: ids == t for t in np.flatnonzero(tally).tolist()}
        groups: list[tuple[int, NDArray[np.bool_], int]] = []   # (channel id, its messages, their count)
        for t in sorted(masks, key=lambda t: int(masks[t].argmax())):
            topic, msgtype = pairs[t]
            channel_id = current.channel_ids[topic]
            mask = masks[t]
            count = int(tally[t])
            groups.append((channel_id, mask, count))
            base = current.sequence[channel_id]
            channel[mask] = channel_id
            sequence[mask] = (base + np.arange(1, count + 1, dtype=np.int64)) & 0xFFFFFFFF
            current.sequence[channel_id] = (base + count) & 0xFFFFFFFF
            self._topic_types[topic] = msgtype
            self._topic_counts[topic] = self._topic_counts.get(topic, 0) + count
        try:
            bulk.append(channel, sequence, logs, datas, offsets, groups)
        except (OSError, ValueError) as err:   # (ValueError: lengths given that are not the messages')
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
        """Write ``metadata.yaml`` (rosbag2 version 9, storage mcap) atomically.

        Raises:
            RecordingError: it cannot be written.
        """
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
        write_bytes_atomic(self.folder / 'metadata.yaml', text.encode('utf-8'), fsync=self.fsync,
                           what='rosbag2 metadata', error=RecordingError)


def _open_exclusive(path: Path) -> BinaryIO:
    """Create ``path`` for writing; fail if it exists."""
    return path.open('xb')


def _is_log_file(path: Path, prefix: str) -> bool:
    """True for ``<prefix>_<index>.mcap``."""
    return path.suffix == '.mcap' and re.fullmatch(re.escape(prefix) + r'_\d+', path.stem) is not None
