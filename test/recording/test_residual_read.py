"""Reading residual rows back: streamed in bounded parts, in bulk, past damaged chunks, in any byte order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gimbal_friction.recording.cdr import default_typestore, make_float64_multi_array, make_joint_state
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.mcap_scan import McapScanner
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.residual_read import (
    ReadReport,
    iter_residual_log,
    iter_residual_rows,
    read_residual_rows,
)
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, JOINT_STATE_TYPE, RESIDUAL, RESIDUAL_DETAIL
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS, ResidualRows

T0 = 1_700_000_000_000_000_000  # [ns]
JOINTS = ('elevation', 'azimuth')


def row(i: int) -> np.ndarray:
    out = np.arange(len(RESIDUAL_FIELDS), dtype=np.float64) + 1000.0 * i
    out[-1] = i % 2
    return out


def write_log(folder: Path, n: int, **kwargs: object) -> Path:
    """n rows on two joints, each with a residual JointState, written one message at a time."""
    with ResidualLogWriter(folder, **kwargs) as writer:  # type: ignore[arg-type]
        for i in range(n):
            joint = JOINTS[i % 2]
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, T0 + i, make_float64_multi_array(row(i), joint))
            writer.write(RESIDUAL, JOINT_STATE_TYPE, T0 + i, make_joint_state(T0 + i, [joint], effort=[0.1]))
    return folder


def stamps(rows: ResidualRows) -> np.ndarray:
    return (np.asarray(rows.stamp_s) / 1000.0).round().astype(int)


def test_streamed_parts_are_bounded_and_add_up_to_the_whole(tmp_path: Path) -> None:
    folder = write_log(tmp_path / 'log', 500, chunk_size=2048, max_bytes=16 * 1024)
    whole, report = read_residual_rows(folder)
    assert len(whole) == report.rows == 500 and len(report.files) >= 4
    np.testing.assert_array_equal(stamps(whole), np.arange(500))
    np.testing.assert_array_equal(whole.joint, np.array(JOINTS * 250))
    np.testing.assert_array_equal(whole.method, np.arange(500) % 2)
    for name in RESIDUAL_FIELDS[1:-1]:
        np.testing.assert_array_equal(getattr(whole, name), RESIDUAL_FIELDS.index(name) + 1000.0 * np.arange(500))
    parts = list(iter_residual_rows(folder, chunk_rows=37))
    assert [len(p) for p in parts] == [37] * 13 + [500 - 37 * 13]
    np.testing.assert_array_equal(np.concatenate([p.stamp_s for p in parts]), whole.stamp_s)
    assert report.topic_counts == {RESIDUAL_DETAIL: 500, RESIDUAL: 500}
    assert (report.bad_chunks, report.truncated_files, report.skipped_rows) == (0, [], 0)


def test_streaming_reads_no_further_than_it_must(tmp_path: Path) -> None:
    folder = write_log(tmp_path / 'log', 600, chunk_size=1024, max_bytes=8 * 1024)
    report = ReadReport()
    parts = iter_residual_rows(folder, chunk_rows=10, report=report)
    first = next(parts)
    assert len(first) == 10
    n_files = len(list(folder.glob('*.mcap')))
    assert n_files >= 6 and len(report.files) == 1  # the first part came from the first file alone
    rest = sum(len(p) for p in parts)
    assert rest == 590 and len(report.files) == n_files
    with pytest.raises(RecordingError, match='chunk_rows'):
        next(iter_residual_rows(folder, chunk_rows=0))


def damage_one_chunk(path: Path, which: int) -> int:
    """Corrupt the compressed bytes of chunk ``which`` (counted from 0); return the messages it held."""
    data = bytearray(path.read_bytes())
    pos, k = 8, 0
    while True:
        op = data[pos]
        length = int.from_bytes(data[pos + 1 : pos + 9], 'little')
        if op == 0x06:
            if k == which:
                middle = pos + 9 + length // 2
                data[middle : middle + 16] = bytes(16)
                break
            k += 1
        pos += 9 + length
    path.write_bytes(bytes(data))
    scan = McapScanner(path)
    kept = sum(len(b) for b in scan.blocks())
    return scan.report.lost_messages if kept else -1


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_a_damaged_chunk_is_skipped_and_the_chunks_after_it_are_read(tmp_path: Path, compression: str) -> None:
    folder = write_log(tmp_path / 'log', 400, chunk_size=2048, compression=compression)
    (path,) = folder.glob('*.mcap')
    lost = damage_one_chunk(path, 3)
    rows, report = read_residual_rows(folder)
    assert report.bad_chunks == 1 and report.lost_messages == lost > 0 and not report.unknown_loss
    assert len(rows) == 400 - lost // 2  # half of the messages are rows
    got = stamps(rows)
    assert got[0] == 0 and got[-1] == 399  # rows after the damaged chunk are read
    gap = np.flatnonzero(np.diff(got) != 1)
    assert gap.shape[0] == 1 and got[gap[0] + 1] - got[gap[0]] - 1 == lost // 2
    assert any('damaged' in p for p in report.problems)
    assert 'damaged chunks skipped' in report.summary()


def test_big_endian_rows_and_other_widths(tmp_path: Path) -> None:
    store = default_typestore()
    folder = tmp_path / 'log'
    with ResidualLogWriter(folder) as writer:
        for i in range(6):
            msg = make_float64_multi_array(row(i), 'elevation')
            writer.write_raw(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, T0 + i,
                             bytes(store.serialize_cdr(msg, FLOAT64_MULTI_ARRAY_TYPE, little_endian=i % 2 == 0)))
        writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, T0 + 9, make_float64_multi_array([1.0, 2.0], 'x'))
    rows, report = read_residual_rows(folder)
    np.testing.assert_array_equal(stamps(rows), np.arange(6))  # in file order, whatever the byte order
    assert report.skipped_rows == 1 and 'not rows skipped' in report.summary()


def test_iter_residual_log_decodes_any_topic_and_skips_damage(tmp_path: Path) -> None:
    folder = write_log(tmp_path / 'log', 300, chunk_size=2048)
    (path,) = folder.glob('*.mcap')
    lost = damage_one_chunk(path, 2)
    report = ReadReport()
    items = list(iter_residual_log(folder, [RESIDUAL], report=report))
    assert len(items) == 300 - lost // 2 and report.bad_chunks == 1
    assert {x.msgtype for x in items} == {JOINT_STATE_TYPE}
    assert list(items[0].msg.name) == ['elevation']  # type: ignore[attr-defined]


def test_refusals(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r'not a residual log: .*no such file'):
        read_residual_rows(tmp_path / 'missing')
    (tmp_path / 'junk').mkdir()
    (tmp_path / 'junk' / 'x.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(RecordingError, match='not an MCAP file'):
        read_residual_rows(tmp_path / 'junk')
    with ResidualLogWriter(tmp_path / 'wrong') as writer:
        writer.write(RESIDUAL_DETAIL, JOINT_STATE_TYPE, T0, make_joint_state(T0, ['elevation']))
    with pytest.raises(RecordingError, match=f'{RESIDUAL_DETAIL} has type {JOINT_STATE_TYPE}'):
        read_residual_rows(tmp_path / 'wrong')
    (tmp_path / 'empty_file').mkdir()  # a killed logger's brand-new file: no records, not an error
    write_log(tmp_path / 'empty_file' / 'sub', 3)
    (tmp_path / 'empty_file' / 'sub' / 'residuals_1.mcap').write_bytes(b'')
    rows, report = read_residual_rows(tmp_path / 'empty_file' / 'sub')
    assert len(rows) == 3 and [p.name for p in report.truncated_files] == ['residuals_1.mcap']
