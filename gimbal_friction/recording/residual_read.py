"""Reading residual logs back: the residual rows (in bulk, or streamed in bounded memory) and any decoded message.

A residual log (docs/ros.md "Files") is a folder of MCAP files ``<prefix>_<n>.mcap`` written by
:class:`~.residual_log.ResidualLogWriter` (``residual_logger`` live, ``gimbal-friction replay`` offline); a single
``.mcap`` file is accepted too. Files are read in write order with the tolerant scanner of :mod:`.mcap_scan`: a file
cut short (killed writer, full disk) gives its complete chunks, a damaged chunk is skipped and counted and the
chunks after it are read.

``/gimbal/friction/residual_detail`` rows are decoded in bulk from their CDR bytes
(:func:`~.cdr.float64_multi_array_rows`: the Float64MultiArray layout is fixed per joint label), into the row type
of :mod:`gimbal_friction.streams.residual_row` (12 columns; the 11-column layout 1 is read too). What a read went
through is a :class:`ReadReport`.

Times: ``log_time_ns`` is the log time [ns]; row fields carry their units in their names (SI, temperature in °C).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError, get_types_from_msg, get_typestore

from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.recording.cdr import DEFAULT_STORE, float64_multi_array_rows
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.mcap_scan import McapScanner, MessageBlock
from gimbal_friction.recording.topics import (
    FLOAT64_MULTI_ARRAY_TYPE,
    MESSAGE_ENCODING,
    RESIDUAL,
    RESIDUAL_DETAIL,
    SCHEMA_ENCODING,
    TEMPERATURE,
)
from gimbal_friction.streams.inputs import effective_time
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS_V1, ResidualRows, rows_from_detail

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    from numpy.typing import NDArray
    from rosbags.typesys.store import Typestore

__all__ = [
    'RESIDUAL_LOG_TOPICS',
    'LogMessage',
    'ReadReport',
    'file_write_order',
    'iter_residual_log',
    'iter_residual_rows',
    'read_residual_rows',
    'read_temperature_stream',
    'residual_log_files',
]

#: a folder (or file) is a residual log if it holds at least one of these topics
RESIDUAL_LOG_TOPICS = (RESIDUAL, RESIDUAL_DETAIL)
_FILE_INDEX = re.compile(r'^(?P<stem>.*?)(?:_(?P<index>\d+))?$')
_WIDTHS = (12, len(RESIDUAL_FIELDS_V1))


# ----------------------------------------------------------------------------------------------------------------
# records


@dataclass
class ReadReport:
    """What a read of residual logs went through (filled while reading)."""

    files: list[Path] = field(default_factory=list)
    """Files read, in order."""
    truncated_files: list[Path] = field(default_factory=list)
    """Files without a valid end (killed writer, full disk); their complete chunks were read."""
    topic_counts: dict[str, int] = field(default_factory=dict)
    """Messages per topic over all files [-]."""
    rows: int = 0
    """Residual rows read [-]."""
    bad_chunks: int = 0
    """Damaged chunks skipped (the chunks after them were read) [-]."""
    lost_messages: int = 0
    """Messages known to be lost in skipped chunks [-]."""
    unknown_loss: bool = False
    """Some damage held an unknown number of messages (a chunk cut short or damaged without an index)."""
    skipped_rows: int = 0
    """``residual_detail`` messages that are not residual rows (another width, undecodable) [-]."""
    problems: list[str] = field(default_factory=list)
    """One line per problem met."""

    def summary(self) -> str:
        """One line: what was read (files, rows) and what was not (files cut short, damaged chunks, messages
        that are not rows), so that a reader knows which rows any result rests on.

        >>> r = ReadReport(files=[Path('a.mcap')], truncated_files=[Path('a.mcap')], rows=14870)
        >>> print(r.summary())
        14870 residual rows read from 1 file; not read: the end of 1 file cut short, after its last complete
        chunk (a.mcap)
        """
        parts = [f'{self.rows} residual rows read from {len(self.files)} file{"s" if len(self.files) != 1 else ""}']
        lost = self.not_read()
        return '; '.join(parts) + (f'; not read: {lost}' if lost else '')

    def not_read(self) -> str:
        """What the read could not use, in words ('' when nothing)."""
        parts = []
        if self.truncated_files:
            n = len(self.truncated_files)
            parts.append(f'the end of {n} file{"s" if n != 1 else ""} cut short, after {"their" if n != 1 else "its"} '
                         f'last complete chunk ({", ".join(p.name for p in self.truncated_files)})')
        if self.bad_chunks:
            parts.append(f'{self.bad_chunks} damaged chunks skipped ({self.lost_messages} messages lost'
                         f'{" and more" if self.unknown_loss else ""})')
        if self.skipped_rows:
            parts.append(f'{self.skipped_rows} residual_detail messages that are not rows skipped')
        return '; '.join(parts)

    @property
    def skipped(self) -> bool:
        """Some data were not read: a file cut short, a damaged chunk, or residual_detail messages that are not
        rows (every command that reads logs says so, with :meth:`summary`)."""
        return bool(self.truncated_files or self.bad_chunks or self.unknown_loss or self.skipped_rows)

    def as_dict(self) -> dict[str, Any]:
        """What was read and what was skipped, JSON-ready (the ``read`` record of refit, report and fleet)."""
        return {'files': len(self.files), 'rows': self.rows,
                'truncated_files': [str(p) for p in self.truncated_files], 'damaged_chunks': self.bad_chunks,
                'lost_messages': self.lost_messages, 'unknown_loss': self.unknown_loss,
                'skipped_messages': self.skipped_rows, 'skipped': self.skipped, 'summary': self.summary()}


class LogMessage(NamedTuple):
    """One decoded message of a residual log."""

    topic: str
    msgtype: str
    log_time_ns: int
    """Log time [ns]."""
    msg: object
    """rosbags message dataclass."""


# ----------------------------------------------------------------------------------------------------------------
# files


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
        msg = f'not a residual log: {where} ({err.strerror or err})'
        raise RecordingError(msg) from err
    if not files:
        inner = _inner_log(where)
        hint = f'; it holds the residual log {inner}: give that folder' if inner is not None else ''
        msg = f'not a residual log: {where} (no .mcap files{hint})'
        raise RecordingError(msg)
    return sorted(files, key=file_write_order)


def _inner_log(where: Path) -> Path | None:
    """The residual-log folder inside a ``replay`` / ``residual_logger`` output folder (``residuals/``, or the one
    subfolder holding .mcap files), or None."""
    try:
        subs = sorted(p for p in where.iterdir() if p.is_dir())
        found = [p for p in subs if any(f.suffix == '.mcap' and f.is_file() for f in p.iterdir())]
    except OSError:
        return None
    named = [p for p in found if p.name == 'residuals']
    return named[0] if named else (found[0] if len(found) == 1 else None)


def file_write_order(p: Path) -> tuple[str, int, str]:
    """Sort key of log files: ``name_2`` before ``name_10`` (rotation index as a number)."""
    match = _FILE_INDEX.match(p.stem)
    if match is None:  # pragma: no cover - the pattern matches every string
        return (p.stem, -1, p.name)
    index = match.group('index')
    return (match.group('stem'), -1 if index is None else int(index), p.name)


def _as_paths(folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[Path]:
    if isinstance(folders, (str, os.PathLike)):
        return [Path(folders)]
    paths = [Path(x) for x in folders]
    if not paths:
        msg = 'not a residual log: no folder given'
        raise RecordingError(msg)
    return paths


# ----------------------------------------------------------------------------------------------------------------
# scanning


class _Decoder:
    """Deserializes CDR with a private type store, registering types a file defines that the store lacks."""

    def __init__(self) -> None:
        self.store: Typestore = get_typestore(DEFAULT_STORE)

    def ensure(self, scan: McapScanner, schema_id: int, msgtype: str) -> None:
        if msgtype in self.store.types:
            return
        schema = scan.schemas.get(schema_id)
        if schema is None or schema.encoding != SCHEMA_ENCODING:
            msg = f'{scan.path}: message type {msgtype!r} is unknown and the file has no ros2msg schema for it'
            raise RecordingError(msg)
        try:
            self.store.register(get_types_from_msg(schema.data.decode('utf-8'), msgtype))
        except (TypesysError, UnicodeDecodeError) as err:
            msg = f'{scan.path}: cannot parse the schema of {msgtype!r}: {err}'
            raise RecordingError(msg) from err

    def decode(self, data: bytes, msgtype: str) -> object:
        return self.store.deserialize_cdr(data, msgtype)


_DECODE_ERRORS = (SerdeError, TypesysError, KeyError, ValueError, IndexError, AssertionError)


class _Topics:
    """Channel id -> (topic, msgtype) of one file, with the contract's checks on the residual topics."""

    def __init__(self, scan: McapScanner) -> None:
        self.scan = scan
        self.known: dict[int, tuple[str, str]] = {}

    def of(self, channel_id: int) -> tuple[str, str] | None:
        hit = self.known.get(channel_id)
        if hit is not None:
            return hit
        channel = self.scan.channels.get(channel_id)
        if channel is None:
            return None
        schema = self.scan.schemas.get(channel.schema_id)
        msgtype = schema.name if schema is not None else ''
        if channel.topic == RESIDUAL_DETAIL:
            if channel.message_encoding != MESSAGE_ENCODING:
                msg = (f'{self.scan.path}: topic {channel.topic} has message encoding '
                       f'{channel.message_encoding!r}, not cdr')
                raise RecordingError(msg)
            if msgtype != FLOAT64_MULTI_ARRAY_TYPE:
                msg = f'{self.scan.path}: {RESIDUAL_DETAIL} has type {msgtype}, expected {FLOAT64_MULTI_ARRAY_TYPE}'
                raise RecordingError(msg)
        self.known[channel_id] = (channel.topic, msgtype)
        return self.known[channel_id]


def _scan_folders(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]], report: ReadReport
) -> Iterator[tuple[McapScanner, _Topics, MessageBlock]]:
    """Every message block of every file of ``folders``, with its file's channels; fills ``report``."""
    for folder in _as_paths(folders):
        seen: set[str] = set()
        for path in residual_log_files(folder):
            scan = McapScanner(path)
            topics = _Topics(scan)
            report.files.append(path)
            for block in scan.blocks():
                ids, counts = np.unique(block.channel_id, return_counts=True)
                for channel_id, n in zip(ids.tolist(), counts.tolist(), strict=True):
                    hit = topics.of(channel_id)
                    name = hit[0] if hit is not None else f'(channel {channel_id}, definition lost)'
                    report.topic_counts[name] = report.topic_counts.get(name, 0) + n
                yield scan, topics, block
            seen.update(c.topic for c in scan.channels.values())
            r = scan.report
            if r.truncated:
                report.truncated_files.append(path)
            report.bad_chunks += r.bad_chunks
            report.lost_messages += r.lost_messages
            report.unknown_loss = report.unknown_loss or r.unknown_loss
            report.problems.extend(r.problems)
        if not seen.intersection(RESIDUAL_LOG_TOPICS):
            have = ', '.join(sorted(seen)) or 'no topics'
            need = ' or '.join(RESIDUAL_LOG_TOPICS)
            msg = f'not a residual log: {folder} (holds {have}; expected {need})'
            raise RecordingError(msg)


class _Piece(NamedTuple):
    """``residual_detail`` messages of one block and one layout: their place in the block, label and values."""

    position: NDArray[np.intp]
    log_time_ns: NDArray[np.int64]
    label: str
    values: NDArray[np.float64]


def _detail_pieces(
    scan: McapScanner, topics: _Topics, block: MessageBlock, decoder: _Decoder, report: ReadReport
) -> list[_Piece]:
    """The ``residual_detail`` messages of a block, decoded in bulk (one piece per layout met)."""
    detail_ids = [c for c in np.unique(block.channel_id).tolist() if (topics.of(c) or ('',))[0] == RESIDUAL_DETAIL]
    if not detail_ids:
        return []
    where = np.flatnonzero(np.isin(block.channel_id, detail_ids))
    rows = float64_multi_array_rows(block.buffer, block.data_start[where], block.data_length[where])
    pieces = [_Piece(where[idx], block.log_time[where[idx]], label, values) for idx, label, values in rows.blocks]
    for k in rows.others.tolist():  # not plain little-endian CDR: the type store
        m = int(where[k])
        try:
            msg = decoder.decode(block.data(m), FLOAT64_MULTI_ARRAY_TYPE)
            values = np.asarray(msg.data, dtype=np.float64).reshape(1, -1)  # type: ignore[attr-defined]  # the type store decodes to an untyped message object
            dims = msg.layout.dim  # type: ignore[attr-defined]  # the type store decodes to an untyped message object
            label = str(dims[0].label) if len(dims) else ''
        except _DECODE_ERRORS:
            report.skipped_rows += 1
            continue
        pieces.append(_Piece(np.array([m], dtype=np.intp), block.log_time[[m]], label, values))
    return pieces


def _rows_of(pieces: list[_Piece], report: ReadReport) -> tuple[ResidualRows, NDArray[np.int64]] | None:
    """The pieces as rows in message order, with their log times [ns] (None: no row)."""
    parts: list[ResidualRows] = []
    positions: list[NDArray[np.intp]] = []
    logs: list[NDArray[np.int64]] = []
    for piece in pieces:
        if piece.values.shape[1] not in _WIDTHS:
            report.skipped_rows += piece.values.shape[0]
            continue
        parts.append(rows_from_detail(np.full(piece.values.shape[0], piece.label), piece.values))
        positions.append(piece.position)
        logs.append(piece.log_time_ns)
    if not parts:
        return None
    rows = ResidualRows.concatenate(parts)
    order = np.argsort(np.concatenate(positions), kind='stable')
    return rows.select(order), np.concatenate(logs)[order]


# ----------------------------------------------------------------------------------------------------------------
# the residual rows


def iter_residual_rows(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    chunk_rows: int = 100_000,
    *,
    report: ReadReport | None = None,
) -> Iterator[ResidualRows]:
    """The residual rows of one or more residual logs, ``chunk_rows`` at a time, in file order, in bounded memory.

    Memory holds about one MCAP chunk and ``chunk_rows`` rows at a time, whatever the size of the logs (used for
    fleets of 22 M-message logs). Every part has ``chunk_rows`` rows except the last (none for logs without rows).

    Args:
        paths: residual-log folder(s) or ``.mcap`` file(s).
        chunk_rows: rows per part [-] (> 0).
        report: filled while reading (files, cut-short files, topic counts, damaged chunks skipped).

    Raises:
        RecordingError: a path holds no MCAP file or none of :data:`RESIDUAL_LOG_TOPICS` (raised after that
            folder's rows), a file is not MCAP, or ``residual_detail`` is not a Float64MultiArray.
    """
    if chunk_rows <= 0:
        msg = f'chunk_rows = {chunk_rows}: must be positive'
        raise RecordingError(msg)
    report = report if report is not None else ReadReport()
    decoder = _Decoder()
    pending: list[ResidualRows] = []
    held = 0
    for scan, topics, block in _scan_folders(paths, report):
        got = _rows_of(_detail_pieces(scan, topics, block, decoder, report), report)
        if got is None:
            continue
        rows = got[0]
        report.rows += len(rows)
        pending.append(rows)
        held += len(rows)
        while held >= chunk_rows:
            whole = ResidualRows.concatenate(pending)
            yield whole.select(np.arange(chunk_rows))
            rest = whole.select(np.arange(chunk_rows, held))
            pending = [rest] if len(rest) else []
            held = len(rest)
    if held:
        yield ResidualRows.concatenate(pending)


def read_residual_rows(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
) -> tuple[ResidualRows, ReadReport]:
    """Every residual row of one or more residual logs, in file order, and what the read went through.

    Files cut short contribute their complete chunks (listed in ``report.truncated_files``); damaged chunks are
    skipped and counted (``report.bad_chunks``), later chunks are read.

    Raises:
        RecordingError: see :func:`iter_residual_rows`.
    """
    report = ReadReport()
    parts = list(iter_residual_rows(paths, chunk_rows=1 << 62, report=report))
    return ResidualRows.concatenate(parts), report


# ----------------------------------------------------------------------------------------------------------------
# any message


def read_temperature_stream(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The bearing temperatures the logger logged as inputs: times [s] (stamp, or log time where the stamp is zero:
    the suite's one time rule) and values [°C], sorted by time; empty arrays if the inputs were not logged."""
    times: list[float] = []
    values: list[float] = []
    for item in iter_residual_log(folders, [TEMPERATURE]):
        msg: Any = item.msg
        ns = int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)
        times.append(effective_time(ns, item.log_time_ns) / NS_PER_S)
        values.append(float(msg.temperature))
    order = np.argsort(np.asarray(times, dtype=np.float64), kind='stable')
    return np.asarray(times, dtype=np.float64)[order], np.asarray(values, dtype=np.float64)[order]


def iter_residual_log(
    folders: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    topics: Iterable[str] | None = None,
    *,
    report: ReadReport | None = None,
) -> Iterator[LogMessage]:
    """Decoded messages of one or more residual-log folders (or single ``.mcap`` files), in file order.

    Files are read in write order (``residuals_0``, ``residuals_1``, ...); a file cut short yields the messages of
    its complete chunks, a damaged chunk is skipped. The check that a folder holds a residual topic is made once
    its files are read, so the error comes after that folder's messages.

    Args:
        folders: folder(s) or file(s).
        topics: only these topics (default: all).
        report: filled while reading.

    Raises:
        RecordingError: no MCAP files, none of :data:`RESIDUAL_LOG_TOPICS`, unreadable or undecodable data.
    """
    wanted = None if topics is None else ({topics} if isinstance(topics, str) else set(topics))
    decoder = _Decoder()
    report = report if report is not None else ReadReport()
    for scan, names, block in _scan_folders(folders, report):
        for k in range(len(block)):
            channel_id = int(block.channel_id[k])
            hit = names.of(channel_id)
            if hit is None:
                continue
            topic, msgtype = hit
            if wanted is not None and topic not in wanted:
                continue
            channel = scan.channels[channel_id]
            if channel.message_encoding != MESSAGE_ENCODING:
                msg = f'{scan.path}: topic {topic} has message encoding {channel.message_encoding!r}, not cdr'
                raise RecordingError(msg)
            decoder.ensure(scan, channel.schema_id, msgtype)
            log_time = int(block.log_time[k])
            try:
                message = decoder.decode(block.data(k), msgtype)
            except _DECODE_ERRORS as err:
                msg = f'{scan.path}: cannot decode {topic} message at log time {log_time} ns: {err!r}'
                raise RecordingError(msg) from err
            yield LogMessage(topic, msgtype, log_time, message)


# ----------------------------------------------------------------------------------------------------------------
# layout 1 arrays (deprecated: for callers not yet switched to read_residual_rows)


