"""``gimbal-friction model`` and ``report`` through their main(): formats, layering, one-line refusals."""

from __future__ import annotations

import csv
import io
import json
import subprocess
import sys

import pytest

from gimbal_friction.cli.main import main
from gimbal_friction.config.loader import render_parameter_file
from gimbal_friction.physics.model import CONTRACT_FIELDS


def test_model_json_has_contract_fields(capsys):
    assert main(['model', '--temperature', '-40,0,60', '--format', 'json']) == 0
    out = capsys.readouterr().out
    rows = json.loads(out)
    assert [r['temperature_c'] for r in rows] == [-40.0, 0.0, 60.0]
    assert set(CONTRACT_FIELDS) <= set(rows[0])
    assert rows[0]['m_total_nmm'] == pytest.approx(3.14, rel=0.01)
    assert rows[0]['m_viscous_nmm'] == pytest.approx(2.30, rel=0.005)


def test_model_range_spec_stop_inclusive_and_csv(capsys):
    assert main(['model', '-t', '-40:60:20', '--format', 'csv']) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [float(r['temperature_c']) for r in rows] == [-40, -20, 0, 20, 40, 60]
    assert list(rows[0]) == list(CONTRACT_FIELDS)


def test_model_table_default_is_fig11_table(capsys):
    assert main(['model']) == 0
    out = capsys.readouterr().out
    assert 'M [N*mm]' in out and 'loose' in out
    assert len([line for line in out.splitlines() if line.strip().startswith(('-', '0', '1', '2', '3', '4',
                                                                              '5', '6'))]) >= 11


def test_overrides_and_config_layering(tmp_path, capsys):
    main(['model', '-t', '60', '--format', 'json'])
    base = json.loads(capsys.readouterr().out)[0]
    assert main(['model', '-t', '60', '--format', 'json', '--interference-mm', '0.008']) == 0
    over = json.loads(capsys.readouterr().out)[0]
    assert over['axial_force_n'] < base['axial_force_n']  # Fig. 8: more interference, less force when hot
    cfg = tmp_path / 'lub.yaml'
    cfg.write_text(render_parameter_file({'walther_a': 8.7}))
    assert main(['model', '-t', '0', '--format', 'json', '--config', str(cfg)]) == 0
    layered = json.loads(capsys.readouterr().out)[0]
    assert layered['viscosity_cst'] > 338.0 * 1.2
    assert main(['model', '-t', '0', '--format', 'json', '--speed-rpm', '60']) == 0
    fast = json.loads(capsys.readouterr().out)[0]
    assert fast['m_viscous_nmm'] > 1.5


@pytest.mark.slow
def test_plot_written(tmp_path, capsys):
    png = tmp_path / 'fig11.png'
    assert main(['model', '--plot', str(png), '--format', 'json']) == 0
    json.loads(capsys.readouterr().out)  # stdout stays pure JSON
    assert png.stat().st_size > 10000 and png.read_bytes()[:4] == b'\x89PNG'
    assert main(['model', '--plot', str(png)]) == 1  # the one rule of every command's outputs
    assert 'already exists; nothing written' in capsys.readouterr().err
    assert main(['model', '--plot', str(png), '--force']) == 0


@pytest.mark.parametrize(('argv', 'needle', 'code'), [
    (['model', '--temperature', 'cold'], 'start:stop:step', 1),
    (['model', '-t', '60:-40:10'], 'stop >= start', 1),
    (['model', '--gasket-mm', '-0.1'], 'gasket_thickness_mm', 1),
    (['model', '--axis', 'azimuth'], "'azimuth' is not configured", 1),
    (['model', '--format', 'xml'], 'invalid choice', 2),
    (['model', '--config', '/nonexistent.yaml'], 'cannot read', 1),
    # issue 31 item 3: outside the model's validity range (30,695,377 N*mm at -100 degC before)
    (['model', '-t', '200,-100'], "--temperature 200 degC lies outside the model's validity range -40..60 degC", 1),
    (['model', '-t', '-100'], "--temperature -100 degC lies outside the model's validity range", 1),
    (['model', '-t', '-60:60:20'], '--temperature -60 degC', 1),
    (['model', '--gasket-mm', '0', '-t', '30'], 'validity range -40..20 degC for these parameters: the bearing pair '
     'has no axial preload', 1),
])
def test_bad_input_one_line_reason(capsys, argv, needle, code):
    with pytest.raises(SystemExit) if code == 2 else _nullcontext() as exc:
        rc = main(argv)
    if code == 2:
        assert exc.value.code == 2
    else:
        assert rc == code
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1, err


class _nullcontext:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


@pytest.mark.slow
def test_report_writes_every_figure(tmp_path, capsys):
    assert main(['report', '--out', str(tmp_path), '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    names = sorted(p.rsplit('/', 1)[-1] for p in doc['figures'])
    assert names == ['fig05_free_contact_angle.png', 'fig07_axial_force_gasket.png',
                     'fig08_axial_force_interference.png', 'fig09_torque_gasket.png',
                     'fig10_torque_interference.png', 'fig11_components.png']
    assert all((tmp_path / n).stat().st_size > 10000 for n in names)


@pytest.mark.slow
def test_console_script_runs_and_help(tmp_path):
    exe = [sys.executable, '-m', 'gimbal_friction.cli.main']
    out = subprocess.run(exe + ['--help'], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and 'model' in out.stdout and 'report' in out.stdout
    out = subprocess.run(exe + ['model', '-t', '-40', '--format', 'json'], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and json.loads(out.stdout)[0]['temperature_c'] == -40.0


def test_report_refuses_logs_without_the_axis_naming_the_joints_and_draws_nothing(tmp_path, capsys):
    import numpy as np

    from gimbal_friction.recording.bag_write import make_float64_multi_array
    from gimbal_friction.recording.residual_log import ResidualLogWriter
    from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL_DETAIL
    t0 = 1_700_000_000_000_000_000
    log = tmp_path / 'other'
    with ResidualLogWriter(log) as writer:
        for i in range(50):
            row = np.full(12, 1.0)
            row[1] = 20.0
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, t0 + i, make_float64_multi_array(row, 'joint_2'))
    out = tmp_path / 'rep'
    assert main(['report', '--residuals', str(log), '--out', str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(log) in err and "axis 'elevation'" in err and 'joint_2' in err
    assert not out.exists()  # refused before drawing anything


@pytest.mark.slow
def test_report_refuses_to_overwrite_figures_unless_force(tmp_path, capsys):
    assert main(['report', '--out', str(tmp_path)]) == 0
    before = (tmp_path / 'fig11_components.png').stat().st_mtime_ns
    capsys.readouterr()
    assert main(['report', '--out', str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert 'already exists; nothing written' in err and '--force' in err
    assert (tmp_path / 'fig11_components.png').stat().st_mtime_ns == before
    assert main(['report', '--out', str(tmp_path), '--force']) == 0


def _plateau_log(folder, plateaus):
    """A residual log with, per (temperature [degC], predicted torque per direction [N*m]), 60 s of samples at
    that temperature (1 Hz, alternating direction), measured = the prediction."""
    import numpy as np

    from gimbal_friction.recording.bag_write import make_float64_multi_array
    from gimbal_friction.recording.residual_log import ResidualLogWriter
    from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL_DETAIL
    from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS
    t = 1_700_000_000.0
    with ResidualLogWriter(folder) as writer:
        for temperature, predicted_nm in plateaus:
            for i in range(60):
                sign = 1.0 if i % 2 == 0 else -1.0
                row = dict.fromkeys(RESIDUAL_FIELDS, 0.0)
                row.update(stamp_s=t, temperature_c=temperature, velocity_rad_s=sign * 0.0349066,
                           measured_nm=sign * predicted_nm, predicted_nm=sign * predicted_nm, current_a=0.05,
                           torque_constant_nm_per_a=0.05)
                writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, int(t * 1e9),
                             make_float64_multi_array(np.array([row[f] for f in RESIDUAL_FIELDS]), 'elevation'))
                t += 1.0
            t += 600.0


@pytest.mark.slow
def test_report_table_says_what_its_model_columns_are_and_where_the_feedforward_was_off(tmp_path, capsys):
    """The Fig. 13 table says what 'model' is (the feedforward as published and logged) beside the model at the
    plateau's temperature, and names the plateaus where the two differ: a live feedforward that used a stale
    temperature (here: at -40 degC the torque of +20 degC, what the fallback gives). It used to print one 'model'
    column and nothing else, so a degraded live run looked like a different model."""
    from gimbal_friction.config.loader import axis_params, load_parameters
    from gimbal_friction.physics.model import friction_torque
    params = axis_params(load_parameters(), 'elevation')
    at_20 = float(friction_torque(params, 20.0).m_total_nmm) * 1e-3   # [N*m], the direction factor is 1 here
    log = tmp_path / 'log'
    _plateau_log(log, [(-40.0, at_20), (20.0, at_20)])
    assert main(['report', '--residuals', str(log), '--out', str(tmp_path / 'rep'), '--format', 'json']) == 0
    fig13 = {(r['temperature_c'], r['direction']): r for r in json.loads(capsys.readouterr().out)['fig13']}
    m40 = fig13[(-40.0, 'cw')]
    assert m40['predicted_nmm'] == pytest.approx(at_20 * 1e3)
    assert m40['model_at_t_nmm'] == pytest.approx(float(friction_torque(params, -40.0).m_total_nmm), rel=0.2)
    assert fig13[(20.0, 'ccw')]['model_at_t_nmm'] == pytest.approx(-at_20 * 1e3, rel=1e-6)
    assert main(['report', '--residuals', str(log), '--out', str(tmp_path / 'rep'), '--force']) == 0
    lines = capsys.readouterr().out.splitlines()
    header = next(k for k, line in enumerate(lines) if 'model at t [N*mm]' in line)  # the table's header
    assert lines[header - 2].startswith('model:       the feedforward paired with each sample in the residual log')
    assert lines[header - 1] == "model at t:  the configured model at the plateau's temperature"
    note = next(line for line in lines if line.startswith('note: the feedforward as published differs'))
    assert '-40.0 degC cw' in note and '-40.0 degC ccw' in note and '20.0 degC' not in note


def test_the_validity_range_is_in_the_help_and_the_table(capsys):
    with pytest.raises(SystemExit):
        main(['model', '--help'])
    text = ' '.join(capsys.readouterr().out.split())
    assert "the model's validity range, -40..60 degC" in text and 'within -40..60 degC (others are refused)' in text
    assert main(['model', '-t', '-40,60']) == 0
    assert "the model's validity range: -40..60 degC" in capsys.readouterr().out
