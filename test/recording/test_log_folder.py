"""The residual log's folder and file policy without a node (gimbal_friction.recording.log_folder): a run writes
beside a folder that holds a log, never into it; the rotation limits; the folder a relative output_dir names."""

from __future__ import annotations

from pathlib import Path

import pytest

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.recording.log_folder import holds_log, open_own_folder, rotation_limits, wanted_folder


def test_a_folder_holding_a_log_is_left_alone(tmp_path: Path):
    wanted = tmp_path / 'res'
    assert not holds_log(wanted)
    wanted.mkdir()
    (wanted / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    assert holds_log(wanted)
    made: list[Path] = []
    folder, writer = open_own_folder(wanted, lambda f: made.append(f) or f'writer of {f.name}', now=lambda: 86400.0)
    assert folder == tmp_path / 'res_19700102_000000' and writer == 'writer of res_19700102_000000'
    assert made == [folder]


def test_a_run_never_finds_a_free_sibling_after_too_many(tmp_path: Path):
    def taken(folder: Path) -> str:
        folder.mkdir()
        (folder / 'metadata.yaml').write_text('x')
        raise GimbalFrictionError('exists')

    with pytest.raises(GimbalFrictionError, match='99 timestamped siblings'):
        open_own_folder(tmp_path / 'res', taken, now=lambda: 0.0)


def test_rotation_limits_and_the_folder_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    assert rotation_limits(0.0, 0.0) == (None, None)
    assert rotation_limits(1.5, 60.0) == (1_500_000, 60.0)
    monkeypatch.chdir(tmp_path)
    assert wanted_folder('logs/a') == tmp_path / 'logs' / 'a'
    monkeypatch.setenv('HOME', str(tmp_path / 'home'))
    assert wanted_folder('~/r') == tmp_path / 'home' / 'r' and wanted_folder('~/r').is_absolute()
