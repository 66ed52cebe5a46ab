"""Recovery of bags and residual logs that are cut short or damaged: every readable record, in a readable file.
One job in one module: recovery (MCAP, sqlite3 and folders share the outcome records and the staging rule).

``gimbal-friction recover IN --out OUT`` (docs/cli.md): IN is a bag folder, a bag file (``.mcap`` or ``.db3``) or a
residual-log folder or file; OUT is created, of the same kind, readable by the standard readers (rosbags
``AnyReader``, ``mcap`` ``make_reader``, and for a folder a rosbag2 ``metadata.yaml``). Nothing is overwritten: OUT
must not exist, and it appears only when complete (written under a temporary name, then renamed).

- MCAP (:func:`recover_mcap`): the file is read with the tolerant scanner of :mod:`.mcap_scan` (chunked or not,
  zstd, lz4 or no compression; cut short mid-chunk, a torn record, corrupted bytes inside a chunk with good chunks
  after it) and every message it yields is written again, with its channel, schema, log and publish time and
  sequence number, into a complete MCAP file (ROS 2 profile kept).
- sqlite3 (:func:`recover_db3`): the tables are copied row by row with Python's ``sqlite3``; a range of rows that
  cannot be read (a page cut off or corrupted) is skipped and the rows after it are read. A database whose schema
  cannot be read gives a clean error.

Each file's outcome is a :class:`FileRecovery` (messages kept, known lost, whether more may be lost); a folder's is
a :class:`Recovery`.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple
from urllib.parse import quote

import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from gimbal_friction.common.files import staged
from gimbal_friction.recording.bag import foreign_serialization, unsupported_serialization
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.mcap_scan import McapScanner, MessageBlock
from gimbal_friction.recording.residual_read import file_write_order
from gimbal_friction.recording.topics import MCAP_PROFILE

if TYPE_CHECKING:
    from collections.abc import Callable, Generator, Iterator

__all__ = [
    'FileRecovery',
    'Recovery',
    'RecoveryResult',
    'TopicStats',
    'recover',
    'recover_db3',
    'recover_mcap',
]

LIBRARY = 'gimbal_friction recover (mcap-python)'
#: chunk size of recovered MCAP files [B]
CHUNK_SIZE = 1 << 20
_COMPRESSION = {'': CompressionType.NONE, 'none': CompressionType.NONE, 'lz4': CompressionType.LZ4,
                'zstd': CompressionType.ZSTD}
_STORAGES = {'.mcap': 'mcap', '.db3': 'sqlite3'}
_ROWS_PER_FETCH = 10_000


class TopicStats(NamedTuple):
    """One topic of a recovered file, for the folder's metadata.yaml."""

    msgtype: str
    serialization_format: str
    offered_qos_profiles: object
    """As rosbag2 writes it (a YAML list, or the string of one)."""
    type_description_hash: str
    messages: int
    start_ns: int
    end_ns: int


class FileRecovery(NamedTuple):
    """What recovering one file kept and lost."""

    messages: int
    """Messages kept [-]."""
    truncated: bool
    """The source was cut short (no valid end)."""
    lost: int = 0
    """Messages known to be lost [-]."""
    unknown_loss: bool = False
    """More may be lost than ``lost`` (damage whose message count is unknown)."""
    damaged: int = 0
    """Damaged chunks (MCAP) or unreadable row ranges (sqlite3) skipped [-]."""
    problems: tuple[str, ...] = ()
    """One line per problem met."""
    source: Path | None = None
    target: Path | None = None
    storage: str = 'mcap'
    """``'mcap'`` or ``'sqlite3'``."""
    topics: dict[str, TopicStats] | None = None
    """Per topic of the recovered file (for metadata.yaml)."""

    def lost_text(self) -> str:
        """``'12'``, ``'12 + an unknown number'`` or ``'an unknown number'``."""
        if self.unknown_loss:
            return f'{self.lost} + an unknown number' if self.lost else 'an unknown number'
        return str(self.lost)


#: the result type of :func:`recover_mcap` (old name)
RecoveryResult = FileRecovery


class Recovery(NamedTuple):
    """What :func:`recover` did: the output, and per source file what was kept and lost."""

    source: Path
    target: Path
    kind: str
    """``'folder'`` or ``'file'``."""
    files: tuple[FileRecovery, ...]
    skipped: tuple[str, ...] = ()
    """Files of the source folder that could not be read at all (one line each)."""

    @property
    def messages(self) -> int:
        """Messages kept [-]."""
        return sum(f.messages for f in self.files)

    @property
    def lost(self) -> int:
        """Messages known to be lost [-]."""
        return sum(f.lost for f in self.files)

    @property
    def unknown_loss(self) -> bool:
        """More may be lost than :attr:`lost`."""
        return any(f.unknown_loss for f in self.files) or bool(self.skipped)

    def lost_text(self) -> str:
        """The loss in words (see :meth:`FileRecovery.lost_text`)."""
        return FileRecovery(0, False, self.lost, self.unknown_loss).lost_text()


# ----------------------------------------------------------------------------------------------------------------
# MCAP


def recover_mcap(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    chunk_size: int = CHUNK_SIZE,
    compression: str | None = None,
) -> FileRecovery:
    """Rewrite an MCAP file, complete, cut short or damaged, into a complete one holding every readable message.

    Schemas, channels (with metadata), log/publish times and sequence numbers are kept; the profile comes from the
    source header. Messages whose channel (or schema) definition was lost with a damaged chunk cannot be written
    and are counted as lost.

    Args:
        src: MCAP file to read.
        dst: file to create; must not exist.
        chunk_size: chunk size of the new file [B].
        compression: ``'zstd'``, ``'lz4'`` or ``'none'``; default: that of the source's first chunk (zstd if none
            was read).

    Raises:
        RecordingError: ``dst`` exists, ``src`` is not MCAP or cannot be read, or writing fails.
    """
    source, target = Path(src), Path(dst)
    if compression is not None and compression not in _COMPRESSION:
        msg = f'compression {compression!r}: expected one of zstd, lz4, none'
        raise RecordingError(msg)
    _check_target(target)
    if not source.is_file():
        msg = f'recover: {source} is not a file'
        raise RecordingError(msg)
    scan = McapScanner(source)
    blocks = scan.blocks()
    try:
        return _copy_mcap(scan, blocks, source, target, chunk_size, compression)
    finally:
        blocks.close()


def _copy_mcap(
    scan: McapScanner, blocks: Generator[MessageBlock, None, None], source: Path, target: Path, chunk_size: int,
    compression: str | None,
) -> FileRecovery:
    first = next(blocks, None)  # reads the header (and the summary of a complete file)
    if first is None and scan.report.profile is None:
        msg = f'recover: {source} holds no MCAP record (empty, or cut before its header): nothing to recover'
        raise RecordingError(msg)
    chosen = compression if compression is not None else (scan.report.compression or 'zstd')
    kept = 0
    orphans = 0
    topics: dict[str, dict[str, Any]] = {}
    with _temporary(target) as tmp:
        try:
            with tmp.open('xb') as stream:
                writer = McapWriter(stream, chunk_size=chunk_size, compression=_COMPRESSION[chosen])
                report = scan.report
                library = f'{LIBRARY}' + (f' from {report.library}' if report.library else '')
                writer.start(profile=report.profile if report.profile is not None else MCAP_PROFILE,
                             library=library)
                schema_ids: dict[int, int] = {}
                channel_ids: dict[int, int | None] = {}

                def out_channel(channel_id: int) -> int | None:
                    if channel_id in channel_ids:
                        return channel_ids[channel_id]
                    channel = scan.channels.get(channel_id)
                    if channel is None:
                        return None  # definition lost: try again when a later chunk defines it
                    schema_id = 0
                    if channel.schema_id:
                        schema = scan.schemas.get(channel.schema_id)
                        if schema is None:
                            return None
                        if schema.id not in schema_ids:
                            schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                        schema_id = schema_ids[schema.id]
                    channel_ids[channel_id] = writer.register_channel(
                        channel.topic, channel.message_encoding, schema_id, channel.metadata)
                    schema = scan.schemas.get(channel.schema_id)
                    topics.setdefault(channel.topic, {
                        'msgtype': schema.name if schema is not None else '',
                        'encoding': channel.message_encoding,
                        'qos': channel.metadata.get('offered_qos_profiles', ''),
                        'hash': channel.metadata.get('topic_type_hash', ''),
                        'count': 0, 'start': None, 'end': None,
                    })
                    return channel_ids[channel_id]

                block = first
                while block is not None:
                    ids = block.channel_id.tolist()
                    logs = block.log_time.tolist()
                    pubs = block.publish_time.tolist()
                    seqs = block.sequence.tolist()
                    for k, channel_id in enumerate(ids):
                        out = out_channel(channel_id)
                        if out is None:
                            orphans += 1
                            continue
                        writer.add_message(out, logs[k], block.data(k), pubs[k], seqs[k])
                        stat = topics[scan.channels[channel_id].topic]
                        stat['count'] += 1
                        stat['start'] = logs[k] if stat['start'] is None else min(stat['start'], logs[k])
                        stat['end'] = logs[k] if stat['end'] is None else max(stat['end'], logs[k])
                        kept += 1
                    block = next(blocks, None)
                for channel_id in sorted(scan.channels):   # channels that held no message: kept, with 0
                    out_channel(channel_id)
                writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish is unannotated
                stream.flush()
                os.fsync(stream.fileno())
        except OSError as err:
            msg = f'recover: writing {target}: {err.strerror or err}'
            raise RecordingError(msg) from err
    report = scan.report
    problems = list(report.problems)
    if orphans:
        problems.append(f'{source.name}: {orphans} messages on channels whose definition was lost: dropped')
    lost = report.lost_messages + orphans
    unknown = report.unknown_loss
    if report.expected_messages is not None and not unknown:  # a complete file's statistics tell the loss exactly
        lost = max(lost, report.expected_messages - kept)
    return FileRecovery(
        messages=kept, truncated=report.truncated, lost=lost, unknown_loss=unknown, damaged=report.bad_chunks,
        problems=tuple(problems), source=source, target=target, storage='mcap',
        topics={name: TopicStats(t['msgtype'], t['encoding'], _qos(t['qos']), t['hash'], t['count'],
                                 t['start'] or 0, t['end'] or 0)
                for name, t in topics.items()},
    )


def _qos(text: object) -> list[Any]:
    """``offered_qos_profiles`` (a channel's or a topic row's string, or a list already) as a list of profiles,
    [] if unreadable."""
    if isinstance(text, list):
        return text
    if not isinstance(text, str) or not text:
        return []
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return []
    return value if isinstance(value, list) else []


#: the metadata.yaml version this writes when the source has none, the newest rosbag2 reads (Kilted: 9)
METADATA_VERSION = 9
#: rmw's QoS policies by name (version >= 9 writes names; earlier versions their numbers): rmw/types.h
_POLICY_NUMBERS = {
    'history': {'system_default': 0, 'keep_last': 1, 'keep_all': 2, 'unknown': 3},
    'reliability': {'system_default': 0, 'reliable': 1, 'best_effort': 2, 'unknown': 3, 'best_available': 4},
    'durability': {'system_default': 0, 'transient_local': 1, 'volatile': 2, 'unknown': 3, 'best_available': 4},
    'liveliness': {'system_default': 0, 'automatic': 1, 'manual_by_topic': 3, 'unknown': 4, 'best_available': 5},
}


def qos_for_version(profiles: object, version: int) -> object:
    r"""``offered_qos_profiles`` in the form metadata.yaml of ``version`` needs (rosbag2_storage's yaml.hpp): a YAML
    sequence of profiles from version 9 on, before it one string holding that sequence as YAML with the policies as
    numbers (rosbag2's decoder of version 9 reads numbers or names; before 9, numbers only); a string for a version
    before 9 is kept as it is.

    >>> qos_for_version('- history: 3\n  depth: 0', 9)
    [{'history': 3, 'depth': 0}]
    >>> qos_for_version([{'history': 'keep_last', 'depth': 5, 'reliability': 'reliable'}], 8)
    '- history: 1\n  depth: 5\n  reliability: 1\n'
    """
    items = _qos(profiles)
    if version >= 9:
        return items
    if isinstance(profiles, str) and items:   # already a string of that form: kept as written
        return profiles
    numbered = [{k: (_POLICY_NUMBERS[k].get(v, _POLICY_NUMBERS[k]['unknown']) if k in _POLICY_NUMBERS
                     and isinstance(v, str) else v) for k, v in p.items()} if isinstance(p, dict) else p
                for p in items]
    text: str = yaml.safe_dump(numbered, sort_keys=False, default_flow_style=False) if numbered else ''
    return text


# ----------------------------------------------------------------------------------------------------------------
# sqlite3


def recover_db3(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> FileRecovery:
    """Copy a rosbag2 sqlite3 database, cut short or damaged, keeping every row that can be read.

    The source is opened read-only (a ``-wal`` file next to it is replayed on a private copy). Tables and indexes
    are created from the source's schema; each table is copied in rowid order, and a range of rows that cannot be
    read is skipped (the rows after it are read): rosbag2 numbers messages without gaps, so the rows skipped are
    counted as lost.

    Raises:
        RecordingError: ``dst`` exists, the source is not a rosbag2 sqlite3 database, or its schema cannot be read.
    """
    source, target = Path(src), Path(dst)
    _check_target(target)
    if not source.is_file():
        msg = f'recover: {source} is not a file'
        raise RecordingError(msg)
    with contextlib.ExitStack() as stack:
        con = _open_readonly(source, stack)
        try:
            schema = con.execute('SELECT type, name, sql FROM sqlite_master WHERE sql IS NOT NULL').fetchall()
        except sqlite3.Error as err:
            msg = f'recover: {source}: cannot read the database schema ({err}): nothing can be recovered'
            raise RecordingError(msg) from err
        tables = [(name, sql) for kind, name, sql in schema if kind == 'table' and not name.startswith('sqlite_')]
        indexes = [sql for kind, name, sql in schema if kind == 'index' and not name.startswith('sqlite_')]
        names = {name for name, _ in tables}
        if not {'messages', 'topics'} <= names:
            msg = f'recover: {source} is not a rosbag2 sqlite3 bag (tables: {", ".join(sorted(names)) or "none"})'
            raise RecordingError(msg)
        problems: list[str] = []
        lost = 0
        unknown = False
        damaged = 0
        copied: dict[str, int] = {}
        with _temporary(target) as tmp:
            out = sqlite3.connect(tmp)
            try:
                for _, sql in tables:
                    out.execute(sql)
                for table, _ in tables:
                    salvage = _Salvage(con, table)
                    rows = 0
                    invalid = 0
                    for batch in salvage.batches():
                        marks = ','.join('?' * len(batch[0]))
                        before = out.total_changes
                        # rows read from damaged pages may break the table's constraints (NULLs, duplicates)
                        out.executemany(f'INSERT OR IGNORE INTO "{table}" VALUES ({marks})', batch)
                        done = out.total_changes - before
                        rows += done
                        invalid += len(batch) - done
                    copied[table] = rows
                    invalid += salvage.invalid
                    damaged += salvage.gaps
                    described = salvage.describe()
                    if invalid:
                        described = ', '.join(x for x in (described, f'{invalid} invalid rows dropped') if x)
                    if described:
                        problems.append(f'{source.name}: table {table}: {described}')
                    if table == 'messages':
                        lost += salvage.lost  # rowids skipped (invalid cells are those rows, damaged)
                        unknown = unknown or salvage.tail_lost
                for sql in indexes:
                    out.execute(sql)
                out.commit()
                topics = _db3_topics(out)
            except sqlite3.Error as err:
                msg = f'recover: writing {target}: {err}'
                raise RecordingError(msg) from err
            finally:
                out.close()
    return FileRecovery(
        messages=copied.get('messages', 0), truncated=bool(damaged) or unknown, lost=lost, unknown_loss=unknown,
        damaged=damaged, problems=tuple(problems), source=source, target=target, storage='sqlite3', topics=topics,
    )


def _open_readonly(source: Path, stack: contextlib.ExitStack) -> sqlite3.Connection:
    """The source database, read only; with a ``-wal`` file, a private copy of both (so the WAL is replayed)."""
    wal = source.with_name(source.name + '-wal')
    try:
        if wal.exists():
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix='gf-recover-')))
            shutil.copyfile(source, folder / source.name)
            shutil.copyfile(wal, folder / wal.name)
            con = sqlite3.connect(folder / source.name)
        else:
            con = sqlite3.connect(f'file:{quote(str(source.resolve()))}?mode=ro&immutable=1', uri=True)
    except (OSError, sqlite3.Error) as err:
        msg = f'recover: cannot open {source}: {err}'
        raise RecordingError(msg) from err
    stack.callback(con.close)
    try:  # accept a file shorter than its header says (cut short): read the pages it has
        con.execute('PRAGMA writable_schema=ON')
    except sqlite3.Error as err:
        msg = f'recover: cannot read {source}: {err}'
        raise RecordingError(msg) from err
    return con


class _Salvage:
    """Rows of one table in rowid order, passing over ranges that cannot be read."""

    def __init__(self, con: sqlite3.Connection, table: str) -> None:
        self.con = con
        self.table = table
        self.gaps = 0
        self.lost = 0
        self.tail_lost = False
        self.invalid = 0
        self.last: int | None = None

    def _query(self, after: int | None, limit: int | None = None) -> sqlite3.Cursor:
        where = '' if after is None else f' WHERE rowid > {int(after)}'
        tail = '' if limit is None else f' LIMIT {int(limit)}'
        return self.con.execute(f'SELECT rowid, * FROM "{self.table}"{where} ORDER BY rowid{tail}')

    def _readable_from(self, bad: int) -> int | None:
        """The smallest ``x > bad`` from which a row can be read again (None: no readable row after ``bad``).

        Probes ``x = bad + 1, + 2, + 4, ...`` (a probe reads the first row at or after ``x``), then bisects back
        between the last failing probe and the first that reads.
        """

        def ok(x: int) -> bool | None:  # True: a row at or after x is read; None: no row there; False: error
            try:
                return True if self._query(x - 1, 1).fetchone() is not None else None
            except sqlite3.Error:
                return False

        lo = bad  # known unreadable
        step = 1
        while True:
            probe = lo + step
            state = ok(probe)
            if state is None:
                return None
            if state:
                break
            lo = probe
            step *= 2
            if step > 1 << 62:
                return None
        hi = probe
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if ok(mid) is False:
                lo = mid
            else:
                hi = mid
        return hi

    def batches(self) -> Iterator[list[tuple[Any, ...]]]:
        """The table's rows (without the rowid column), a batch at a time.

        After an error the rows are read one at a time from the last row read, to find the first that cannot be
        read; reading resumes at the next readable row, and goes back to batches after a batch worth of rows.
        """
        after: int | None = None
        careful = 0  # rows still to read one at a time
        while True:
            try:
                cursor = self._query(after)
                while True:
                    rows = cursor.fetchmany(1 if careful else _ROWS_PER_FETCH)
                    if not rows:
                        return
                    careful = max(0, careful - len(rows))
                    good = []
                    for row in rows:
                        rowid = row[0]
                        previous = 0 if self.last is None else self.last
                        if not isinstance(rowid, int) or rowid <= previous:  # out of order: a damaged page's cell
                            self.invalid += 1
                            continue
                        self.lost += rowid - previous - 1  # rosbag2 numbers rows from 1 without gaps
                        self.last = after = rowid
                        good.append(tuple(row[1:]))
                    if good:
                        yield good
            except sqlite3.Error:
                if not careful:  # find the exact row: read one at a time from the last row read
                    careful = _ROWS_PER_FETCH
                    continue
                start = 0 if after is None else after
                resume = self._readable_from(start + 1)  # the row after `after` cannot be read
                if resume is None:
                    self.tail_lost = True
                    return
                self.gaps += 1
                after = resume - 1

    def describe(self) -> str:
        parts = []
        if self.gaps:
            parts.append(f'{self.gaps} unreadable row ranges skipped ({self.lost} rows)')
        if self.tail_lost:
            parts.append(f'rows after rowid {self.last if self.last is not None else 0} unreadable')
        return ', '.join(parts)


def _db3_topics(con: sqlite3.Connection) -> dict[str, TopicStats]:
    columns = {row[1] for row in con.execute('PRAGMA table_info(topics)')}
    has_hash = 'type_description_hash' in columns
    query = ('SELECT id, name, type, serialization_format, offered_qos_profiles'
             + (', type_description_hash' if has_hash else '') + ' FROM topics')
    counts = {row[0]: row[1:] for row in con.execute(
        'SELECT topic_id, count(*), min(timestamp), max(timestamp) FROM messages GROUP BY topic_id')}
    out = {}
    for row in con.execute(query):
        count, start, end = counts.get(row[0], (0, 0, 0))   # a topic with no message is kept, with 0
        out[row[1]] = TopicStats(row[2], row[3], row[4] or [], (row[5] or '') if has_hash else '', count, start,
                                 end)
    return out


# ----------------------------------------------------------------------------------------------------------------
# folders and files


def recover(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    progress: Callable[[int, int, str], None] | None = None,
) -> Recovery:
    """Recover a bag folder, a bag file (``.mcap``/``.db3``) or a residual-log folder/file into ``dst``.

    A folder gives a folder of the same file names plus a rosbag2 ``metadata.yaml`` (of the source's version, in
    that version's form; version 9 without one) describing what was kept, every topic, those with no message too;
    its files are those its metadata.yaml lists and any other ``.mcap``/``.db3`` in it (a recorder killed
    before writing metadata.yaml). A file gives a file.

    Args:
        src: what to recover.
        dst: what to create; must not exist.
        progress: called as ``progress(done, total, file_name)`` per file.

    Raises:
        RecordingError: ``dst`` exists, ``src`` is not a bag or residual log, its serialization is not CDR
            (:func:`~.bag.foreign_serialization`: nothing to recover, it would stay unreadable), nothing in it can be
            read, or writing fails. Output already written is removed.
    """
    source, target = Path(src), Path(dst)
    _check_target(target)
    phrase = foreign_serialization(source)  # not damaged, and not readable once copied: say so
    if phrase is not None:
        raise unsupported_serialization(source, phrase, prefix='recover:')
    if source.is_file():
        storage = _STORAGES.get(source.suffix)
        if storage is None:
            msg = f'recover: {source} is not a bag or residual log (expected a folder, a .mcap or a .db3 file)'
            raise RecordingError(msg)
        if progress is not None:
            progress(0, 1, source.name)
        result = recover_mcap(source, target) if storage == 'mcap' else recover_db3(source, target)
        if progress is not None:
            progress(1, 1, source.name)
        return Recovery(source, target, 'file', (result,))
    if not source.is_dir():
        msg = f'recover: {source}: no such file or directory'
        raise RecordingError(msg)
    meta = _source_metadata(source)
    files = _folder_files(source, meta)
    storages = {_STORAGES[p.suffix] for p in files}
    if len(storages) > 1:
        msg = f'recover: {source} mixes .mcap and .db3 files; recover them one by one'
        raise RecordingError(msg)
    results: list[FileRecovery] = []
    skipped: list[str] = []
    with _temporary(target, folder=True) as tmp:
        for i, path in enumerate(files):
            if progress is not None:
                progress(i, len(files), path.name)
            try:
                one = recover_mcap(path, tmp / path.name) if path.suffix == '.mcap' else \
                    recover_db3(path, tmp / path.name)
            except RecordingError as err:
                skipped.append(str(err))
                continue
            if one.messages == 0:
                (tmp / path.name).unlink(missing_ok=True)
                skipped.append(f'{path.name}: no message could be read')
                continue
            results.append(one._replace(target=target / path.name))
        if progress is not None:
            progress(len(files), len(files), '')
        if not results:
            why = '; '.join(skipped) or 'no files'
            msg = f'recover: nothing could be read from {source} ({why})'
            raise RecordingError(msg)
        try:
            _write_metadata(tmp, storages.pop(), results, meta, source)
        except OSError as err:
            msg = f'recover: writing {target / "metadata.yaml"}: {err.strerror or err}'
            raise RecordingError(msg) from err
    return Recovery(source, target, 'folder', tuple(results), tuple(skipped))


def _check_target(target: Path) -> None:
    if target.exists() or target.is_symlink():
        msg = f'recover: {target} exists already; choose a new --out (nothing is overwritten)'
        raise RecordingError(msg)
    if not target.parent.is_dir():
        msg = f'recover: {target.parent} is not a folder'
        raise RecordingError(msg)


def _temporary(target: Path, *, folder: bool = False) -> contextlib.AbstractContextManager[Path]:
    """A temporary path next to ``target``, renamed to it on success and removed on failure (the one rule,
    :func:`~gimbal_friction.common.files.staged`; an existing ``target`` is never overwritten)."""
    return staged(target, folder=folder, what='recovered bag', error=RecordingError)


def _source_metadata(folder: Path) -> dict[str, Any] | None:
    """The source's rosbag2 metadata (None if absent or unreadable)."""
    path = folder / 'metadata.yaml'
    if not path.is_file():
        return None
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
        info = doc['rosbag2_bagfile_information']
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return None
    if not isinstance(info, dict):
        return None
    if (info.get('compression_mode') or '').lower() not in ('', 'none'):
        msg = f'recover: {folder} is a compressed bag ({info.get("compression_mode")} mode); decompress it first'
        raise RecordingError(msg)
    return info


def _folder_files(folder: Path, meta: dict[str, Any] | None) -> list[Path]:
    listed: list[Path] = []
    if meta is not None:
        for name in meta.get('relative_file_paths') or []:
            path = folder / Path(str(name)).name
            if path.suffix in _STORAGES and path.is_file() and path not in listed:
                listed.append(path)
    others = sorted((p for p in folder.iterdir() if p.suffix in _STORAGES and p.is_file() and p not in listed),
                    key=file_write_order)
    files = listed + others
    if not files:
        msg = f'recover: {folder} holds no .mcap or .db3 file (not a bag or residual log)'
        raise RecordingError(msg)
    return files


def _write_metadata(
    folder: Path, storage: str, files: list[FileRecovery], meta: dict[str, Any] | None, source: Path
) -> None:
    """A rosbag2 metadata.yaml describing the recovered files: of the source's version (:data:`METADATA_VERSION`
    without a readable source metadata, or for a newer one), every field in the form that version needs
    (``offered_qos_profiles``: :func:`qos_for_version`; ``type_description_hash`` from version 7), every topic of
    the recovered files, those with no message too."""
    version = METADATA_VERSION
    with contextlib.suppress(KeyError, TypeError, ValueError):
        version = min(int((meta or {})['version']), METADATA_VERSION)
    known = {}
    for entry in (meta or {}).get('topics_with_message_count') or []:
        with contextlib.suppress(KeyError, TypeError):
            known[entry['topic_metadata']['name']] = entry['topic_metadata']
    topics: dict[str, dict[str, Any]] = {}
    for f in files:
        for name, t in (f.topics or {}).items():
            entry = topics.setdefault(name, {'stats': t, 'count': 0})
            entry['count'] += t.messages

    def span(stats: list[TopicStats]) -> tuple[int, int]:
        busy = [t for t in stats if t.messages]
        start = min((t.start_ns for t in busy), default=0)
        return start, max((t.end_ns for t in busy), default=0) - start

    def topic_metadata(name: str, stats: TopicStats) -> dict[str, Any]:
        src = known.get(name) or {}
        out = {'name': name, 'type': str(src.get('type') or stats.msgtype),
               'serialization_format': str(src.get('serialization_format') or stats.serialization_format),
               'offered_qos_profiles': qos_for_version(src.get('offered_qos_profiles', stats.offered_qos_profiles),
                                                       version)}
        if version >= 7:
            out['type_description_hash'] = str(src.get('type_description_hash') or stats.type_description_hash or '')
        return out

    start, duration = span([t for f in files for t in (f.topics or {}).values()])
    info = {
        'version': version,
        'storage_identifier': storage,
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f.messages for f in files),
        'topics_with_message_count': [{'topic_metadata': topic_metadata(name, e['stats']), 'message_count': e['count']}
                                      for name, e in topics.items()],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f.target.name for f in files if f.target is not None],
        'files': [
            {
                'path': f.target.name,
                'starting_time': {'nanoseconds_since_epoch': span(list((f.topics or {}).values()))[0]},
                'duration': {'nanoseconds': span(list((f.topics or {}).values()))[1]},
                'message_count': f.messages,
            }
            for f in files if f.target is not None
        ],
        'custom_data': {'recovered_by': LIBRARY, 'recovered_from': str(source)},
        'ros_distro': str((meta or {}).get('ros_distro') or ''),
    }
    text = yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False, default_flow_style=False,
                          width=1 << 30)   # (no folded lines: one string per line, as rosbag2 writes them)
    (folder / 'metadata.yaml').write_text(text, encoding='utf-8')
