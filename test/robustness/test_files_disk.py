"""A full or read-only file system: one line and a non-zero exit, nothing half-written left under the asked-for
name, and what reached the disk recoverable."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from gimbal_friction.recording.cdr import make_float64_multi_array
from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.residual_read import read_residual_rows
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL_DETAIL

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / 'bags' / 'chamber_sample'
T0 = 1_700_000_000_000_000_000  # [ns]
FULL = (errno.ENOSPC, errno.EFBIG)


def test_replay_onto_a_full_disk_then_recover_what_reached_it(tmp_path: Path, full_disk, rb) -> None:
    disk = full_disk(512 * 1024)
    out = disk.folder / 'out'
    line = rb.refused(rb.run('replay', str(SAMPLE), '--out', str(out), preexec=disk.preexec), 'replay')
    assert ('No space left on device' if disk.kind == 'tmpfs' else 'File too large') in line
    assert str(out / 'residuals') in line
    rows, report = read_residual_rows(out / 'residuals')  # the flushed chunks read back as they are
    assert len(rows) > 0 and report.truncated_files
    fixed = rb.run('recover', str(out / 'residuals'), '--out', str(tmp_path / 'fixed'))
    assert fixed.code == 0, fixed.err
    assert len(read_residual_rows(tmp_path / 'fixed')[0]) == len(rows)


def test_recover_onto_a_full_disk_leaves_nothing_behind(tmp_path: Path, full_disk, rb) -> None:
    disk = full_disk(256 * 1024)
    target = disk.folder / 'fixed'
    line = rb.refused(rb.run('recover', str(SAMPLE), '--out', str(target), preexec=disk.preexec), 'recover')
    assert 'writing' in line
    assert not target.exists() and not [p for p in disk.folder.iterdir() if p.name.startswith('.fixed')]


def test_report_onto_a_full_disk_leaves_no_partial_figure(full_disk, rb) -> None:
    disk = full_disk(64 * 1024)
    rep = disk.folder / 'rep'
    line = rb.refused(rb.run('report', '--out', str(rep), preexec=disk.preexec), 'report')
    assert 'cannot write' in line
    left = list(rep.iterdir()) if rep.exists() else []
    assert not [p for p in left if not p.name.endswith('.png')], left  # no temporary file left behind
    for png in left:  # every figure that is there is whole (a PNG ends with its IEND chunk)
        assert png.read_bytes().endswith(b'IEND\xaeB`\x82'), png


@pytest.mark.slow
@pytest.mark.parametrize('command', ['replay', 'recover', 'report', 'refit'])
def test_read_only_outputs_are_one_line(tmp_path: Path, read_only_dir: Path, command: str, rb) -> None:
    out = read_only_dir / 'out'
    if command == 'replay':
        args = ['replay', str(SAMPLE), '--out', str(out)]
    elif command == 'recover':
        args = ['recover', str(SAMPLE), '--out', str(out)]
    elif command == 'report':
        args = ['report', '--out', str(out)]
    else:
        log = tmp_path / 'log'
        assert rb.run('replay', str(SAMPLE), '--out', str(log), '--no-inputs').code == 0
        args = ['refit', str(log / 'residuals'), '--out', str(out / 'refit.yaml')]
    line = rb.refused(rb.run(*args), command)
    assert str(read_only_dir) in line
    assert any(x in line for x in ('Read-only file system', 'Not a directory', 'is not a folder')), line


def test_the_writer_on_a_full_disk_keeps_what_it_flushed(tmp_path: Path, full_disk) -> None:
    disk = full_disk(96 * 1024)
    if disk.preexec is not None:  # no tmpfs here: the same through a stream that fails once the limit is reached
        limit = 96 * 1024

        class Limited:
            def __init__(self, path: Path) -> None:
                self.inner = path.open('xb')

            def write(self, data: bytes) -> int:
                if self.inner.tell() + len(data) > limit:
                    raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
                return self.inner.write(data)

            def __getattr__(self, name: str) -> object:
                return getattr(self.inner, name)

        opener = Limited
    else:
        opener = None
    folder = disk.folder / 'log'
    writer = ResidualLogWriter(folder, chunk_size=2048, flush_interval_s=None, opener=opener)  # type: ignore[arg-type]
    flushed = 0
    with pytest.raises(RecordingError) as caught:
        for i in range(100_000):
            row = np.full(12, float(i))
            row[-1] = 0
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, T0 + i, make_float64_multi_array(row, 'elevation'))
            if i % 50 == 49:
                writer.flush()
                flushed = writer.stats.flushed_messages
    assert '\n' not in str(caught.value) and caught.value.__cause__.errno in FULL  # type: ignore[union-attr]
    writer.close()  # no footer, no metadata.yaml, no second error
    rows, report = read_residual_rows(folder)
    assert len(rows) >= flushed > 0 and report.truncated_files
    np.testing.assert_array_equal(rows.stamp_s, np.arange(len(rows)))
