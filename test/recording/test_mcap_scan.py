"""The tolerant MCAP scanner: the same messages as mcap's reader on good files, every readable one on bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapWriter

from gimbal_friction.recording.errors import RecordingError
from gimbal_friction.recording.mcap_scan import McapScanner


def write_mcap(path: Path, n: int = 500, **kwargs: object) -> list[tuple[int, int, bytes]]:
    """n messages on three channels (one defined late); returns (channel topic index, log time, data)."""
    rng = np.random.default_rng(n)
    out = []
    with path.open('wb') as stream:
        writer = McapWriter(stream, **kwargs)  # type: ignore[arg-type]
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channels = [writer.register_channel(f'/t{k}', 'cdr', schema, {'k': str(k)}) for k in range(2)]
        for i in range(n):
            if i == n // 2:
                channels.append(writer.register_channel('/late', 'cdr', schema))
            k = int(rng.integers(len(channels)))
            data = bytes(rng.integers(0, 256, size=int(rng.integers(0, 60)), dtype=np.uint8))
            writer.add_message(channels[k], 1000 + i, data, 2000 + i, i)
            out.append((k, 1000 + i, data))
        writer.finish()
    return out


def scanned(path: Path) -> tuple[list[tuple[int, int, bytes]], McapScanner]:
    scan = McapScanner(path)
    got = []
    for block in scan.blocks():
        for k in range(len(block)):
            topic = scan.channels[int(block.channel_id[k])].topic
            index = 2 if topic == '/late' else int(topic[2:])
            got.append((index, int(block.log_time[k]), block.data(k)))
            assert int(block.publish_time[k]) == int(block.log_time[k]) + 1000
            assert int(block.sequence[k]) == int(block.log_time[k]) - 1000
    return got, scan


@pytest.mark.parametrize('kwargs', [
    {'chunk_size': 1024, 'compression': CompressionType.ZSTD},
    {'chunk_size': 700, 'compression': CompressionType.LZ4},
    {'chunk_size': 2000, 'compression': CompressionType.NONE},
    {'chunk_size': 1024, 'index_types': IndexType.NONE},  # no message indexes: every chunk walked
    {'use_chunking': False},  # messages outside chunks
])
def test_good_files_read_like_the_mcap_reader(tmp_path: Path, kwargs: dict[str, object]) -> None:
    path = tmp_path / 'x.mcap'
    expected = write_mcap(path, **kwargs)
    got, scan = scanned(path)
    assert got == expected
    with path.open('rb') as stream:
        assert [m.data for _, _, m in make_reader(stream).iter_messages(log_time_order=False)] == \
            [d for _, _, d in expected]
    report = scan.report
    assert report.complete and not report.truncated and report.problems == []
    assert report.expected_messages == len(expected) and report.profile == 'ros2'
    assert {c.topic: c.metadata for c in scan.channels.values()}['/t1'] == {'k': '1'}


def test_every_cut_gives_a_prefix(tmp_path: Path) -> None:
    path = tmp_path / 'x.mcap'
    expected = write_mcap(path, chunk_size=800, compression=CompressionType.NONE)
    data = path.read_bytes()
    previous = -1
    for cut in range(0, len(data), max(1, len(data) // 97)):
        (tmp_path / 'cut.mcap').write_bytes(data[:cut])
        got, scan = scanned(tmp_path / 'cut.mcap')
        assert got == expected[: len(got)]
        assert len(got) >= previous  # uncompressed: a cut chunk gives its complete messages
        previous = len(got)
        assert scan.report.truncated


def test_a_damaged_length_resynchronises_on_the_next_chunk(tmp_path: Path) -> None:
    path = tmp_path / 'x.mcap'
    expected = write_mcap(path, chunk_size=1024)
    data = bytearray(path.read_bytes())
    pos, chunks = 8, []
    while pos < len(data) and data[pos] != 0x0F:
        length = int.from_bytes(data[pos + 1 : pos + 9], 'little')
        if data[pos] == 0x06:
            chunks.append(pos)
        pos += 9 + length
    second = chunks[1]
    data[second + 1 : second + 9] = (10**12).to_bytes(8, 'little')  # a length past the end of the file
    path.write_bytes(bytes(data))
    got, scan = scanned(path)
    assert 0 < len(got) < len(expected)
    assert got[0] == expected[0] and got[-1] == expected[-1]  # chunks after the damage are read
    assert scan.report.unknown_loss and scan.report.skipped_bytes > 0
    assert set(got) <= set(expected)


def test_short_empty_and_foreign_files(tmp_path: Path) -> None:
    for size, data in ((0, b''), (5, b'\x89MCAP')):
        (tmp_path / f'{size}.mcap').write_bytes(data)
        got, scan = scanned(tmp_path / f'{size}.mcap')
        assert got == [] and scan.report.truncated
    (tmp_path / 'junk.mcap').write_bytes(b'PK\x03\x04 not mcap')
    with pytest.raises(RecordingError, match='not an MCAP file'):
        scanned(tmp_path / 'junk.mcap')
    with pytest.raises(RecordingError, match='cannot open'):
        scanned(tmp_path / 'missing.mcap')
