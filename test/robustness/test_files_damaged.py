"""Files cut short, corrupted or empty: one line and a non-zero exit where nothing can be done, every readable
record kept where something can (``gimbal-friction recover``), and never a traceback."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.highlevel import AnyReader

from gimbal_friction.recording.cdr import make_float64_multi_array
from gimbal_friction.recording.mcap_scan import McapScanner
from gimbal_friction.recording.recover import recover_mcap
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.residual_read import read_residual_rows
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL_DETAIL

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / 'bags' / 'chamber_sample'
T0 = 1_700_000_000_000_000_000  # [ns]


def residual_log(folder: Path, n: int = 600, **kwargs: object) -> Path:
    with ResidualLogWriter(folder, **kwargs) as writer:  # type: ignore[arg-type]
        for i in range(n):
            row = np.full(12, float(i))
            row[-1] = 0.0
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, T0 + i, make_float64_multi_array(row, 'elevation'))
    return folder


def chunks_of(path: Path) -> list[tuple[int, int, int]]:
    """(start, end, messages) of every chunk record of a complete file, with its message indexes."""
    data = path.read_bytes()
    out = []
    pos = 8
    while data[pos] != 0x0F:
        length = int.from_bytes(data[pos + 1 : pos + 9], 'little')
        end = pos + 9 + length
        if data[pos] == 0x06:
            out.append([pos, end, 0])
        elif data[pos] == 0x07:
            out[-1][1] = end  # the chunk's message indexes belong to it
            out[-1][2] += int.from_bytes(data[pos + 11 : pos + 15], 'little') // 16
        pos = end
    return [tuple(x) for x in out]  # type: ignore[misc]


@pytest.fixture(scope='module')
def log_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, list[tuple[int, int, int]]]:
    folder = residual_log(tmp_path_factory.mktemp('log') / 'log', 400, chunk_size=1200)
    (path,) = folder.glob('*.mcap')
    return path.read_bytes(), chunks_of(path)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_corruption_never_raises_and_keeps_every_intact_chunk(
    tmp_path: Path, log_file: tuple[bytes, list[tuple[int, int, int]]], data: st.DataObject
) -> None:
    raw, chunks = log_file
    first_end = chunks[0][1]  # the first chunk defines the channel: damage after it
    damaged = bytearray(raw)
    hits = []
    for _ in range(data.draw(st.integers(1, 4), label='corruptions')):
        at = data.draw(st.integers(first_end, len(raw) - 1), label='at')
        size = data.draw(st.integers(1, 24), label='size')
        damaged[at : at + size] = data.draw(st.binary(min_size=size, max_size=size), label='bytes')
        hits.append((at, at + size))
    cut = data.draw(st.one_of(st.none(), st.integers(first_end, len(raw))), label='cut')
    if cut is not None:
        damaged = damaged[:cut]
    src = tmp_path / f'src_{abs(hash(bytes(damaged))) % 10**9}.mcap'
    src.write_bytes(bytes(damaged))
    dst = src.with_name(src.stem + '_fixed.mcap')
    result = recover_mcap(src, dst)  # never raises on a file that starts like MCAP
    untouched = [all(e <= a or s >= b for s, e in hits) and (cut is None or b <= cut) for a, b, _ in chunks]
    intact = sum(n for (_, _, n), ok in zip(chunks, untouched, strict=True) if ok)
    assert result.messages >= intact
    with AnyReader([dst]) as reader:
        assert reader.message_count == result.messages
    rows, _ = read_residual_rows(dst)
    values = np.asarray(rows.stamp_s)
    assert set(values.astype(int).tolist()) <= set(range(400))  # nothing invented
    assert len(np.unique(values)) == len(values)
    src.unlink()
    dst.unlink()


@pytest.mark.parametrize('usize', [1 << 63, (1 << 64) - 1, (1 << 32) + 1])
def test_a_chunk_claiming_an_absurd_uncompressed_size_is_lost_alone(
    tmp_path: Path, log_file: tuple[bytes, list[tuple[int, int, int]]], usize: int
) -> None:
    """Found by the random corruption above (explore profile): 0x80 in the top byte of a chunk's uncompressed size
    made the decompressor raise OverflowError out of recover."""
    raw, chunks = log_file
    start, _, lost = chunks[1]
    damaged = bytearray(raw)
    damaged[start + 25 : start + 33] = usize.to_bytes(8, 'little')  # opcode, length, start/end time, then the size
    src = tmp_path / 'src.mcap'
    src.write_bytes(bytes(damaged))
    result = recover_mcap(src, tmp_path / 'fixed.mcap')
    assert result.messages == sum(n for _, _, n in chunks) - lost


def test_recover_cli_on_a_killed_log_folder_and_what_it_prints(tmp_path: Path, rb) -> None:
    folder = residual_log(tmp_path / 'log', 800, chunk_size=1024, max_bytes=6000)
    (folder / 'metadata.yaml').unlink()
    files = sorted(folder.glob('*.mcap'))
    last = files[-1].read_bytes()
    files[-1].write_bytes(last[: len(last) // 2])  # killed mid-chunk
    (folder / 'residuals_99.mcap').write_bytes(b'')  # killed right after rotating
    run = rb.run('recover', str(folder), '--out', str(tmp_path / 'fixed'))
    assert run.code == 0, run.err
    kept = len(read_residual_rows(folder)[0])
    assert f'kept {kept} messages' in run.out and 'lost' in run.out
    assert 'residuals_99.mcap' in run.out and 'no MCAP record' in run.out  # the empty file, skipped
    assert len(read_residual_rows(tmp_path / 'fixed')[0]) == kept
    with AnyReader([tmp_path / 'fixed']) as reader:
        assert reader.message_count == kept
    doc = json.loads(rb.run('recover', str(folder), '--out', str(tmp_path / 'again'), '--format', 'json').out)
    assert doc['kept'] == kept and doc['kind'] == 'folder' and len(doc['files']) == len(files)


def test_a_damaged_chunk_in_a_residual_log_costs_only_that_chunk(tmp_path: Path, rb) -> None:
    folder = residual_log(tmp_path / 'log', 600, chunk_size=1500)
    (path,) = folder.glob('*.mcap')
    a, b, n = chunks_of(path)[2]
    data = bytearray(path.read_bytes())
    data[(a + b) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    rows, report = read_residual_rows(folder)
    assert len(rows) == 600 - n and report.bad_chunks == 1 and report.lost_messages == n
    assert int(rows.stamp_s[-1]) == 599  # the chunks after the damage are used (refit, report, fleet)
    run = rb.run('report', '--residuals', str(folder), '--out', str(tmp_path / 'rep'))
    note, *rest = run.err.strip().splitlines()
    assert note == (f'note: residual logs: {600 - n} residual rows read from 1 file; not read: 1 damaged chunks '
                    f'skipped ({n} messages lost)')
    # the damage is a note, not a refusal: these rows (a temperature ramp) hold no plateau, and that is what is said
    assert run.code == 1 and len(rest) == 1 and 'no temperature plateau' in rest[0], run.err


@pytest.mark.slow
@pytest.mark.parametrize('damage', ['cut', 'corrupt', 'empty'])
def test_replay_of_a_damaged_bag_is_one_line_pointing_to_recover(tmp_path: Path, damage: str, rb) -> None:
    bag = tmp_path / 'bag'
    shutil.copytree(SAMPLE, bag)
    (mcap_file,) = bag.glob('*.mcap')
    data = bytearray(mcap_file.read_bytes())
    if damage == 'cut':
        data = data[: len(data) // 2]
    elif damage == 'corrupt':  # bytes inside a zstd chunk: was a 47-line ZstdError traceback
        a, b, _ = chunks_of(mcap_file)[2]
        middle = (a + b) // 2
        data[middle : middle + 64] = bytes(64)
    else:
        data = bytearray()
    mcap_file.write_bytes(bytes(data))
    line = rb.refused(rb.run('replay', str(bag), '--out', str(tmp_path / 'out')), 'replay')
    assert f'gimbal-friction recover {bag} --out' in line
    assert not (tmp_path / 'out' / 'residuals').exists() or not any((tmp_path / 'out' / 'residuals').iterdir())
    fixed = rb.run('recover', str(bag), '--out', str(tmp_path / 'fixed'))
    if damage == 'empty':
        line = rb.refused(fixed, 'recover')
        assert 'nothing could be read' in line
    else:
        assert fixed.code == 0, fixed.err
        run = rb.run('replay', str(tmp_path / 'fixed'), '--out', str(tmp_path / 'out2'), '--format', 'json')
        assert run.code == 0, run.err
        assert json.loads(run.out)['messages_in'] > 1000


def test_recover_refusals_are_one_line(tmp_path: Path, rb) -> None:
    (tmp_path / 'junk.mcap').write_bytes(b'PK\x03\x04' * 100)
    assert 'not an MCAP file' in rb.refused(rb.run('recover', str(tmp_path / 'junk.mcap'), '--out',
                                                        str(tmp_path / 'o.mcap')), 'recover')
    assert 'no such file' in rb.refused(rb.run('recover', str(tmp_path / 'nope'), '--out',
                                                    str(tmp_path / 'o')), 'recover')
    (tmp_path / 'empty.mcap').write_bytes(b'')
    assert 'no MCAP record' in rb.refused(rb.run('recover', str(tmp_path / 'empty.mcap'), '--out',
                                                      str(tmp_path / 'o2.mcap')), 'recover')
    assert 'exists already' in rb.refused(rb.run('recover', str(SAMPLE), '--out', str(tmp_path)), 'recover')
    (tmp_path / 'bad.db3').write_bytes(b'SQLite format 3\x00' + bytes(200))
    rb.refused(rb.run('recover', str(tmp_path / 'bad.db3'), '--out', str(tmp_path / 'o.db3')), 'recover')
    assert not (tmp_path / 'o.mcap').exists() and not (tmp_path / 'o.db3').exists()


def test_scanner_on_the_sample_bag_agrees_with_its_statistics() -> None:
    (path,) = SAMPLE.glob('*.mcap')
    scan = McapScanner(path)
    assert sum(len(b) for b in scan.blocks()) == scan.report.expected_messages > 60000
