"""Residual log writer and reader: round trip, rotation, metadata.yaml, torn files, a real SIGKILL, refusals."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from gimbal_friction.recording.cdr import (
    default_typestore,
    make_float64_multi_array,
    make_joint_state,
    make_temperature,
)
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.recover import recover_mcap
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.residual_read import (
    iter_residual_log,
    read_residual_rows,
    residual_log_files,
)
from gimbal_friction.recording.topics import (
    FLOAT64_MULTI_ARRAY_TYPE,
    JOINT_STATE_TYPE,
    RESIDUAL,
    RESIDUAL_DETAIL,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS, RESIDUAL_FIELDS_V1, ResidualRows

T0 = 1_700_000_000_000_000_000  # [ns]
N_FIELDS = len(RESIDUAL_FIELDS)


def detail_row(i: int) -> np.ndarray:
    """Row i: field k holds k + 100 i, except the method (0 or 1)."""
    row = np.arange(N_FIELDS, dtype=np.float64) + 100.0 * i
    row[-1] = i % 2
    return row


class Log:
    """What the reader gives for a folder: the rows and the report."""

    def __init__(self, paths: object) -> None:
        self.detail, self.report = read_residual_rows(paths)  # type: ignore[arg-type]
        self.files = tuple(self.report.files)
        self.truncated_files = tuple(self.report.truncated_files)
        self.topic_counts = self.report.topic_counts


def read_log(paths: object) -> Log:
    return Log(paths)


def write_rows(writer: ResidualLogWriter, n: int, *, start: int = 0, step_ns: int = 1_000_000) -> None:
    """n residual samples: a detail row, a residual JointState, and (every 10th) a raw temperature."""
    store = default_typestore()
    for i in range(start, start + n):
        t = T0 + i * step_ns
        joint = 'elevation' if i % 2 == 0 else 'azimuth'
        writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, t, make_float64_multi_array(detail_row(i), joint))
        writer.write(RESIDUAL, JOINT_STATE_TYPE, t, make_joint_state(t, [joint], effort=[1e-3 * i]))
        if i % 10 == 0:
            raw = store.serialize_cdr(make_temperature(t, 20.0 + i), TEMPERATURE_TYPE)
            writer.write_raw(TEMPERATURE, TEMPERATURE_TYPE, t, raw)


def check_rows(detail: ResidualRows, indices: np.ndarray) -> None:
    assert len(detail) == len(indices)
    for k, name in enumerate(RESIDUAL_FIELDS[:-1]):
        np.testing.assert_array_equal(getattr(detail, name), k + 100.0 * indices)
    np.testing.assert_array_equal(detail.method, indices % 2)
    np.testing.assert_array_equal(detail.joint, np.where(indices % 2 == 0, 'elevation', 'azimuth'))


def test_rows_follow_the_core_residual_fields() -> None:
    assert ResidualRows._fields[1:] == RESIDUAL_FIELDS


def test_layout_1_rows_are_read_and_the_old_arrays_still_work(tmp_path: Path) -> None:
    folder = tmp_path / 'v1'
    with ResidualLogWriter(folder) as writer:
        for i in range(20):
            row = np.arange(len(RESIDUAL_FIELDS_V1), dtype=np.float64) + 100.0 * i
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, T0 + i, make_float64_multi_array(row, 'az'))
        write_rows(writer, 4, start=20)  # layout 2 rows after them
    rows, report = read_residual_rows(folder)
    assert len(rows) == 24 and report.rows == 24 and report.skipped_rows == 0
    i = np.arange(20)
    np.testing.assert_array_equal(rows.residual_nm[:20], 10 + 100.0 * i)  # m_* columns of layout 1 dropped
    np.testing.assert_array_equal(rows.predicted_nm[:20], 6 + 100.0 * i)
    assert np.isnan(rows.torque_constant_nm_per_a[:20]).all() and (rows.method[:20] == 0).all()
    check_rows(ResidualRows(*(np.asarray(c)[20:] for c in tuple.__iter__(rows))), np.arange(20, 24))


def test_round_trip(tmp_path: Path) -> None:
    folder = tmp_path / 'residuals'
    with ResidualLogWriter(folder) as writer:
        write_rows(writer, 50)
        assert writer.stats.messages == 105
    log = read_log([folder])
    assert len(log.detail) == 50
    check_rows(log.detail, np.arange(50))
    assert log.files == (folder / 'residuals_0.mcap',)
    assert log.truncated_files == ()
    assert log.topic_counts == {RESIDUAL_DETAIL: 50, RESIDUAL: 50, TEMPERATURE: 5}

    items = list(iter_residual_log(folder, [RESIDUAL, TEMPERATURE]))
    assert [x.topic for x in items[:3]] == [RESIDUAL, TEMPERATURE, RESIDUAL]
    assert items[0].msgtype == JOINT_STATE_TYPE
    assert list(items[2].msg.effort) == [1e-3]  # type: ignore[attr-defined]
    assert items[1].msg.temperature == 20.0  # type: ignore[attr-defined]


def test_close_writes_metadata_that_rosbags_and_mcap_open(tmp_path: Path) -> None:
    folder = tmp_path / 'log'
    writer = ResidualLogWriter(folder, chunk_size=2048)
    write_rows(writer, 30)
    assert not (folder / 'metadata.yaml').exists()
    writer.close()
    writer.close()  # idempotent
    assert writer.stats.current_file is None

    meta = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9
    assert meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['residuals_0.mcap']
    assert meta['message_count'] == 63
    assert meta['starting_time']['nanoseconds_since_epoch'] == T0
    assert meta['duration']['nanoseconds'] == 29_000_000
    counts = {x['topic_metadata']['name']: x['message_count'] for x in meta['topics_with_message_count']}
    assert counts == {RESIDUAL_DETAIL: 30, RESIDUAL: 30, TEMPERATURE: 3}
    assert all(x['topic_metadata']['offered_qos_profiles'] == [] for x in meta['topics_with_message_count'])

    with AnyReader([folder]) as reader:  # the folder as a rosbag2 bag
        assert reader.message_count == 63
        conns = [c for c in reader.connections if c.topic == RESIDUAL_DETAIL]
        first = next(reader.messages(connections=conns))
        msg = reader.deserialize(first[2], FLOAT64_MULTI_ARRAY_TYPE)
        np.testing.assert_array_equal(msg.data, detail_row(0))  # type: ignore[attr-defined]
    with AnyReader([folder / 'residuals_0.mcap']) as reader:  # a bare file
        assert reader.message_count == 63

    with (folder / 'residuals_0.mcap').open('rb') as stream:  # what Foxglove / mcap readers see
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == 'ros2'
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
        decoded = list(reader.iter_decoded_messages(topics=[RESIDUAL]))
        assert len(decoded) == 30
        assert list(decoded[1].decoded_message.name) == ['azimuth']


def test_rotation_by_size_gives_files_that_all_read_back(tmp_path: Path) -> None:
    folder = tmp_path / 'log'
    with ResidualLogWriter(folder, chunk_size=1024, max_bytes=8 * 1024) as writer:
        write_rows(writer, 400)
        stats = writer.stats
    assert len(stats.files) >= 4
    files = residual_log_files(folder)
    assert files == list(stats.files)
    assert [f.name for f in files[:3]] == ['residuals_0.mcap', 'residuals_1.mcap', 'residuals_2.mcap']
    for path in files[:-1]:
        assert path.stat().st_size < 8 * 1024 + 4 * 1024  # limit + one chunk + summary
    log = read_log(folder)
    check_rows(log.detail, np.arange(400))
    meta = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['relative_file_paths'] == [f.name for f in files]
    assert sum(x['message_count'] for x in meta['files']) == meta['message_count'] == 840
    with AnyReader([folder]) as reader:
        assert sum(1 for _ in reader.messages()) == 840
    for path in files:
        with AnyReader([path]) as reader:
            assert reader.message_count > 0


def test_rotation_by_duration(tmp_path: Path) -> None:
    folder = tmp_path / 'log'
    with ResidualLogWriter(folder, max_duration_s=0.05) as writer:  # 50 ms of log time per file
        write_rows(writer, 200)  # 1 ms apart: 4 files
    files = residual_log_files(folder)
    assert len(files) == 4
    log = read_log([folder])
    check_rows(log.detail, np.arange(200))
    starts = [x['starting_time']['nanoseconds_since_epoch'] for x in yaml.safe_load(
        (folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']['files']]
    assert starts == [T0 + k * 50_000_000 for k in range(4)]


def test_several_folders_read_together(tmp_path: Path) -> None:
    with ResidualLogWriter(tmp_path / 'a') as writer:
        write_rows(writer, 10, start=10)
    with ResidualLogWriter(tmp_path / 'b') as writer:
        write_rows(writer, 10)
    log = read_log([tmp_path / 'a', tmp_path / 'b'])
    check_rows(log.detail, np.r_[np.arange(10, 20), np.arange(10)])  # in file order
    assert len(log.files) == 2


def test_time_based_flush_puts_chunks_on_disk(tmp_path: Path) -> None:
    now = [0.0]
    folder = tmp_path / 'log'
    writer = ResidualLogWriter(folder, chunk_size=1 << 20, flush_interval_s=1.0, clock=lambda: now[0])
    path = folder / 'residuals_0.mcap'
    write_rows(writer, 5)
    assert writer.stats.flushed_messages == 0
    size = path.stat().st_size
    now[0] = 1.5
    write_rows(writer, 1, start=5)  # interval passed: its first write flushes everything so far
    assert (writer.stats.flushed_messages, writer.stats.messages) == (12, 13)
    assert path.stat().st_size > size
    # a reader sees the flushed messages although the file is still open (no footer)
    log = read_log(folder)
    check_rows(log.detail, np.arange(6))
    assert log.truncated_files == (path,)
    writer.close()
    assert read_log(folder).truncated_files == ()


def finished_log(tmp_path: Path, n: int = 300) -> Path:
    folder = tmp_path / 'complete'
    with ResidualLogWriter(folder, chunk_size=1024) as writer:
        write_rows(writer, n)
    return folder / 'residuals_0.mcap'


def test_torn_files_give_their_completed_chunks(tmp_path: Path) -> None:
    src = finished_log(tmp_path)
    data = src.read_bytes()
    previous = -1
    for cut in (0, 5, 8, 40, len(data) // 3, len(data) // 2, len(data) - 200, len(data) - 1):
        folder = tmp_path / f'torn_{cut}'
        folder.mkdir()
        (folder / 'residuals_0.mcap').write_bytes(data[:cut])
        if cut < len(data) // 3:
            with pytest.raises(RecordingError, match='not a residual log'):  # no residual topic seen yet
                read_log(folder)
            continue
        log = read_log(folder)
        n = len(log.detail)
        assert n >= previous
        previous = n
        check_rows(log.detail, np.arange(n))  # a prefix, no torn message
        assert log.truncated_files == (folder / 'residuals_0.mcap',)
    assert previous == 300  # the last cut only loses the footer


def test_recover_mcap_makes_a_valid_file(tmp_path: Path) -> None:
    src = finished_log(tmp_path)
    data = src.read_bytes()
    torn = tmp_path / 'torn.mcap'
    torn.write_bytes(data[: len(data) * 2 // 3])
    fixed = tmp_path / 'fixed.mcap'
    result = recover_mcap(torn, fixed)
    assert result.truncated
    assert 0 < result.messages < 630
    with AnyReader([fixed]) as reader:
        assert reader.message_count == result.messages
    with fixed.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert sum(1 for _ in reader.iter_decoded_messages()) == result.messages
        assert reader.get_header().profile == 'ros2'
    n = len(read_log(fixed).detail)
    assert n == len(read_log(torn).detail)
    with pytest.raises(RecordingError, match='exists'):
        recover_mcap(torn, fixed)
    whole = recover_mcap(src, tmp_path / 'whole.mcap')
    assert (whole.messages, whole.truncated, whole.lost, whole.unknown_loss) == (630, False, 0, False)


def test_refuses_folders_that_are_not_residual_logs(tmp_path: Path) -> None:
    (tmp_path / 'empty').mkdir()
    with pytest.raises(RecordingError, match=r'not a residual log: .*no .mcap files'):
        read_log([tmp_path / 'empty'])
    with pytest.raises(RecordingError, match='not a residual log'):
        read_log([tmp_path / 'missing'])
    with ResidualLogWriter(tmp_path / 'other') as writer:
        writer.write(TEMPERATURE, TEMPERATURE_TYPE, T0, make_temperature(T0, 20.0))
    with pytest.raises(RecordingError, match=f'not a residual log: .*holds {TEMPERATURE}'):
        read_log([tmp_path / 'other'])
    (tmp_path / 'junk').mkdir()
    (tmp_path / 'junk' / 'x.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(RecordingError, match='not an MCAP file'):
        read_log(tmp_path / 'junk')


def test_writer_refusals(tmp_path: Path) -> None:
    folder = tmp_path / 'log'
    with ResidualLogWriter(folder) as writer:
        write_rows(writer, 1)
        with pytest.raises(RecordingError, match=f'{RESIDUAL} was logged as {JOINT_STATE_TYPE}'):
            writer.write(RESIDUAL, FLOAT64_MULTI_ARRAY_TYPE, T0, make_float64_multi_array([1.0], 'x'))
        with pytest.raises(RecordingError, match='unknown message type'):
            writer.write_raw('/x', 'my_pkg/msg/Nope', T0, b'\x00\x01\x00\x00')
        with pytest.raises(RecordingError, match='not plain CDR'):
            writer.write_raw('/x', TEMPERATURE_TYPE, T0, b'\x01')
        with pytest.raises(RecordingError, match='cannot serialize'):
            writer.write('/y', TEMPERATURE_TYPE, T0, object())
        write_rows(writer, 1, start=1)  # still healthy after refused input
    with pytest.raises(RecordingError, match='already holds a log'):
        ResidualLogWriter(folder)
    with pytest.raises(RecordingError, match='writer is closed'):
        writer.write(RESIDUAL, JOINT_STATE_TYPE, T0, make_joint_state(T0, ['elevation']))
    (tmp_path / 'a_file').write_text('x')
    with pytest.raises(RecordingError, match='cannot create'):
        ResidualLogWriter(tmp_path / 'a_file' / 'log')
    with pytest.raises(RecordingError, match='max_bytes'):
        ResidualLogWriter(tmp_path / 'log2', max_bytes=0)
    assert len(read_log(folder).detail) == 2


class FullDisk:
    """Wraps a file object: writes fail with ENOSPC once armed."""

    def __init__(self, inner: object) -> None:
        self.inner = inner
        self.armed = False

    def write(self, data: bytes) -> int:
        if self.armed:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self.inner.write(data)  # type: ignore[attr-defined]

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)


def test_disk_full_is_a_recording_error_and_keeps_flushed_data(tmp_path: Path) -> None:
    folder = tmp_path / 'log'
    streams: list[FullDisk] = []

    def opener(path: Path) -> FullDisk:
        streams.append(FullDisk(path.open('xb')))
        return streams[-1]

    writer = ResidualLogWriter(
        folder, chunk_size=512, flush_interval_s=None, opener=opener  # type: ignore[arg-type]
    )
    write_rows(writer, 20)
    writer.flush()
    streams[-1].armed = True
    with pytest.raises(RecordingError, match='No space left on device'):
        write_rows(writer, 50, start=20)
    assert writer.failed
    with pytest.raises(RecordingError, match='earlier error'):
        write_rows(writer, 1, start=70)
    writer.close()  # closes the file, writes no metadata.yaml, raises nothing more
    assert not (folder / 'metadata.yaml').exists()
    log = read_log(folder)
    assert len(log.detail) >= 20
    check_rows(log.detail, np.arange(len(log.detail)))


KILL_SCRIPT = """
import sys, time
from gimbal_friction.recording.cdr import make_float64_multi_array
from gimbal_friction.recording.residual_log import ResidualLogWriter
folder, wanted = sys.argv[1], int(sys.argv[2])
# chunks far larger than what is written: only the timed flushes put data on disk
writer = ResidualLogWriter(folder, chunk_size=1 << 22, flush_interval_s=0.002)
i = 0
told = False
while True:
    writer.write('/gimbal/friction/residual_detail', 'std_msgs/msg/Float64MultiArray', 10**9 + i * 10**6,
                 make_float64_multi_array([float(i)] * 11 + [0.0], 'elevation'))
    i += 1
    flushed = writer.stats.flushed_messages
    if not told and flushed >= wanted:
        print(flushed, flush=True)
        told = True
    time.sleep(0.0005)
"""


def test_sigkill_leaves_the_flushed_messages_readable(tmp_path: Path) -> None:
    folder = tmp_path / 'killed'
    proc = subprocess.Popen(
        [sys.executable, '-c', KILL_SCRIPT, str(folder), '200'],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=dict(os.environ),
        text=True,
    )
    timer = threading.Timer(30.0, proc.kill)
    timer.start()
    try:
        line = proc.stdout.readline() if proc.stdout else ''
        time.sleep(0.05)  # keep writing a little: the kill lands mid-run
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        timer.cancel()
    stderr = proc.stderr.read() if proc.stderr else ''
    assert line.strip(), f'writer process printed nothing; stderr: {stderr}'
    flushed = int(line)
    assert proc.returncode == -signal.SIGKILL
    assert not (folder / 'metadata.yaml').exists()
    log = read_log([folder])
    assert len(log.detail) >= flushed >= 200
    assert log.truncated_files == (folder / 'residuals_0.mcap',)
    np.testing.assert_array_equal(log.detail.stamp_s, np.arange(len(log.detail), dtype=float))
    fixed = tmp_path / 'fixed.mcap'
    assert recover_mcap(folder / 'residuals_0.mcap', fixed).messages == len(log.detail)
    with AnyReader([fixed]) as reader:
        assert reader.message_count == len(log.detail)
    shutil.rmtree(folder)
