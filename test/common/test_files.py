"""The one atomic replace of a file or folder written in steps (gimbal_friction.common.files.staged)."""

import pytest

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.common.files import staged, write_bytes_atomic
from gimbal_friction.recording.errors import RecordingError


def test_a_staged_folder_appears_whole_and_leaves_no_temporary(tmp_path):
    out = tmp_path / 'export'
    with staged(out, folder=True, what='export') as folder:
        (folder / 'a.csv').write_text('1\n')
        assert not out.exists()            # nothing at the target until the block ends
    assert (out / 'a.csv').read_text() == '1\n'
    assert [p.name for p in tmp_path.iterdir()] == ['export']


def test_replace_swaps_the_old_folder_out_only_on_success(tmp_path):
    out = tmp_path / 'bag'
    out.mkdir()
    (out / 'old').write_text('old')
    with pytest.raises(ValueError), staged(out, folder=True, replace=True) as folder:
        (folder / 'new').write_text('new')
        raise ValueError('the writer failed')
    assert [p.name for p in out.iterdir()] == ['old']   # a failed write keeps the old one whole
    with staged(out, folder=True, replace=True) as folder:
        (folder / 'new').write_text('new')
    assert [p.name for p in out.iterdir()] == ['new']
    assert [p.name for p in tmp_path.iterdir()] == ['bag']


def test_an_existing_target_is_refused_without_replace(tmp_path):
    out = tmp_path / 'x.db3'
    with pytest.raises(RecordingError, match='appeared while writing the recovered bag'), \
            staged(out, what='recovered bag', error=RecordingError) as path:
        path.write_text('new')
        out.write_text('someone else')
    assert out.read_text() == 'someone else'
    assert [p.name for p in tmp_path.iterdir()] == ['x.db3']


def test_write_bytes_atomic_names_the_file_and_raises_the_given_error(tmp_path):
    class MineError(GimbalFrictionError):
        pass

    with pytest.raises(MineError, match=r'^cannot write correction file .*: it is a directory$'):
        write_bytes_atomic(tmp_path, b'x', what='correction file', error=MineError)
    write_bytes_atomic(tmp_path / 'f', b'x', fsync=True)
    assert (tmp_path / 'f').read_bytes() == b'x'


# ------------------------------------------------------------------------------------------ issue 32 item 5: modes
@pytest.fixture
def umask():
    """Set the process's umask for a test (restored after)."""
    import os
    old = os.umask(0o022)
    os.umask(old)
    yield os.umask
    os.umask(old)


@pytest.mark.parametrize(('mask', 'mode'), [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_files_written_follow_the_umask_like_any_other_tools(tmp_path, umask, mask, mode):
    """An atomic write (every figure, YAML, summary.json, fleet.* and loop_study.json goes through it) gives a
    new file 0666 less the umask, as open() does (mkstemp made every output 0600); replacing a file too."""
    from gimbal_friction.common.files import write_text_atomic
    umask(mask)
    path = tmp_path / 'summary.json'
    write_text_atomic(path, '{}')
    assert path.stat().st_mode & 0o777 == mode
    path.chmod(0o600)
    write_text_atomic(path, '{"again": 1}')
    assert path.stat().st_mode & 0o777 == mode
    with staged(tmp_path / 'folder', folder=True) as folder:
        (folder / 'a.csv').write_text('1\n')
    assert (tmp_path / 'folder').stat().st_mode & 0o777 == 0o777 & ~mask
    assert sorted(p.name for p in tmp_path.iterdir()) == ['folder', 'summary.json']   # no temporary left


def test_a_commands_figure_is_readable_by_others(tmp_path, umask, capsys):
    from gimbal_friction.cli.main import main
    umask(0o022)
    png = tmp_path / 'fig11.png'
    assert main(['model', '--plot', str(png), '--format', 'json']) == 0
    assert png.stat().st_mode & 0o777 == 0o644


# ------------------------------------------------------------------------------------------ the bounded read
def test_a_bounded_read_refuses_what_is_not_a_small_regular_utf8_file(tmp_path):
    import os

    from gimbal_friction.common.files import ReadError, file_exists, read_text_bounded
    good = tmp_path / 'good.yaml'
    good.write_text('a: 1\n')
    assert read_text_bounded(good, 100) == 'a: 1\n'
    fifo = tmp_path / 'fifo'
    os.mkfifo(fifo)
    loop = tmp_path / 'loop'
    loop.symlink_to(tmp_path / 'loop2')
    (tmp_path / 'loop2').symlink_to(loop)
    (tmp_path / 'binary').write_bytes(b'a: \xff\xfe\n')
    (tmp_path / 'big').write_text('x' * 101)
    cases = {fifo: 'not_regular', '/dev/zero': 'not_regular', tmp_path: 'not_regular', loop: 'loop',
             tmp_path / 'binary': 'not_utf8', tmp_path / 'big': 'too_big', tmp_path / 'none': 'missing'}
    for path, kind in cases.items():
        with pytest.raises(ReadError) as info:
            read_text_bounded(path, 100)
        assert info.value.kind == kind and '\n' not in str(info.value), (path, info.value)
    assert file_exists(good) and not file_exists(tmp_path / 'none')
    with pytest.raises(ReadError, match='symbolic link loop'):
        file_exists(loop)
