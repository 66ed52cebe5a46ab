"""The bulk fast path (mcap_bulk) behind ResidualLogWriter.write_raw_many: pinned to the mcap version, used, and the
same files, byte for byte, as write_raw per message (the public mcap API); the forced fallback gives the same files."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from gimbal_friction.recording import mcap_bulk
from gimbal_friction.recording.cdr import default_typestore, float64_multi_array_cdr, joint_state_cdr, make_temperature
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.residual_read import iter_residual_log
from gimbal_friction.recording.topics import (
    FLOAT64_MULTI_ARRAY_TYPE,
    JOINT_STATE_TYPE,
    RESIDUAL,
    RESIDUAL_DETAIL,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)

T0 = 1_700_000_000_000_000_000  # [ns]
TOPICS = [(RESIDUAL, JOINT_STATE_TYPE), (RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE), (TEMPERATURE, TEMPERATURE_TYPE),
          ('/joint_states', JOINT_STATE_TYPE)]


def make_batch(rng: np.random.Generator, n: int, *, start_ns: int = T0, topics=(0, 1, 2, 3)):
    """n messages on random topics, with log times mostly increasing (ties and a few steps back)."""
    store = default_typestore()
    ids = rng.choice(np.array(topics), size=n)
    steps = rng.choice([0, 1_000_000, 3_000_000, -500_000], size=n, p=[0.2, 0.5, 0.25, 0.05])
    logs = start_ns + np.maximum(np.cumsum(steps), 0)
    datas = []
    for k, t in enumerate(ids.tolist()):
        if t in (0, 3):
            names = ['elevation', 'azimuth'][: int(rng.integers(1, 3))]
            datas.append(joint_state_cdr(int(logs[k]), names, rng.normal(size=len(names)),
                                         rng.normal(size=len(names)), rng.normal(size=len(names))))
        elif t == 1:
            datas.append(float64_multi_array_cdr(rng.normal(size=int(rng.integers(1, 40))), 'elevation'))
        else:
            msg = make_temperature(int(logs[k]), float(rng.normal()))
            datas.append(bytes(store.serialize_cdr(msg, TEMPERATURE_TYPE)))
    return ids, logs, datas


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def write_both(tmp_path: Path, batches, **kwargs):
    """Write the batches with write_raw_many and with write_raw; return both folders' files."""
    one, many = tmp_path / 'one', tmp_path / 'many'
    with ResidualLogWriter(one, **kwargs) as writer:
        for ids, logs, datas in batches:
            for t, log_ns, data in zip(ids.tolist(), logs.tolist(), datas, strict=False):
                writer.write_raw(TOPICS[t][0], TOPICS[t][1], log_ns, data)
        stats_one = writer.stats
    with ResidualLogWriter(many, **kwargs) as writer:
        for ids, logs, datas in batches:
            writer.write_raw_many(TOPICS, ids, logs, datas)
        stats_many = writer.stats
    assert stats_one.messages == stats_many.messages
    return folder_bytes(one), folder_bytes(many)


@pytest.mark.parametrize(('chunk_size', 'compression'), [(1, 'none'), (300, 'none'), (5000, 'zstd'),
                                                         (64 * 1024, 'lz4'), (1 << 20, 'zstd')])
def test_same_files_as_write_raw(tmp_path, chunk_size, compression):
    rng = np.random.default_rng(chunk_size)
    batches = [make_batch(rng, n, start_ns=T0 + k * 10**9) for k, n in enumerate((1, 700, 0, 53, 1200))]
    one, many = write_both(tmp_path, batches, chunk_size=chunk_size, compression=compression,
                           flush_interval_s=None)
    assert list(one) == list(many) == ['metadata.yaml', 'residuals_0.mcap']
    assert one == many


def test_topics_appearing_late_and_a_large_schema_chunk(tmp_path):
    rng = np.random.default_rng(7)
    first = make_batch(rng, 200, topics=(0,))
    second = make_batch(rng, 300, start_ns=T0 + 10**10, topics=(0, 1, 2, 3))
    one, many = write_both(tmp_path, [first, second], chunk_size=400, flush_interval_s=None)
    assert one == many


@pytest.mark.parametrize('rotation', [{'max_bytes': 3000}, {'max_bytes': 20_000, 'chunk_size': 1500},
                                      {'max_duration_s': 0.05}, {'max_duration_s': 0.2, 'max_bytes': 9000}])
def test_same_files_with_rotation(tmp_path, rotation):
    rng = np.random.default_rng(11)
    batches = [make_batch(rng, 400), make_batch(rng, 333, start_ns=T0 + 10**9)]
    kwargs = {'chunk_size': 700, 'flush_interval_s': None, 'compression': 'none', **rotation}
    one, many = write_both(tmp_path, batches, **kwargs)
    assert len(one) > 3  # several files
    assert one == many


def test_mixed_with_write_raw_in_the_same_chunks(tmp_path):
    rng = np.random.default_rng(10)
    batches = [make_batch(rng, n, start_ns=T0 + k * 10**9) for k, n in enumerate((30, 1, 250, 7, 400))]
    one, mixed = tmp_path / 'one', tmp_path / 'mixed'
    kwargs = {'chunk_size': 3000, 'flush_interval_s': None, 'max_bytes': 40_000}
    with ResidualLogWriter(one, **kwargs) as writer:
        for ids, logs, datas in batches:
            for t, log_ns, data in zip(ids.tolist(), logs.tolist(), datas, strict=False):
                writer.write_raw(TOPICS[t][0], TOPICS[t][1], log_ns, data)
    with ResidualLogWriter(mixed, **kwargs) as writer:
        for k, (ids, logs, datas) in enumerate(batches):
            if k % 2:
                for t, log_ns, data in zip(ids.tolist(), logs.tolist(), datas, strict=False):
                    writer.write_raw(TOPICS[t][0], TOPICS[t][1], log_ns, data)
            else:  # in pieces, some of one message
                for a, b in ((0, 1), (1, 2), (2, len(ids))):
                    writer.write_raw_many(TOPICS, ids[a:b], logs[a:b], datas[a:b])
    assert folder_bytes(one) == folder_bytes(mixed)
    assert len(folder_bytes(one)) > 2


def test_a_topic_listed_twice(tmp_path):
    rng = np.random.default_rng(16)
    ids, logs, datas = make_batch(rng, 300)
    one, many = tmp_path / 'one', tmp_path / 'many'
    with ResidualLogWriter(one, chunk_size=2000, flush_interval_s=None) as writer:
        writer.write_raw_many(TOPICS, ids, logs, datas)
    doubled = TOPICS + TOPICS
    ids2 = ids + len(TOPICS) * rng.integers(0, 2, size=len(ids))  # the same topics under two ids each
    with ResidualLogWriter(many, chunk_size=2000, flush_interval_s=None) as writer:
        writer.write_raw_many(doubled, ids2, logs, datas)
    assert folder_bytes(one) == folder_bytes(many)


def test_with_a_flush_interval_the_messages_go_one_by_one(tmp_path):
    rng = np.random.default_rng(12)
    batches = [make_batch(rng, 300)]
    ticks = iter(np.arange(0.0, 100.0, 0.01))
    one, many = write_both(tmp_path, batches, chunk_size=2000, flush_interval_s=0.5, clock=lambda: next(ticks))
    # the clock moved on between the two writers: compare what does not depend on it
    assert set(one) == set(many)
    first = [(m.channel_id, m.sequence, m.log_time, m.data) for _, _, m in make_reader(
        (tmp_path / 'one' / 'residuals_0.mcap').open('rb')).iter_messages(log_time_order=False)]
    second = [(m.channel_id, m.sequence, m.log_time, m.data) for _, _, m in make_reader(
        (tmp_path / 'many' / 'residuals_0.mcap').open('rb')).iter_messages(log_time_order=False)]
    assert first == second


def test_the_installed_mcap_is_the_pinned_one_and_the_fast_path_runs_on_it(tmp_path, monkeypatch):
    pinned = next(line.split('==')[1].strip() for line in
                  (Path(__file__).resolve().parents[2] / 'requirements.txt').read_text().splitlines()
                  if line.startswith('mcap=='))
    assert mcap_bulk.mcap_version() == pinned == mcap_bulk.SUPPORTED_MCAP_VERSIONS[0]
    calls = []
    real = mcap_bulk.BulkChunk.append

    def spy(self, *args, **kwargs):
        calls.append(len(args[0]))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(mcap_bulk.BulkChunk, 'append', spy)
    rng = np.random.default_rng(12)
    ids, logs, datas = make_batch(rng, 300)
    with ResidualLogWriter(tmp_path / 'log', chunk_size=5000, flush_interval_s=None) as writer:
        writer.write_raw_many(TOPICS, ids, logs, datas)
    assert sum(calls) == 300 and max(calls) > 1  # the messages went through the fast path, in runs


def test_forced_fallback_gives_the_same_files_and_reads_back_the_same(tmp_path, monkeypatch):
    rng = np.random.default_rng(13)
    batches = [make_batch(rng, 500), make_batch(rng, 300, start_ns=T0 + 10**10)]
    fast_one, fast_many = write_both(tmp_path / 'fast', batches, chunk_size=900, flush_interval_s=None)
    assert fast_one == fast_many
    monkeypatch.setattr(mcap_bulk, 'ENABLED', False)
    with ResidualLogWriter(tmp_path / 'probe', flush_interval_s=None) as writer:
        assert mcap_bulk.bulk_chunk(writer._file.writer) is None
    _slow_one, slow_many = write_both(tmp_path / 'slow', batches, chunk_size=900, flush_interval_s=None)
    assert slow_many == fast_many  # byte for byte
    read = [[(m.topic, m.log_time_ns, m.msg) for m in iter_residual_log(tmp_path / kind / 'many')]
            for kind in ('fast', 'slow')]
    assert len(read[0]) == 800
    assert [(t, lt) for t, lt, _ in read[0]] == [(t, lt) for t, lt, _ in read[1]]


def test_readable_by_mcap_rosbags_and_iter_residual_log(tmp_path):
    rng = np.random.default_rng(14)
    ids, logs, datas = make_batch(rng, 800)
    folder = tmp_path / 'log'
    with ResidualLogWriter(folder, chunk_size=4000, flush_interval_s=None) as writer:
        assert mcap_bulk.bulk_chunk(writer._file.writer) is not None  # the fast path runs on this mcap
        writer.write_raw_many(TOPICS, ids, logs, datas)
    with (folder / 'residuals_0.mcap').open('rb') as stream:
        reader = make_reader(stream)
        got = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(log_time_order=False)]
        stats = reader.get_summary().statistics
    assert got == [(TOPICS[t][0], int(log), d) for t, log, d in zip(ids.tolist(), logs.tolist(), datas, strict=False)]
    assert stats.message_count == 800
    with AnyReader([folder], default_typestore=default_typestore()) as reader:
        assert sum(1 for _ in reader.messages()) == 800
    assert len(list(iter_residual_log(folder))) == 800


def test_a_bad_batch_writes_nothing(tmp_path):
    rng = np.random.default_rng(15)
    ids, logs, datas = make_batch(rng, 20)
    with ResidualLogWriter(tmp_path / 'log', flush_interval_s=None) as writer:
        bad = list(datas)
        bad[7] = b'\x01\x00\x00\x00' + bad[7][4:]
        with pytest.raises(RecordingError, match='not plain CDR'):
            writer.write_raw_many(TOPICS, ids, logs, bad)
        bad[7] = b'\x00\x01'
        with pytest.raises(RecordingError, match='not plain CDR'):
            writer.write_raw_many(TOPICS, ids, logs, bad)
        with pytest.raises(RecordingError, match='topic ids'):
            writer.write_raw_many(TOPICS, ids + 10, logs, datas)
        with pytest.raises(RecordingError, match='negative'):
            writer.write_raw_many(TOPICS, ids, logs - T0 - 10**12, datas)
        with pytest.raises(RecordingError, match='messages but'):
            writer.write_raw_many(TOPICS, ids[:-1], logs, datas)
        with pytest.raises(RecordingError, match='unknown message type'):
            writer.write_raw_many([('/x', 'my_pkg/msg/Nope')], np.zeros(2, int), logs[:2], datas[:2])
        writer.write_raw(RESIDUAL, JOINT_STATE_TYPE, T0, datas[int(np.flatnonzero(ids == 0)[0])])
        with pytest.raises(RecordingError, match='was logged as'):
            writer.write_raw_many([(RESIDUAL, TEMPERATURE_TYPE)], np.zeros(1, int), logs[:1], datas[:1])
        with pytest.raises(RecordingError, match='was logged as'):
            writer.write_raw_many([('/y', TEMPERATURE_TYPE), ('/y', JOINT_STATE_TYPE)], np.array([0, 1]),
                                  logs[:2], datas[:2])
        assert writer.stats.messages == 1
        writer.write_raw_many(TOPICS, ids[:0], logs[:0], [])
        assert writer.stats.messages == 1


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_chunks_compressed_in_the_worker_thread_give_the_same_files(tmp_path, monkeypatch, compression):
    """Without rotation by size, a full chunk is compressed in a worker thread while the next run is appended,
    then written out in turn: the files are those of write_raw, byte for byte (chunk records, indexes, summary)."""
    closed = []
    original = mcap_bulk.BulkChunk.maybe_finalize_pipelined

    def spy(self):
        done = original(self)
        closed.append(done and self.pipelined)
        return done

    monkeypatch.setattr(mcap_bulk.BulkChunk, 'maybe_finalize_pipelined', spy)
    rng = np.random.default_rng(31)
    batches = [make_batch(rng, n, start_ns=T0 + k * 10**9) for k, n in enumerate((900, 1, 1500))]
    one, many = write_both(tmp_path, batches, chunk_size=4000, compression=compression, flush_interval_s=None,
                           max_duration_s=1.5)
    assert sum(closed) > 10   # chunks went through the worker thread
    assert len(one) >= 3 and one == many   # files rotated by duration, and metadata.yaml


# ---------------------------------------------------------------------------------------------- issue 31 item 14
def test_lengths_given_by_the_caller_write_the_same_files(tmp_path):
    """``replay`` passes the lengths of what it serialized (skipping three passes over the messages): the same
    bytes as without them; lengths that are not the messages' fail the writer instead of writing a wrong file."""
    rng = np.random.default_rng(31)
    batches = [make_batch(rng, 400) for _ in range(3)]
    _, plain = write_both(tmp_path / 'a', batches, chunk_size=5000)
    given = tmp_path / 'given'
    with ResidualLogWriter(given, chunk_size=5000) as writer:
        for ids, logs, datas in batches:
            writer.write_raw_many(TOPICS, ids, logs, datas, lengths=[len(d) for d in datas])
    assert folder_bytes(given) == plain
    ids, logs, datas = batches[0]
    with ResidualLogWriter(tmp_path / 'wrong', chunk_size=5000, flush_interval_s=None) as writer:
        with pytest.raises(RecordingError, match='lengths for'):
            writer.write_raw_many(TOPICS, ids, logs, datas, lengths=[len(d) for d in datas][:-1])
        wrong = [len(d) for d in datas]
        wrong[5] += 1
        with pytest.raises(RecordingError, match='their lengths say'):
            writer.write_raw_many(TOPICS, ids, logs, datas, lengths=wrong)
        with pytest.raises(RecordingError):   # and the writer refuses what follows
            writer.write_raw_many(TOPICS, ids, logs, datas)


def test_several_chunks_in_flight_give_the_same_files(tmp_path, monkeypatch):
    """Up to PIPELINE_DEPTH full chunks are compressed in the worker thread while the next is built (one in flight
    made the writer wait for each hand-over); they are written out in order: the files of write_raw, byte for byte.
    The worker is held until the writer first waits for a chunk, so that the pipeline fills deterministically."""
    gate = threading.Event()
    original_compress = mcap_bulk._compress
    original_write = mcap_bulk.BulkChunk._write_oldest
    waited_with: list[int] = []

    def held_compress(*args):
        gate.wait()
        return original_compress(*args)

    def write_oldest(self):
        waited_with.append(len(self._pending))
        gate.set()
        return original_write(self)

    monkeypatch.setattr(mcap_bulk, '_compress', held_compress)
    monkeypatch.setattr(mcap_bulk.BulkChunk, '_write_oldest', write_oldest)
    rng = np.random.default_rng(32)
    batches = [make_batch(rng, 3000)]
    one, many = write_both(tmp_path, batches, chunk_size=4000, compression='zstd', flush_interval_s=None)
    assert waited_with[0] == mcap_bulk.PIPELINE_DEPTH > 1
    assert one == many
