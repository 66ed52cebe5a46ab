"""The bulk fast path of the residual-log writer: many message records appended to an open MCAP chunk at once.

``mcap.writer.Writer.add_message`` costs a few microseconds per message (a ``Message`` object, a record builder, a
message-index tuple, statistics). :class:`BulkChunk` appends a whole run of message records to the writer's open
chunk with numpy and updates the same state -- the result is the file ``add_message`` would have written, byte for
byte (``test/recording/test_mcap_bulk.py``).

This is the only module that goes below mcap's public API: it uses the writer's private chunk builder and
statistics (``Writer.__chunk_builder``, ``Writer.__statistics``, ``Writer.__maybe_finalize_chunk``; for
:meth:`BulkChunk.maybe_finalize_pipelined`, which compresses a full chunk in a worker thread while the next one is
built, also the fields ``Writer.__finalize_chunk`` uses), whose layout is
that of the pinned mcap version (:data:`SUPPORTED_MCAP_VERSIONS`, requirements.txt). :func:`bulk_chunk` checks the
installed version and that structure and returns None otherwise (another mcap version, a writer without chunks, or
:data:`ENABLED` set to False); the writer then uses ``add_message``, message by message: same files, slower.

Times: log times [ns]. Sizes in bytes [B].
"""

from __future__ import annotations

import collections
import io
import itertools
import struct
import threading
import zlib
from concurrent.futures import Future, ThreadPoolExecutor
from importlib import metadata
from typing import TYPE_CHECKING

import lz4.frame
import numpy as np
import zstandard
from mcap.opcode import Opcode
from mcap.records import Chunk, ChunkIndex, MessageIndex
from mcap.writer import CompressionType, IndexType

from gimbal_friction.recording.mcap_scan import MESSAGE_RECORD_HEAD

_CHUNK_BUILDER: type | None
try:  # the chunk builder of mcap's writer (private; checked by bulk_chunk)
    from mcap._chunk_builder import ChunkBuilder as _CHUNK_BUILDER
except ImportError:  # pragma: no cover - another mcap layout: the writer falls back to add_message
    _CHUNK_BUILDER = None

if TYPE_CHECKING:
    from collections.abc import Sequence

    from mcap.data_stream import RecordBuilder
    from mcap.writer import Writer as McapWriter
    from numpy.typing import NDArray

__all__ = ['ENABLED', 'MESSAGE_OVERHEAD', 'SUPPORTED_MCAP_VERSIONS', 'BulkChunk', 'bulk_chunk', 'mcap_version']

#: mcap versions whose writer internals this module knows (requirements.txt pins the first)
SUPPORTED_MCAP_VERSIONS = ('1.6.0',)
#: False: never use the fast path (tests force the fallback with it)
ENABLED = True
#: bytes of a message record besides its data: opcode, length, channel id, sequence, log and publish time [B]
MESSAGE_OVERHEAD = MESSAGE_RECORD_HEAD.itemsize
_OPCODE_MESSAGE = 0x05
_RECORD_HEAD_BYTES = np.dtype(f'V{MESSAGE_OVERHEAD}')


def mcap_version() -> str:
    """The installed mcap version ('' if unknown)."""
    try:
        return metadata.version('mcap')
    except metadata.PackageNotFoundError:  # pragma: no cover - mcap is a dependency
        return ''


_VERSION_OK = mcap_version() in SUPPORTED_MCAP_VERSIONS


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
        stream.finish_record()  # type: ignore[no-untyped-call]  # mcap's record writer is unannotated


class BulkChunk:
    """Appends message records to the open chunk of an mcap ``Writer``, as ``Writer.add_message`` would.

    Built by :func:`bulk_chunk`. The caller decides where runs end (a run must not need a new channel, a file
    rotation or a chunk written out in its middle) and calls :meth:`maybe_finalize` after each run.
    """

    def __init__(self, writer: McapWriter, builder: object, stats: object) -> None:
        self._writer = writer
        self._builder = builder
        self._stats = stats
        #: chunks handed to the worker thread, oldest first (written out in this order)
        self._pending: collections.deque[tuple[Future[tuple[str, bytes, int, int]], tuple[int, int],
                                               dict[int, MessageIndex]]] = collections.deque()
        #: the writer has what :meth:`maybe_finalize_pipelined` uses (set by :func:`bulk_chunk`)
        self.pipelined = False

    def pending(self) -> int:
        """Bytes in the open chunk [B]."""
        return int(self._builder.count)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints

    def append(
        self,
        channel: NDArray[np.int64],
        sequence: NDArray[np.int64],
        log_time: NDArray[np.int64],
        datas: Sequence[bytes],
        record_offsets: NDArray[np.int64],
        groups: Sequence[tuple[int, NDArray[np.bool_], int]],
    ) -> None:
        """Append message records ``k`` (channel id, sequence, log time = publish time [ns], ``datas[k]``).

        Args:
            channel: (m,) channel ids.
            sequence: (m,) sequence numbers.
            log_time: (m,) log times [ns].
            datas: m serialized messages.
            record_offsets: (m + 1,) offset of each record from the first, then the end of the last [B]
                (cumulative ``len(data) + MESSAGE_OVERHEAD``).
            groups: ``(channel id, (m,) mask of its messages, their count)`` per channel of the run, in order of
                first appearance (the order ``add_message`` would have met them in).

        Raises:
            OSError: the chunk buffer could not be written.
        """
        m = channel.shape[0]
        header = np.empty(m, dtype=MESSAGE_RECORD_HEAD)
        header['opcode'] = _OPCODE_MESSAGE
        header['length'] = record_offsets[1:] - record_offsets[:-1] - 9  # record length after opcode and length
        header['channel'] = channel
        header['sequence'] = sequence
        header['log_time'] = log_time
        header['publish_time'] = log_time
        builder = self._builder
        stats = self._stats
        buffer = builder.record_writer._buffer  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        start = buffer.tell()
        parts: list[bytes] = [b''] * (2 * m)
        parts[0::2] = header.view(_RECORD_HEAD_BYTES).tolist()  # bytes objects (a void dtype keeps NULs)
        parts[1::2] = datas
        records = b''.join(parts)
        if len(records) != int(record_offsets[-1] - record_offsets[0]):   # lengths given by the caller, checked
            msg = (f'bulk chunk: the messages hold {len(records) - MESSAGE_OVERHEAD * m} bytes, their lengths say '
                   f'{int(record_offsets[-1] - record_offsets[0]) - MESSAGE_OVERHEAD * m}')
            raise ValueError(msg)
        buffer.write(records)
        positions = record_offsets[:-1] + start
        indices = builder.message_indices  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        counts = stats.channel_message_counts  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        for channel_id, mask, count in groups:  # in order of first appearance, as add_message
            index = indices.get(channel_id)
            if not isinstance(index, _PackedMessageIndex):  # new, or begun by add_message (same place in the dict)
                index = indices[channel_id] = _PackedMessageIndex(channel_id, [] if index is None else index.records)
            entries = np.empty((count, 2), dtype='<u8')
            entries[:, 0] = log_time[mask]
            entries[:, 1] = positions[mask]
            index.add_packed(entries.tobytes())
            counts[channel_id] = counts.get(channel_id, 0) + count
        log_min, log_max = int(log_time.min()), int(log_time.max())
        if builder.num_messages == 0:  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
            builder.message_start_time = log_min  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        else:
            builder.message_start_time = min(builder.message_start_time, log_min)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        builder.message_end_time = max(builder.message_end_time, log_max)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        builder.num_messages += m  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        if stats.message_count == 0:  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
            stats.message_start_time = log_min  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        else:
            stats.message_start_time = min(stats.message_start_time, log_min)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        stats.message_end_time = max(stats.message_end_time, log_max)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        stats.message_count += m  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints

    def maybe_finalize(self) -> None:
        """Write the chunk out if it is full (as ``add_message`` does after each message); OSError propagates."""
        self._writer._Writer__maybe_finalize_chunk()  # type: ignore[attr-defined]  # mcap's private chunk finaliser (name-mangled, no hints)

    def maybe_finalize_pipelined(self) -> bool:
        """:meth:`maybe_finalize`, compressing the full chunk in a worker thread while the caller goes on.

        The chunk is closed (statistics counted, the builder emptied) now and written out by the next call that
        closes a chunk, or by :meth:`finish_pending`, which the caller must call before anything else writes to the
        file (``add_message``, ``flush``, ``finish``): the records then follow each other as
        ``Writer.__finalize_chunk`` writes them, byte for byte. At most :data:`PIPELINE_DEPTH` chunks are in
        flight (more than one: each hand-over to the worker and back waits for the GIL, up to a switch interval
        each way, which one chunk in flight turned into waiting). True if a chunk was closed.
        """
        writer = self._writer
        builder = self._builder
        if not self.pipelined:
            before = builder.num_messages  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
            self.maybe_finalize()
            return bool(before) and builder.num_messages == 0  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        if builder.count <= writer._Writer__chunk_size:  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
            return False
        while self._pending and (len(self._pending) >= PIPELINE_DEPTH or self._pending[0][0].done()):
            self._write_oldest()
        if builder.num_messages == 0:  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
            return False
        self._stats.chunk_count += 1  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        data = builder.end()  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        span = (builder.message_start_time, builder.message_end_time)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        indices = dict(builder.message_indices)  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        compression = writer._Writer__compression  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
        crcs = bool(writer._Writer__enable_crcs)  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
        self._pending.append((_executor().submit(_compress, data, compression, crcs), span, indices))
        builder.reset()  # type: ignore[attr-defined]  # mcap's ChunkBuilder and Statistics internals carry no type hints
        return True

    def finish_pending(self) -> None:
        """Write out the chunks handed to the worker thread, if any, in order (as ``Writer.__finalize_chunk``
        would have); OSError propagates."""
        while self._pending:
            self._write_oldest()

    def _write_oldest(self) -> None:
        """Write out the oldest chunk handed to the worker thread (waiting for it); OSError propagates."""
        future, (start, end), indices = self._pending.popleft()
        name, compressed, size, crc = future.result()
        writer = self._writer
        flush = writer._Writer__flush  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
        stream = writer._Writer__stream  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
        record = writer._Writer__record_builder  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
        chunk = Chunk(compression=name, data=compressed, message_start_time=start, message_end_time=end,
                      uncompressed_crc=crc, uncompressed_size=size)
        flush()
        chunk_start_offset = stream.tell()
        chunk.write(record)
        chunk_size = record.count
        chunk_index = ChunkIndex(message_start_time=start, message_end_time=end, chunk_start_offset=chunk_start_offset,
                                 chunk_length=chunk_size, message_index_offsets={}, message_index_length=0,
                                 compression=name, compressed_size=len(compressed), uncompressed_size=size)
        flush()
        message_index_start_offset = stream.tell()
        if writer._Writer__index_types & IndexType.MESSAGE:  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)
            for channel_id, index in indices.items():
                chunk_index.message_index_offsets[channel_id] = message_index_start_offset + record.count
                index.write(record)
        chunk_index.message_index_length = record.count
        flush()
        writer._Writer__chunk_indices.append(chunk_index)  # type: ignore[attr-defined]  # mcap's private writer state (name-mangled, no hints)


#: chunks compressed in the worker thread at most while the caller builds the next one
PIPELINE_DEPTH = 4
_EXECUTOR: ThreadPoolExecutor | None = None


def _executor() -> ThreadPoolExecutor:
    """The one worker thread that compresses chunks (zstd, lz4 and crc32 release the GIL)."""
    global _EXECUTOR  # noqa: PLW0603 - created on first use, shared by every writer
    if _EXECUTOR is None:
        _EXECUTOR = ThreadPoolExecutor(max_workers=1, thread_name_prefix='mcap-chunk')
    return _EXECUTOR


_LOCAL = threading.local()


def _zstd() -> zstandard.ZstdCompressor:
    """This thread's zstd compressor (``zstandard.compress``'s level and options; made once, not per chunk)."""
    compressor = getattr(_LOCAL, 'zstd', None)
    if compressor is None:
        compressor = _LOCAL.zstd = zstandard.ZstdCompressor()
    return compressor


def _compress(data: bytes, compression: CompressionType, crcs: bool) -> tuple[str, bytes, int, int]:
    """(compression name, compressed records, uncompressed size [B], CRC) of a chunk, as ``Writer.__finalize_chunk``
    computes them."""
    if compression == CompressionType.LZ4:
        name, compressed = 'lz4', lz4.frame.compress(data)
    elif compression == CompressionType.ZSTD:  # what zstandard.compress(data) gives, with a compressor kept
        name, compressed = 'zstd', _zstd().compress(data)
    else:
        name, compressed = '', data
    return name, compressed, len(data), zlib.crc32(data) if crcs else 0


def bulk_chunk(writer: McapWriter) -> BulkChunk | None:
    """The fast path for ``writer``, or None (use ``add_message``): see the module docstring."""
    if not (ENABLED and _VERSION_OK) or _CHUNK_BUILDER is None:
        return None
    builder = getattr(writer, '_Writer__chunk_builder', None)
    stats = getattr(writer, '_Writer__statistics', None)
    finalize = getattr(writer, '_Writer__maybe_finalize_chunk', None)
    if not isinstance(builder, _CHUNK_BUILDER) or not callable(finalize):
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
    bulk = BulkChunk(writer, builder, stats)
    bulk.pipelined = (
        all(callable(getattr(writer, f'_Writer__{name}', None)) for name in ('flush', 'finalize_chunk'))
        and isinstance(getattr(writer, '_Writer__chunk_indices', None), list)
        and isinstance(getattr(writer, '_Writer__chunk_size', None), int)
        and isinstance(getattr(writer, '_Writer__compression', None), CompressionType)
        and isinstance(getattr(writer, '_Writer__index_types', None), IndexType)
        and all(hasattr(writer, f'_Writer__{name}') for name in ('enable_crcs', 'stream', 'record_builder'))
    )
    return bulk
