"""``gimbal-friction export`` through main(): files per axis, JSON summary, refit layering, one-line refusals,
nothing overwritten silently."""

from __future__ import annotations

import hashlib
import json

import pytest
import yaml

from gimbal_friction.cli.main import main
from gimbal_friction.config.loader import load_parameters, render_parameter_file
from gimbal_friction.export.formats import ROS_NODE

FAST = ['--relative-error', '1e-3', '--random-points', '500']


def _one_line_error(capsys, needle):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith('gimbal-friction export') and needle in lines[0], lines[0]


@pytest.fixture
def two_axes(tmp_path):
    cfg = tmp_path / 'two_axes.yaml'
    cfg.write_text(render_parameter_file(None, {'azimuth': {'interference_mm': 0.004, 'scale_negative': 0.9}},
                                         axes=['elevation', 'azimuth']))
    return cfg


def test_export_writes_three_files_per_axis_and_a_json_summary(tmp_path, two_axes, capsys):
    out = tmp_path / 'table'
    assert main(['export', '--out', str(out), '--config', str(two_axes), '--format', 'json', *FAST]) == 0
    doc = json.loads(capsys.readouterr().out)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(f'gimbal_friction_{a}.{ext}' for a in ('elevation', 'azimuth')
                           for ext in ('csv', 'h', 'yaml'))
    assert [a['axis'] for a in doc['axes']] == ['elevation', 'azimuth']
    digest = hashlib.sha256(two_axes.read_bytes()).hexdigest()
    assert doc['sources'][0]['file'] == 'packaged defaults'
    assert doc['sources'][1] == {'file': str(two_axes), 'sha256': digest}
    for axis in doc['axes']:
        r = axis['report']
        assert r['relative_error_bound'] == 1e-3
        assert r['midpoint_max_relative_error'] <= 1e-3 and r['random_max_relative_error'] <= 1e-3
        assert r['temperatures'] > 10 and axis['temperature_range_c'] == [-40.0, 60.0]
        for path in axis['files'].values():
            text = (out / path.split('/')[-1]).read_text()
            assert digest in text and 'requested 0.001' in text
    az = doc['axes'][1]
    assert az['feedforward']['scale_negative'] == 0.9
    csv_text = (out / 'gimbal_friction_azimuth.csv').read_text()
    assert 'interference_mm = 0.004 [mm]' in csv_text
    header_row = next(line for line in csv_text.splitlines() if not line.startswith('#'))
    assert {'temperature_c', 'speed_rpm', 'm_total_nmm', 'm_total_nm'} <= set(header_row.split(','))
    assert '#define GF_AZIMUTH_SCALE_NEGATIVE 0.9' in (out / 'gimbal_friction_azimuth.h').read_text()
    loaded = load_parameters([out / 'gimbal_friction_azimuth.yaml'], node_name=ROS_NODE)
    assert loaded['azimuth']['joint'] == 'azimuth'
    # the two axes differ (interference changes the contact torques when hot)
    el = yaml.safe_load((out / 'gimbal_friction_elevation.yaml').read_text())
    assert el[ROS_NODE]['ros__parameters']['elevation']['torque_lower_nm'] != \
        loaded['azimuth']['torque_lower_nm']


def test_axis_option_and_human_output(tmp_path, two_axes, capsys):
    out = tmp_path / 'az'
    assert main(['export', '--out', str(out), '--config', str(two_axes), '--axis', 'azimuth',
                 '--temperature-min-c', '-30', '--temperature-max-c', '50', '--max-speed-rad-s', '2', *FAST]) == 0
    text = capsys.readouterr().out
    assert 'breakpoints' in text and 'azimuth' in text and 'gimbal_friction_azimuth.h' in text
    assert sorted(p.name for p in out.iterdir()) == ['gimbal_friction_azimuth.csv', 'gimbal_friction_azimuth.h',
                                                     'gimbal_friction_azimuth.yaml']
    e = yaml.safe_load((out / 'gimbal_friction_azimuth.yaml').read_text())[ROS_NODE]['ros__parameters']['azimuth']
    assert e['temperatures_c'][0] == -30.0 and e['temperatures_c'][-1] == 50.0 and e['max_speed_rad_s'] == 2.0


def test_temperature_range_defaults_to_the_feedforward_nodes(tmp_path, capsys):
    """The node's table range: its credible range within the model's validity range (issue 31 item 3)."""
    cfg = tmp_path / 'ff.yaml'
    cfg.write_text(yaml.safe_dump({'friction_feedforward': {'ros__parameters': {'temperature_min_c': -45.0,
                                                                                 'temperature_max_c': 50.0,
                                                                                 'max_torque_nm': 0.01}}}))
    out = tmp_path / 'x'
    assert main(['export', '--out', str(out), '--config', str(cfg), '--format', 'json', *FAST]) == 0
    axis = json.loads(capsys.readouterr().out)['axes'][0]
    assert axis['temperature_range_c'] == [-40.0, 50.0] and axis['validity_range_c'] == [-40.0, 60.0]
    assert axis['feedforward']['max_torque_nm'] == 0.01
    assert '#define GF_ELEVATION_MAX_TORQUE_NM 0.01' in (out / 'gimbal_friction_elevation.h').read_text()


def test_a_refits_parameter_file_gives_a_new_table(tmp_path, capsys):
    refit = tmp_path / 'refit.yaml'
    refit.write_text(render_parameter_file({'walther_a': 8.70, 'walther_b': -21.40}, header='refit'))
    a, b = tmp_path / 'before', tmp_path / 'after'
    assert main(['export', '--out', str(a), *FAST]) == 0
    assert main(['export', '--out', str(b), '--config', str(refit), *FAST]) == 0
    capsys.readouterr()

    def params(d):
        return yaml.safe_load((d / 'gimbal_friction_elevation.yaml').read_text())[ROS_NODE]['ros__parameters'][
            'elevation']

    assert params(a)['ln_switch_speed'] != params(b)['ln_switch_speed']
    assert params(a)['torque_upper_nm'] != params(b)['torque_upper_nm']
    text = (b / 'gimbal_friction_elevation.csv').read_text()
    assert 'walther_a = 8.7' in text and hashlib.sha256(refit.read_bytes()).hexdigest() in text


def test_nothing_overwritten_silently(tmp_path, capsys):
    out = tmp_path / 'table'
    assert main(['export', '--out', str(out), *FAST]) == 0
    capsys.readouterr()
    before = {p.name: p.read_text() for p in out.iterdir()}
    assert main(['export', '--out', str(out), *FAST]) == 1
    _one_line_error(capsys, 'not empty; nothing written (use --force')
    assert {p.name: p.read_text() for p in out.iterdir()} == before
    # --force replaces an earlier export (new date/parameters), and only that
    assert main(['export', '--out', str(out), '--force', '--relative-error', '2e-3', '--random-points', '500']) == 0
    capsys.readouterr()
    assert 'requested 0.002' in (out / 'gimbal_friction_elevation.csv').read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['table']     # no temporary left behind
    foreign = tmp_path / 'notes'
    foreign.mkdir()
    (foreign / 'mine.txt').write_text('keep me')
    assert main(['export', '--out', str(foreign), '--force', *FAST]) == 1
    _one_line_error(capsys, "not an export directory (holds 'mine.txt')")
    assert (foreign / 'mine.txt').read_text() == 'keep me'
    a_file = tmp_path / 'file.txt'
    a_file.write_text('x')
    assert main(['export', '--out', str(a_file), '--force', *FAST]) == 1
    _one_line_error(capsys, 'exists and is not a directory')
    assert a_file.read_text() == 'x'
    empty = tmp_path / 'empty'
    empty.mkdir()
    assert main(['export', '--out', str(empty), *FAST]) == 0    # an empty directory is used
    assert len(list(empty.iterdir())) == 3


@pytest.mark.parametrize(('args', 'needle'), [
    (['--relative-error', '0'], "'--relative-error' = 0.0: must lie in [1e-10, 0.1]"),
    (['--relative-error=-1e-4'], "'--relative-error'"),
    (['--relative-error', 'nan'], "'--relative-error' = nan: must be a finite number"),
    (['--max-speed-rad-s', '0'], "'--max-speed-rad-s'"),
    (['--temperature-min-c', '50', '--temperature-max-c', '40'], "'--temperature-max-c'"),
    (['--temperature-min-c', '-300'], "'--temperature-min-c'"),
    # issue 31 item 3: a table never reaches past the model's validity range
    (['--temperature-max-c', '80'], "'--temperature-max-c' = 80.0: must be <= 60 [degC]: the model's validity range"),
    (['--temperature-min-c', '-60'], "'--temperature-min-c' = -60.0: must be >= -40 [degC]"),
    (['--random-points', '3'], "'--random-points'"),
    (['--axis', 'roll'], "axis 'roll' is not configured (configured: elevation)"),
    (['--relative-error', '1e-10'], 'temperature breakpoints'),
    (['--config', '/nonexistent/params.yaml'], 'parameter file /nonexistent/params.yaml: cannot read'),
])
def test_bad_input_refused_with_one_line(tmp_path, capsys, args, needle):
    out = tmp_path / 'never'
    assert main(['export', '--out', str(out), *args]) == 1
    _one_line_error(capsys, needle)
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_bad_arguments_and_help(capsys):
    assert main_exit(['export']) == 2          # --out is required
    assert 'the following arguments are required: --out' in capsys.readouterr().err
    assert main_exit(['export', '--help']) == 0
    text = capsys.readouterr().out
    for option in ('--out', '--config', '--axis', '--relative-error', '--max-speed-rad-s', '--force', '--format'):
        assert option in text
    assert "within the model's validity range -40..60 degC" in ' '.join(text.split())


def main_exit(argv):
    with pytest.raises(SystemExit) as info:
        main(argv)
    return info.value.code


def test_correction_option_carries_it_into_every_file_and_refuses_a_mismatched_one(tmp_path, two_axes, capsys):
    from gimbal_friction.config.loader import all_axis_params
    from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, load, model_identity, save

    axes = all_axis_params(load_parameters([two_axes]))
    c = Correction(CorrectionSettings(prior_samples=1.0, guard_min_samples=0, guard_z=0.0), model_identity(axes))
    for v in (0.03, -0.03):   # 0.2 N*mm more friction than the model, both ways
        c.learn_residuals('azimuth', [-40.0] * 9, [v] * 9, [0.0] * 9, [2e-4 * (1 if v > 0 else -1)] * 9,
                          [3e-3 * (1 if v > 0 else -1)] * 9)
    c.settle()
    path = tmp_path / 'unit.correction.yaml'
    save(c, path)
    out = tmp_path / 'table'
    assert main(['export', '--out', str(out), '--config', str(two_axes), '--correction', str(path),
                 '--format', 'json', *FAST]) == 0
    doc = json.loads(capsys.readouterr().out)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    by_axis = {a['axis']: a['correction'] for a in doc['axes']}
    az = by_axis['azimuth']
    assert az['samples'] == 18 and az['cells'] == 2 and az['cells_applied'] == 2 and digest in az['source']
    assert az['speed_octaves'] == 12 and az['temperature_bins'] == 37 and az['min_speed_rad_s'] == 0.005
    assert 1e-4 < az['max_abs_nm'] < 2e-4 and az['left_out']['ripple_periods_rad'] == []
    left_out = az['left_out']['trend_max_nm'] > 0.0   # (a trend fitted over the one angle seen: the files say so)
    assert by_axis['elevation']['samples'] == 0 and by_axis['elevation']['max_abs_nm'] == 0.0
    for ext in ('csv', 'h', 'yaml'):
        text = (out / f'gimbal_friction_azimuth.{ext}').read_text()
        assert digest in text and 'Learned correction:' in text and ('Not exported' in text) == left_out
    header = (out / 'gimbal_friction_azimuth.h').read_text()
    assert 'gf_azimuth_correction_split_nm' in header and '* (model + odd) + even;' in header
    # the ROS tables are the lookup's of the correction read back from the file (no position)
    lut = load(path, expected=model_identity(axes)).lookups['azimuth']
    e = load_parameters([out / 'gimbal_friction_azimuth.yaml'], node_name=ROS_NODE)['azimuth']
    assert e['correction_odd_nm'] == lut.odd.ravel().tolist() and e['correction_even_nm'] == lut.even.ravel().tolist()
    assert e['correction_shape'] == [37, 12] and sum(e['correction_cw_samples']) == 9
    row = (-40.0 - e['correction_temperatures_c'][0]) * e['correction_inv_bin_per_c']
    assert max(e['correction_odd_nm'][int(round(row)) * 12:][:12]) == pytest.approx(2e-4 * 9 / 10, rel=0.2)
    # an axis the correction applies nothing to: its feedforward is the model's
    assert '* (model + odd) + even;' not in (out / 'gimbal_friction_elevation.h').read_text()
    # learned against other parameters (the packaged single axis): refused with one line, nothing written
    assert main(['export', '--out', str(tmp_path / 'refused'), '--correction', str(path), *FAST]) == 1
    _one_line_error(capsys, 'use the configuration it was learned with')
    assert not (tmp_path / 'refused').exists()
    # a damaged file: refused with one line, nothing written
    damaged = tmp_path / 'damaged.correction.yaml'
    damaged.write_text(path.read_text().replace('samples_total', 'samples_t0tal'))
    assert main(['export', '--out', str(tmp_path / 'refused'), '--config', str(two_axes), '--correction',
                 str(damaged), *FAST]) == 1
    _one_line_error(capsys, f'correction file {damaged}')
    assert not (tmp_path / 'refused').exists()
