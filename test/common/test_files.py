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
