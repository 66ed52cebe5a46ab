"""Every readable record of an MCAP file, whether it is complete, cut short or damaged.
One job in one module: one tolerant MCAP reader (the record parser and its damage bookkeeping).

The MCAP format (https://mcap.dev/spec) is read here directly, record by record, so that damage stays local:

- a file cut short (a killed writer, a full disk) gives every record before the cut, including the complete records
  of a last chunk that was cut inside (when its compression lets a prefix be decoded);
- a chunk whose bytes are corrupted (CRC mismatch, failed decompression, inconsistent lengths) is skipped and
  counted, and the scan goes on with the next chunk; when a record's framing itself is corrupted, the scan
  resynchronises on the next record that is plainly a chunk (opcode, lengths and compression name consistent);
- a complete file's summary section (schemas, channels, statistics) is read first, so channels whose defining chunk
  was lost are still known.

Messages come out as :class:`MessageBlock` s -- the messages of one chunk as numpy arrays over the chunk's bytes --
so a reader can select and decode them in bulk (:mod:`.residual_read`) and a copier can rewrite them
(:mod:`.recover`). When the message index records that follow a chunk are present, the message positions are taken
from them and only the few records between messages (schemas, channels) are parsed one by one.

Times: ``log_time`` and ``publish_time`` are the records' [ns]. Sizes and offsets in bytes [B].
"""

from __future__ import annotations

import mmap
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from gimbal_friction.recording.errors import LIBRARY_READ_ERRORS, RecordingError

if TYPE_CHECKING:
    import os
    from collections.abc import Generator, Iterator

    from numpy.typing import NDArray

__all__ = [
    'MAGIC',
    'MESSAGE_RECORD_HEAD',
    'ChannelRecord',
    'McapScanner',
    'MessageBlock',
    'ScanReport',
    'SchemaRecord',
]

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_MESSAGE_INDEX = 0x07
OP_STATISTICS = 0x0B
OP_DATA_END = 0x0F
_KNOWN_OPCODES = frozenset(range(0x01, 0x10))
#: records of a summary section (schemas, channels, chunk/attachment/metadata indexes, statistics, offsets, footer)
_SUMMARY_OPCODES = frozenset({0x02, 0x03, 0x04, 0x08, 0x0A, 0x0B, 0x0D, 0x0E})
#: a message record before its data: opcode, record length, channel id, sequence, log time, publish time
MESSAGE_RECORD_HEAD = np.dtype([('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'), ('sequence', '<u4'),
                                ('log_time', '<u8'), ('publish_time', '<u8')])
_HEAD = MESSAGE_RECORD_HEAD.itemsize  # 31 [B]
_FOOTER_SIZE = 1 + 8 + 20  # opcode, length, summary start, summary offset start, summary crc [B]
_COMPRESSIONS = ('', 'zstd', 'lz4')
_U16 = struct.Struct('<H').unpack_from
_U32 = struct.Struct('<I').unpack_from
_U64 = struct.Struct('<Q').unpack_from
_OP_LEN = struct.Struct('<BQ').unpack_from
_CHUNK_HEAD = struct.Struct('<QQQI').unpack_from  # start time, end time, uncompressed size, uncompressed crc


class SchemaRecord(NamedTuple):
    """An MCAP Schema record."""

    id: int
    name: str
    encoding: str
    data: bytes


class ChannelRecord(NamedTuple):
    """An MCAP Channel record."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


class MessageBlock(NamedTuple):
    """Messages of one chunk (or of a run of messages outside chunks), in file order, as arrays over ``buffer``."""

    buffer: bytes
    """The chunk's decompressed records."""
    channel_id: NDArray[np.int64]
    sequence: NDArray[np.int64]
    log_time: NDArray[np.int64]
    """Log time of each message [ns]."""
    publish_time: NDArray[np.int64]
    """Publish time of each message [ns]."""
    data_start: NDArray[np.int64]
    """Offset of each message's data in ``buffer`` [B]."""
    data_length: NDArray[np.int64]
    """Length of each message's data [B]."""

    def __len__(self) -> int:
        """Number of messages [-] (not the number of fields)."""
        return int(self.channel_id.shape[0])

    def data(self, k: int) -> bytes:
        """The serialized data of message ``k``."""
        start = int(self.data_start[k])
        return self.buffer[start : start + int(self.data_length[k])]


@dataclass
class ScanReport:
    """How a scan went: where the file ended, what was skipped, what was lost."""

    path: Path
    profile: str | None = None
    """Profile of the file's header (None before a header was read)."""
    library: str = ''
    complete: bool = False
    """The file ends with a footer and the end magic."""
    truncated: bool = False
    """The file ends inside a record or without a footer."""
    chunks: int = 0
    """Chunks read [-]."""
    bad_chunks: int = 0
    """Chunks skipped because their bytes are damaged [-]."""
    lost_messages: int = 0
    """Messages known to be lost (from the message indexes of skipped chunks) [-]."""
    unknown_loss: bool = False
    """Some lost bytes held an unknown number of messages (a chunk cut short or damaged without an index)."""
    skipped_bytes: int = 0
    """Bytes passed over while resynchronising or at a torn end [B]."""
    expected_messages: int | None = None
    """Message count of the file's statistics record, when the summary was readable [-]."""
    compression: str | None = None
    """Compression of the first chunk read ('' for none)."""
    problems: list[str] = field(default_factory=list)
    """One line per problem met, in file order."""


class _Chunk(NamedTuple):
    compression: str
    uncompressed_size: int
    uncompressed_crc: int
    records: bytes
    """The compressed records (possibly fewer bytes than announced, for a chunk cut short)."""
    complete: bool


class McapScanner:
    """Scans one MCAP file; :meth:`blocks` yields its messages, :attr:`report` says how the scan went.

    ``schemas`` and ``channels`` hold every Schema and Channel record met so far (the summary's first, for a
    complete file); a block's channels are known by the time it is yielded.

    Raises:
        RecordingError: the file cannot be opened or does not start like an MCAP file (a file shorter than the
            magic that is a prefix of it, an empty file included, counts as cut short: no records, no error).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.report = ScanReport(self.path)
        self.schemas: dict[int, SchemaRecord] = {}
        self.channels: dict[int, ChannelRecord] = {}
        self._data_end: int | None = None  # where the summary (or the footer) starts, for a complete file

    # -- public --------------------------------------------------------------------------------------------------

    def blocks(self) -> Generator[MessageBlock, None, None]:
        """The messages of the file, one block per chunk (or run of unchunked messages), in file order."""
        try:
            stream = self.path.open('rb')
        except OSError as err:
            msg = f'cannot open {self.path}: {err.strerror or err}'
            raise RecordingError(msg) from err
        with stream:
            try:
                size = stream.seek(0, 2)
            except OSError as err:
                msg = f'cannot read {self.path}: {err.strerror or err}'
                raise RecordingError(msg) from err
            if size < len(MAGIC):
                stream.seek(0)
                if MAGIC.startswith(stream.read(size)):
                    self._problem(f'{size} bytes: cut short before the first record')
                    self.report.truncated = True
                    self.report.skipped_bytes = size
                    return
                msg = f'not an MCAP file: {self.path} (no MCAP magic)'
                raise RecordingError(msg)
            try:
                view = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
            except (OSError, ValueError) as err:
                msg = f'cannot read {self.path}: {err}'
                raise RecordingError(msg) from err
            with view:
                if view[: len(MAGIC)] != MAGIC:
                    msg = f'not an MCAP file: {self.path} (no MCAP magic)'
                    raise RecordingError(msg)
                self._read_summary(view, size)
                yield from self._walk(view, size)

    # -- top level -----------------------------------------------------------------------------------------------

    def _problem(self, text: str) -> None:
        self.report.problems.append(f'{self.path.name}: {text}')

    def _read_summary(self, mm: mmap.mmap, size: int) -> None:
        """For a file with a footer and end magic: the summary's schemas, channels and message count."""
        if size < len(MAGIC) * 2 + _FOOTER_SIZE or mm[size - len(MAGIC) :] != MAGIC:
            return
        footer = size - len(MAGIC) - _FOOTER_SIZE
        op, length = _OP_LEN(mm, footer)
        if op != OP_FOOTER or length != 20:
            return
        self.report.complete = True
        (summary_start,) = _U64(mm, footer + 9)
        self._data_end = summary_start or footer
        if not summary_start:
            return
        if not len(MAGIC) <= summary_start <= footer:
            self._problem('summary offset outside the file; summary not used')
            return
        pos = summary_start
        try:
            while pos < footer:
                op, length = _OP_LEN(mm, pos)
                end = pos + 9 + length
                if end > footer:
                    raise ValueError('summary record runs past the footer')
                body = mm[pos + 9 : end]
                if op == OP_SCHEMA:
                    schema = _schema(body)
                    self.schemas.setdefault(schema.id, schema)
                elif op == OP_CHANNEL:
                    channel = _channel(body)
                    self.channels.setdefault(channel.id, channel)
                elif op == OP_STATISTICS:
                    (self.report.expected_messages,) = _U64(body, 0)
                pos = end
        except (ValueError, struct.error, UnicodeDecodeError) as err:
            self._problem(f'summary section damaged ({err}); not used past that point')

    def _walk(self, mm: mmap.mmap, size: int) -> Iterator[MessageBlock]:
        pos = len(MAGIC)
        loose: list[int] = []  # offsets of messages outside chunks, waiting to become a block
        while pos < size:
            if pos + 9 > size:
                self._torn(pos, size, 'a record header')
                break
            op, length = _OP_LEN(mm, pos)
            end = pos + 9 + length
            if op not in _KNOWN_OPCODES or (op == OP_MESSAGE and length < _HEAD - 9):
                nxt = self._resync(mm, pos + 1, size)
                self._skip(pos, nxt if nxt is not None else size, f'unreadable record (opcode {op:#04x})')
                if nxt is None:
                    self.report.unknown_loss = True
                    break
                pos = nxt
                continue
            if end > size:
                nxt = self._resync(mm, pos + 1, size)
                if nxt is not None:  # a damaged length, not the end of the file
                    self._skip(pos, nxt, f'record (opcode {op:#04x}) with an impossible length')
                    self.report.unknown_loss = True
                    pos = nxt
                    continue
                if loose:
                    yield self._loose_block(mm, loose)
                    loose = []
                if op == OP_CHUNK:
                    block = self._torn_chunk(mm, pos, size)
                    if block is not None:
                        yield block
                else:
                    self._torn(pos, size, f'a record (opcode {op:#04x})')
                break
            if op != OP_CHUNK:
                # a record that is not a chunk does not hold one: if it seems to, its opcode or length is damaged
                nxt = self._resync(mm, pos + 1, end)
                if nxt is None and op in (OP_DATA_END, OP_FOOTER) and not self._ends_here(mm, op, pos, length, size):
                    nxt = self._resync(mm, pos + 1, size)  # an end marker where the file does not end
                    if nxt is None:
                        self._problem(f'{"data end" if op == OP_DATA_END else "footer"} record at byte {pos} out '
                                      'of place; nothing readable after it')
                        self.report.truncated = True
                        break
                if nxt is not None:
                    self._skip(pos, nxt, f'record (opcode {op:#04x}) spanning a chunk')
                    self.report.unknown_loss = True
                    if loose:
                        yield self._loose_block(mm, loose)
                        loose = []
                    pos = nxt
                    continue
            if op == OP_MESSAGE:
                loose.append(pos)
                pos = end
                continue
            if loose:
                yield self._loose_block(mm, loose)
                loose = []
            if op == OP_CHUNK:
                pos, block = self._chunk(mm, pos, end, size)
                if block is not None:
                    yield block
                continue
            if op == OP_HEADER:
                self._header(mm[pos + 9 : end])
            elif op in (OP_SCHEMA, OP_CHANNEL):
                self._define(op, mm[pos + 9 : end])
            elif op == OP_DATA_END:  # the data section is complete; the summary was read first (if intact)
                if not self.report.complete:
                    self.report.truncated = True
                    self._problem('cut short in the summary section (after every message)')
                return
            elif op == OP_FOOTER:
                return
            pos = end
        else:
            self.report.truncated = True
            self._problem('ends without a footer')
        if loose:
            yield self._loose_block(mm, loose)

    def _ends_here(self, mm: mmap.mmap, op: int, pos: int, length: int, size: int) -> bool:
        """True if a data-end or footer record at ``pos`` is where such a record belongs."""
        if op == OP_FOOTER:
            return length == 20 and pos + 9 + 20 + len(MAGIC) == size
        if length != 4:
            return False
        end = pos + 9 + 4
        if self._data_end is not None:
            return end == self._data_end
        # a file without a valid footer (its end was cut): the summary section follows a data end
        return end >= size or mm[end] in _SUMMARY_OPCODES

    def _torn(self, pos: int, size: int, what: str) -> None:
        self.report.truncated = True
        self.report.skipped_bytes += size - pos
        self._problem(f'cut short inside {what} at byte {pos} ({size - pos} bytes dropped)')

    def _skip(self, pos: int, nxt: int, what: str) -> None:
        self.report.skipped_bytes += nxt - pos
        self._problem(f'{what} at byte {pos}: skipped {nxt - pos} bytes to the next chunk')

    def _header(self, body: bytes) -> None:
        try:
            profile, at = _string(body, 0)
            library, _ = _string(body, at)
        except (ValueError, struct.error, UnicodeDecodeError) as err:
            self._problem(f'header record damaged ({err})')
            return
        if self.report.profile is None:
            self.report.profile, self.report.library = profile, library

    def _define(self, op: int, body: bytes) -> None:
        """Store a Schema or Channel record (a damaged one is reported and dropped)."""
        try:
            if op == OP_SCHEMA:
                schema = _schema(body)
                self.schemas[schema.id] = schema
            else:
                channel = _channel(body)
                self.channels[channel.id] = channel
        except (ValueError, struct.error, UnicodeDecodeError) as err:
            self._problem(f'{"schema" if op == OP_SCHEMA else "channel"} record damaged ({err})')

    @staticmethod
    def _resync(mm: mmap.mmap, start: int, size: int) -> int | None:
        """Offset of the next record after ``start`` that is plainly a chunk (None if there is none)."""
        pos = start
        while True:
            pos = mm.find(b'\x06', pos, size)
            if pos < 0:
                return None
            if _chunk_at(mm, pos, size):
                return pos
            pos += 1

    # -- chunks --------------------------------------------------------------------------------------------------

    def _chunk(self, mm: mmap.mmap, pos: int, end: int, size: int) -> tuple[int, MessageBlock | None]:
        """Read the chunk at ``pos`` and the message indexes after it; return (next offset, its messages)."""
        nxt, index = _message_indexes(mm, end, size)
        known = sum(int(x.shape[0]) for x in index.values())
        try:
            chunk = _parse_chunk(mm[pos + 9 : end], complete=True)
            records = _decompress(chunk)
        except ValueError as err:
            self._bad_chunk(pos, str(err), known)
            return nxt, None
        self.report.chunks += 1
        if self.report.compression is None:
            self.report.compression = chunk.compression
        return nxt, self._records(records, index, f'chunk at byte {pos}')

    def _bad_chunk(self, pos: int, why: str, known: int) -> None:
        self.report.bad_chunks += 1
        self.report.lost_messages += known
        if not known:
            self.report.unknown_loss = True
        lost = f'{known} messages lost' if known else 'its messages lost (no index: count unknown)'
        self._problem(f'chunk at byte {pos} damaged ({why}): skipped, {lost}')

    def _torn_chunk(self, mm: mmap.mmap, pos: int, size: int) -> MessageBlock | None:
        """The complete records of a chunk the file ends inside (when a prefix can be decoded)."""
        self.report.truncated = True
        self.report.unknown_loss = True
        try:
            chunk = _parse_chunk(mm[pos + 9 : size], complete=False)
            records = _decompress(chunk)
        except ValueError as err:
            self.report.skipped_bytes += size - pos
            self._problem(f'cut short inside the chunk at byte {pos} ({err}): its messages are lost')
            return None
        block = self._records(records, {}, f'cut-short chunk at byte {pos}', complete=False)
        kept = 0 if block is None else len(block)
        self._problem(f'cut short inside the chunk at byte {pos}: {kept} complete messages kept from it')
        return block

    def _records(
        self, buf: bytes, index: dict[int, NDArray[np.int64]], where: str, *, complete: bool = True
    ) -> MessageBlock | None:
        """The messages of a chunk's records; schemas and channels among them are stored."""
        offsets = None
        if index and complete:
            offsets = self._indexed(buf, _sorted_unique(np.concatenate(list(index.values()))))
        if offsets is None:
            offsets = self._walk_records(buf, 0, len(buf), where, complete=complete)
        if offsets.shape[0] == 0:
            return None
        return _block(buf, offsets)

    def _indexed(self, buf: bytes, offsets: NDArray[np.int64]) -> NDArray[np.int64] | None:
        """Message offsets from the chunk's indexes, checked; the records between them parsed. None: walk instead."""
        n = len(buf)
        if offsets.shape[0] == 0 or int(offsets[0]) < 0 or int(offsets[-1]) + _HEAD > n:
            return None
        u8 = np.frombuffer(buf, dtype=np.uint8)
        if not bool(np.all(u8[offsets] == OP_MESSAGE)):
            return None
        lengths = u8[offsets[:, None] + np.arange(1, 9)].view('<u8').reshape(-1).astype(np.int64)
        ends = offsets + 9 + lengths
        if bool(np.any(lengths < _HEAD - 9)) or int(ends[-1]) > n or bool(np.any(ends[:-1] > offsets[1:])):
            return None
        gap_starts = np.concatenate(([0], ends)).tolist()
        gap_ends = np.concatenate((offsets, [n])).tolist()
        try:
            for a, b in zip(gap_starts, gap_ends, strict=True):
                if a < b:
                    self._walk_records(buf, a, b, '', complete=True, messages_allowed=False)
        except _IndexMismatch:
            return None
        return offsets

    def _walk_records(
        self, buf: bytes, start: int, stop: int, where: str, *, complete: bool, messages_allowed: bool = True
    ) -> NDArray[np.int64]:
        """Offsets of the message records in ``buf[start:stop]`` (record by record); schemas/channels stored.

        With ``messages_allowed=False`` (the gaps between indexed messages) a message record or a record that does
        not end exactly at ``stop`` raises ``_IndexMismatch``.
        """
        out: list[int] = []
        pos = start
        while pos + 9 <= stop:
            op, length = _OP_LEN(buf, pos)
            end = pos + 9 + length
            if end > stop:
                break
            if op == OP_MESSAGE:
                if not messages_allowed:
                    raise _IndexMismatch
                if length < _HEAD - 9:
                    break
                out.append(pos)
            elif op in (OP_SCHEMA, OP_CHANNEL):
                self._define(op, buf[pos + 9 : end])
            elif op not in _KNOWN_OPCODES:
                break
            pos = end
        if pos != stop:
            if not messages_allowed:
                raise _IndexMismatch
            if complete:
                self._problem(f'{where}: records stop {stop - pos} bytes before the end of the chunk')
        return np.asarray(out, dtype=np.int64)

    def _loose_block(self, mm: mmap.mmap, offsets: list[int]) -> MessageBlock:
        """Messages outside chunks: their records copied into one buffer."""
        parts = []
        starts = []
        at = 0
        for pos in offsets:
            (length,) = _U64(mm, pos + 1)
            record = mm[pos : pos + 9 + length]
            parts.append(record)
            starts.append(at)
            at += len(record)
        return _block(b''.join(parts), np.asarray(starts, dtype=np.int64))


class _IndexMismatch(Exception):  # noqa: N818  # a control-flow signal inside the scanner, not an error
    """The message indexes of a chunk do not describe its records (walk the chunk instead)."""


#: Largest uncompressed chunk accepted [bytes]; a larger claim marks the chunk damaged (mcap writes ~1 MiB).
MAX_CHUNK_BYTES = 1 << 32
#: What decompressing a damaged chunk may raise (zstandard's ZstdError, lz4's RuntimeError, a size that overflows).
_DECOMPRESS_ERRORS: tuple[type[BaseException], ...] = (*LIBRARY_READ_ERRORS, OverflowError, MemoryError)


def _block(buf: bytes, offsets: NDArray[np.int64]) -> MessageBlock:
    u8 = np.frombuffer(buf, dtype=np.uint8)
    heads = np.ascontiguousarray(u8[offsets[:, None] + np.arange(_HEAD)]).view(MESSAGE_RECORD_HEAD).reshape(-1)
    lengths = heads['length'].astype(np.int64)
    return MessageBlock(
        buffer=buf,
        channel_id=heads['channel'].astype(np.int64),
        sequence=heads['sequence'].astype(np.int64),
        log_time=heads['log_time'].astype(np.int64),
        publish_time=heads['publish_time'].astype(np.int64),
        data_start=offsets + _HEAD,
        data_length=lengths - (_HEAD - 9),
    )


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = _U32(buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise ValueError('string runs past its record')
    return bytes(buf[pos + 4 : end]).decode('utf-8'), end


def _schema(body: bytes) -> SchemaRecord:
    (schema_id,) = _U16(body, 0)
    name, at = _string(body, 2)
    encoding, at = _string(body, at)
    (n,) = _U32(body, at)
    if at + 4 + n > len(body):
        raise ValueError('schema data runs past its record')
    return SchemaRecord(schema_id, name, encoding, bytes(body[at + 4 : at + 4 + n]))


def _channel(body: bytes) -> ChannelRecord:
    channel_id, schema_id = struct.unpack_from('<HH', body, 0)
    topic, at = _string(body, 4)
    encoding, at = _string(body, at)
    (n,) = _U32(body, at)
    at += 4
    stop = at + n
    if stop > len(body):
        raise ValueError('channel metadata runs past its record')
    metadata: dict[str, str] = {}
    while at < stop:
        key, at = _string(body, at)
        value, at = _string(body, at)
        metadata[key] = value
    return ChannelRecord(channel_id, schema_id, topic, encoding, metadata)


def _chunk_at(mm: mmap.mmap, pos: int, size: int) -> bool:
    """True if a chunk record starts at ``pos``: opcode, lengths and compression name agree with each other."""
    if pos + 9 + 40 > size or mm[pos] != OP_CHUNK:
        return False
    (length,) = _U64(mm, pos + 1)
    if length < 40 or pos + 9 + length > size:
        return False
    (name_len,) = _U32(mm, pos + 9 + 28)
    if name_len > 4:
        return False
    at = pos + 9 + 32
    name = mm[at : at + name_len]
    if name not in (b'', b'zstd', b'lz4'):
        return False
    (records,) = _U64(mm, at + name_len)
    return bool(28 + 4 + name_len + 8 + records == length)


def _parse_chunk(body: bytes, *, complete: bool) -> _Chunk:
    """The fields of a chunk record's body (``complete=False``: the body may end early)."""
    try:
        _, _, usize, crc = _CHUNK_HEAD(body, 0)
        name, at = _string(body, 28)
        (records_len,) = _U64(body, at)
    except (struct.error, UnicodeDecodeError) as err:
        msg = f'chunk header unreadable: {err}'
        raise ValueError(msg) from err
    if name not in _COMPRESSIONS:
        msg = f'unknown chunk compression {name!r}'
        raise ValueError(msg)
    if usize > MAX_CHUNK_BYTES:  # damaged: no writer makes such chunks, and decompressing would allocate it
        msg = f'chunk claims {usize} bytes uncompressed (more than {MAX_CHUNK_BYTES})'
        raise ValueError(msg)
    at += 8
    records = body[at : at + records_len]
    if complete and (len(records) != records_len or at + records_len != len(body)):
        msg = 'chunk lengths do not add up'
        raise ValueError(msg)
    return _Chunk(name, usize, crc, bytes(records), complete)


def _decompress(chunk: _Chunk) -> bytes:
    """A chunk's records, decompressed and checked (CRC, size); for a cut chunk, the prefix that decodes."""
    data = chunk.records
    try:
        if chunk.compression == 'zstd':
            import zstandard

            if chunk.complete:
                out = zstandard.ZstdDecompressor().decompress(data, max_output_size=chunk.uncompressed_size)
            else:
                out = zstandard.ZstdDecompressor().decompressobj().decompress(data)
        elif chunk.compression == 'lz4':
            import lz4.frame

            if chunk.complete:
                out = lz4.frame.decompress(data)
            else:
                out = lz4.frame.LZ4FrameDecompressor().decompress(data)
        else:
            out = data
    except _DECOMPRESS_ERRORS as err:
        msg = f'{chunk.compression} decompression failed: {str(err).strip() or type(err).__name__}'
        raise ValueError(msg) from err
    out = bytes(out)
    if chunk.complete:
        if len(out) != chunk.uncompressed_size:
            msg = f'decompressed to {len(out)} bytes, expected {chunk.uncompressed_size}'
            raise ValueError(msg)
        if chunk.uncompressed_crc and zlib.crc32(out) != chunk.uncompressed_crc:
            msg = 'CRC mismatch'
            raise ValueError(msg)
    return out


def _message_indexes(mm: mmap.mmap, pos: int, size: int) -> tuple[int, dict[int, NDArray[np.int64]]]:
    """The message index records at ``pos`` (after a chunk): (offset after them, channel id -> record offsets)."""
    out: dict[int, NDArray[np.int64]] = {}
    while pos + 9 <= size and mm[pos] == OP_MESSAGE_INDEX:
        (length,) = _U64(mm, pos + 1)
        end = pos + 9 + length
        if end > size or length < 6:
            break
        (channel_id,) = _U16(mm, pos + 9)
        (n,) = _U32(mm, pos + 11)
        if 6 + n != length or n % 16:
            break
        entries = np.frombuffer(mm[pos + 15 : end], dtype='<u8').reshape(-1, 2)
        out[channel_id] = entries[:, 1].astype(np.int64)
        pos = end
    return pos, out


def chunk_time_ranges(path: str | os.PathLike[str]) -> list[tuple[int, int]] | None:
    """``(message start time, message end time)`` [ns] of every chunk of an MCAP file, in file order.

    Reads only the records' headers (no decompression). None when the file is not a plain sequence of records up to
    its data end or footer -- messages outside chunks, an unknown or cut record -- (read such a file record by
    record, with :class:`McapScanner` or a library reader).
    """
    try:
        with Path(path).open('rb') as stream:
            size = stream.seek(0, 2)
            if size < len(MAGIC) + 9:
                return None
            with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                if mm[: len(MAGIC)] != MAGIC:
                    return None
                out: list[tuple[int, int]] = []
                pos = len(MAGIC)
                while pos + 9 <= size:
                    op, length = _OP_LEN(mm, pos)
                    end = pos + 9 + length
                    if end > size or op == OP_MESSAGE or op not in _KNOWN_OPCODES:
                        return None
                    if op == OP_CHUNK:
                        if length < 16:
                            return None
                        out.append(_TIMES(mm, pos + 9))
                    elif op in (OP_DATA_END, OP_FOOTER):
                        return out
                    pos = end
    except (OSError, ValueError):
        return None
    return None


_TIMES = struct.Struct('<QQ').unpack_from


def _sorted_unique(values: NDArray[np.int64]) -> NDArray[np.int64]:
    """``np.unique(values)`` for the message offsets of a chunk's indexes (one sorted run per channel): a stable
    sort merges the runs in about one pass, where ``np.unique`` hashes and sorts every value."""
    out = np.sort(values, kind='stable')
    if out.shape[0] > 1:
        keep = np.empty(out.shape[0], dtype=bool)
        keep[0] = True
        np.not_equal(out[1:], out[:-1], out=keep[1:])
        if not keep.all():
            out = out[keep]
    return out
