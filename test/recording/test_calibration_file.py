"""calibrate-kt's result as data (gimbal_friction.recording.calibration): the ``gimbal_friction_calibration``
section of its parameter file, which the config loader, the nodes' command-line resolution and refit read as
each should (nodes: ignored; refit: the T_0 uncertainty, with a version check; old comment-only files: a note)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gimbal_friction.cli.main import main
from gimbal_friction.common.errors import ConfigFileError
from gimbal_friction.config.loader import (
    axis_params,
    check_config_files,
    load_parameters,
)
from gimbal_friction.config.rcl import command_line_parameters, ros_parameter_sections
from gimbal_friction.recording.calibration import (
    CALIBRATION_FORMAT_VERSION,
    CALIBRATION_SECTION,
    read_calibration,
)

DATA = Path(__file__).resolve().parent.parent / 'data' / 'kt_calibration.csv'


@pytest.fixture(scope='module')
def kt_file(tmp_path_factory):
    out = tmp_path_factory.mktemp('kt') / 'kt.yaml'
    assert main(['calibrate-kt', str(DATA), '--out', str(out), '--format', 'json']) == 0
    return out


def test_the_file_carries_the_result_as_versioned_data(kt_file, capsys):
    import yaml

    section = yaml.safe_load(kt_file.read_text())[CALIBRATION_SECTION]['ros__parameters']
    assert section['format_version'] == CALIBRATION_FORMAT_VERSION == 1
    assert section['axis'] == 'elevation'
    assert section['torque_constant_nm_per_a'] == pytest.approx(0.0523, rel=2e-3)
    assert section['no_load_current_a'] == pytest.approx(0.012, abs=1e-3)
    assert section['no_load_torque_nm'] == pytest.approx(section['torque_constant_nm_per_a']
                                                         * section['no_load_current_a'], rel=1e-9)
    assert section['samples'] == 40 and section['samples_used'] == 39   # one gross outlier rejected
    for name in ('torque_constant_se_nm_per_a', 'no_load_current_se_a', 'no_load_torque_se_nm'):
        assert 0.0 < section[name] < 1e-3
    assert 0.99 < section['r2'] <= 1.0 and isinstance(section['date'], str)
    cal = read_calibration(kt_file)
    assert cal.axis == 'elevation' and cal.note is None
    assert cal.no_load_torque_se_nm == section['no_load_torque_se_nm']


def test_the_loader_and_the_nodes_ignore_the_section(kt_file):
    check_config_files([kt_file])                      # no unknown-name refusal
    params = load_parameters([kt_file])
    assert CALIBRATION_SECTION not in params and 'format_version' not in params
    assert axis_params(params, 'elevation').torque_constant_nm_per_a == pytest.approx(0.0523, rel=2e-3)
    names = [name for name, _ in ros_parameter_sections(kt_file.read_text(), str(kt_file))]
    assert names == ['/**', CALIBRATION_SECTION]       # a parameter section for a node no one runs
    for node in ('friction_feedforward', 'friction_estimator', 'residual_logger', 'gimbal_sim'):
        got = command_line_parameters(['--ros-args', '--params-file', str(kt_file)], node)
        assert 'format_version' not in got.values and 'axis.elevation.no_load_current_a' in got.values


def test_an_unknown_format_version_is_refused_in_one_line(kt_file, tmp_path):
    newer = tmp_path / 'newer.yaml'
    newer.write_text(kt_file.read_text().replace('format_version: 1', 'format_version: 2'))
    with pytest.raises(ConfigFileError, match='format_version 2 is not supported') as err:
        read_calibration(newer)
    assert '\n' not in str(err.value)


def test_an_old_comment_only_file_still_reads_with_a_note(kt_file, tmp_path, capsys):
    text = kt_file.read_text()
    old = tmp_path / 'old.yaml'
    old.write_text(text[:text.index(CALIBRATION_SECTION)])
    cal = read_calibration(old)
    new = read_calibration(kt_file)
    assert cal.axis == 'elevation'
    assert cal.no_load_torque_se_nm == pytest.approx(new.no_load_torque_se_nm, rel=0.05)   # 2 digits in the comment
    assert cal.note is not None and 'rerun calibrate-kt' in cal.note and '\n' not in cal.note


@pytest.mark.slow
def test_refit_reads_the_section_and_notes_an_old_file(kt_file, tmp_path, capsys):
    """refit --calibration takes the T_0 uncertainty from the data section (exact), and says so for an old file."""
    logs = tmp_path / 'replay'
    assert main(['synth-bag', '--out', str(tmp_path / 'bag'), '--seed', '3', '--format', 'json']) == 0
    assert main(['replay', str(tmp_path / 'bag'), '--out', str(logs), '--format', 'json']) == 0
    capsys.readouterr()
    assert main(['refit', str(logs / 'residuals'), '--out', str(tmp_path / 'a.yaml'), '--calibration', str(kt_file),
                 '--format', 'json']) == 0
    captured = capsys.readouterr()
    rec = json.loads(captured.out)
    se = read_calibration(kt_file).no_load_torque_se_nm
    assert rec['axes']['elevation']['offset']['calibration_se_nmm'] == pytest.approx(1e3 * se, rel=1e-12)
    assert 'note' not in captured.err
    text = kt_file.read_text()
    old = tmp_path / 'old.yaml'
    old.write_text(text[:text.index(CALIBRATION_SECTION)])
    assert main(['refit', str(logs / 'residuals'), '--out', str(tmp_path / 'b.yaml'), '--calibration', str(old),
                 '--format', 'json']) == 0
    assert 'note:' in capsys.readouterr().err
