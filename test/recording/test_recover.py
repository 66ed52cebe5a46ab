"""Recovery of MCAP and sqlite3 files and folders: every readable message kept, the output opened by the standard
readers (rosbags AnyReader, mcap make_reader, a rosbag2 metadata.yaml for a folder)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from test_residual_read import damage_one_chunk, stamps, write_log

from gimbal_friction.recording.bag import open_chamber_bag
from gimbal_friction.recording.bag_write import write_chamber_bag
from gimbal_friction.recording.cdr import default_typestore, make_joint_state, make_temperature
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.recover import recover, recover_db3, recover_mcap
from gimbal_friction.recording.residual_read import read_residual_rows
from gimbal_friction.recording.topics import (
    JOINT_STATE_TYPE,
    JOINT_STATES,
    MOTOR_CURRENT,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)

T0 = 1_700_000_000_000_000_000  # [ns]


def chamber(n: int = 600) -> list[tuple[str, str, int, object]]:
    msgs: list[tuple[str, str, int, object]] = []
    for i in range(n):
        t = T0 + i * 1_000_000
        msgs.append((JOINT_STATES, JOINT_STATE_TYPE, t, make_joint_state(t, ['elevation'], [0.1 * i], [0.5])))
        if i % 2 == 0:
            msgs.append((MOTOR_CURRENT, JOINT_STATE_TYPE, t + 1, make_joint_state(t, ['elevation'], effort=[1.0])))
        if i % 10 == 0:
            msgs.append((TEMPERATURE, TEMPERATURE_TYPE, t + 2, make_temperature(t, 20.0 + i)))
    return msgs


def messages(path: Path) -> list[tuple[str, int, bytes]]:
    with AnyReader([path], default_typestore=default_typestore()) as reader:
        return [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]


def test_a_cut_residual_log_file_becomes_complete(tmp_path: Path) -> None:
    folder = write_log(tmp_path / 'log', 400, chunk_size=2048, compression='none')
    (src,) = folder.glob('*.mcap')
    data = src.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[: len(data) * 2 // 3])
    result = recover_mcap(cut, tmp_path / 'fixed.mcap')
    rows, report = read_residual_rows(tmp_path / 'fixed.mcap')
    assert result.truncated and result.unknown_loss and report.truncated_files == []
    assert len(rows) == len(read_residual_rows(cut)[0]) > 200  # the complete records of the cut chunk too
    np.testing.assert_array_equal(stamps(rows), np.arange(len(rows)))
    with (tmp_path / 'fixed.mcap').open('rb') as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == result.messages
    assert len(messages(tmp_path / 'fixed.mcap')) == result.messages
    with pytest.raises(RecordingError, match='exists already'):
        recover_mcap(cut, tmp_path / 'fixed.mcap')


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_a_damaged_chunk_loses_only_its_messages(tmp_path: Path, compression: str) -> None:
    folder = write_log(tmp_path / 'log', 300, chunk_size=1500, compression=compression)
    (src,) = folder.glob('*.mcap')
    before = messages(src)
    lost = damage_one_chunk(src, 2)
    result = recover_mcap(src, tmp_path / 'fixed.mcap')
    assert (result.messages, result.lost, result.damaged, result.unknown_loss) == (600 - lost, lost, 1, False)
    after = messages(tmp_path / 'fixed.mcap')
    assert len(after) == 600 - lost and set(after) <= set(before)  # the rest, unchanged
    assert after[-1] == before[-1]


def test_a_killed_residual_log_folder_gets_its_metadata(tmp_path: Path) -> None:
    folder = write_log(tmp_path / 'log', 500, chunk_size=1024, max_bytes=8 * 1024)
    (folder / 'metadata.yaml').unlink()  # as a killed logger leaves it
    files = sorted(folder.glob('*.mcap'))
    last = files[-1].read_bytes()
    files[-1].write_bytes(last[: len(last) // 2])
    result = recover(folder, tmp_path / 'out')
    assert result.kind == 'folder' and len(result.files) == len(files)
    meta = yaml.safe_load((tmp_path / 'out' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['relative_file_paths'] == [p.name for p in files] and meta['message_count'] == result.messages
    with AnyReader([tmp_path / 'out']) as reader:  # the folder as a rosbag2 bag
        assert reader.message_count == result.messages
    rows, report = read_residual_rows(tmp_path / 'out')
    assert len(rows) == len(read_residual_rows(folder)[0]) and report.truncated_files == []
    assert not list(tmp_path.glob('.out*'))  # no temporary left behind


def test_a_chamber_bag_folder_with_a_cut_file_replays_after_recovery(tmp_path: Path) -> None:
    bag = write_chamber_bag(tmp_path / 'bag', chamber())
    (mcap_file,) = bag.glob('*.mcap')
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: len(data) * 3 // 4])
    with pytest.raises(RecordingError, match='gimbal-friction recover'):
        open_chamber_bag(bag)
    result = recover(bag, tmp_path / 'fixed')
    arrays = open_chamber_bag(tmp_path / 'fixed').read_arrays()
    assert 0 < len(arrays.joint_states) < 600 and result.messages > 0


@pytest.mark.parametrize('damage', ['cut', 'corrupt'])
def test_sqlite_bags_keep_every_readable_row(tmp_path: Path, damage: str) -> None:
    bag = write_chamber_bag(tmp_path / 'bag', chamber(3000), storage='sqlite3')
    (db3,) = bag.glob('*.db3')
    original = messages(db3)
    total = len(original)
    data = bytearray(db3.read_bytes())
    if damage == 'cut':
        data = data[: len(data) * 2 // 3]
    else:
        middle = len(data) // 2
        data[middle : middle + 4096] = np.random.default_rng(1).bytes(4096)
    db3.write_bytes(bytes(data))
    result = recover(bag, tmp_path / 'fixed')
    (fixed,) = (tmp_path / 'fixed').glob('*.db3')
    kept = messages(tmp_path / 'fixed')
    assert len(kept) == result.messages and 0 < result.messages < total
    if damage == 'corrupt':  # rows after the damaged pages are read, and the loss is counted exactly
        assert result.lost == total - result.messages and not result.unknown_loss
        assert kept[-1] == original[-1] and set(kept) <= set(original)
    else:
        assert result.unknown_loss
    with sqlite3.connect(fixed) as con:
        assert con.execute('PRAGMA integrity_check').fetchone() == ('ok',)
    arrays = open_chamber_bag(tmp_path / 'fixed').read_arrays()
    assert len(arrays.joint_states) > 0


def test_a_bare_db3_and_refusals(tmp_path: Path) -> None:
    bag = write_chamber_bag(tmp_path / 'bag', chamber(50), storage='sqlite3')
    (db3,) = bag.glob('*.db3')
    result = recover(db3, tmp_path / 'copy.db3')
    assert result.kind == 'file' and result.messages == len(messages(db3)) and result.lost == 0
    assert len(open_chamber_bag(tmp_path / 'copy.db3').read_arrays().joint_states) == 50
    (tmp_path / 'zero.db3').write_bytes(b'SQLite format 3\x00' + bytes(84))
    with pytest.raises(RecordingError, match=r'cannot read the database schema|not a rosbag2 sqlite3 bag'):
        recover_db3(tmp_path / 'zero.db3', tmp_path / 'zero_out.db3')
    (tmp_path / 'notes.txt').write_text('x')
    with pytest.raises(RecordingError, match='not a bag or residual log'):
        recover(tmp_path / 'notes.txt', tmp_path / 'o1')
    (tmp_path / 'nothing').mkdir()
    with pytest.raises(RecordingError, match=r'holds no .mcap or .db3 file'):
        recover(tmp_path / 'nothing', tmp_path / 'o2')
    with pytest.raises(RecordingError, match='no such file'):
        recover(tmp_path / 'missing', tmp_path / 'o3')
    with pytest.raises(RecordingError, match='exists already'):
        recover(db3, tmp_path / 'bag')
    assert not any((tmp_path / name).exists() for name in ('o1', 'o2', 'zero_out.db3'))
