"""``gimbal-friction refit`` through main(): residual logs in, a layerable parameter file out, refusals.

The logs are written with ResidualLogWriter on /gimbal/friction/residual_detail from a synthetic truth: the
package model with ``walther_a`` + 0.02 (ν(−40 °C) 44.7k -> 74k cSt), plateaus −40…60 °C every 20 °C, both
directions at 1/3 rpm, ±5 % position ripple and 0.1 mN*m white noise.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from gimbal_friction.cli.main import main
from gimbal_friction.common.xp import ARRAY
from gimbal_friction.config.loader import axis_params, load_parameters, render_parameter_file
from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.bag_write import make_float64_multi_array, make_temperature, write_chamber_bag
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.topics import (
    FLOAT64_MULTI_ARRAY_TYPE,
    RESIDUAL_DETAIL,
    RESIDUAL_FIELDS,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)

T0 = 1_700_000_000_000_000_000  # [ns]
SPEED_RAD_S = 2.0 * math.pi / 180.0  # 1/3 rpm
PLATEAUS = (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0)


def truth_params(shift: float = 0.02) -> AxisParams:
    base = AxisParams()
    return base.replace(walther_a=base.walther_a + shift)


def detail_rows(truth: AxisParams, plateaus=PLATEAUS, n_per: int = 120, seed: int = 0, speed_rad_s=SPEED_RAD_S):
    """RESIDUAL_FIELDS rows of the truth, predicted with the package defaults: (rows, stamps [ns])."""
    rng = np.random.default_rng(seed)
    base = AxisParams()
    rows, stamps = [], []
    k = 0
    for plateau in plateaus:
        for sign in (1.0, -1.0):
            t = plateau + rng.normal(0.0, 0.05, n_per)
            v = sign * speed_rad_s * (1.0 + rng.normal(0.0, 3e-3, n_per))
            pos = np.linspace(-0.1, 0.19, n_per)[::int(sign)]
            n_rpm = np.abs(v) * 60.0 / (2.0 * math.pi)
            true = friction_torque(truth, t, n_rpm).m_total_nmm * 1e-3
            true = true * (1.0 + 0.05 * np.sin(2.0 * np.pi * pos / math.radians(3.4)))
            measured = sign * (true + rng.normal(0.0, 1e-4, n_per))
            model = friction_torque(base, t, n_rpm)
            predicted = sign * model.m_total_nmm * 1e-3
            for i in range(n_per):
                stamp = T0 + k * 10_000_000
                k += 1
                rows.append([stamp * 1e-9, t[i], pos[i], v[i], measured[i] / 0.05, measured[i], predicted[i],
                             measured[i] - predicted[i], 0.0, 0.05, 0.0, 0.0])   # RESIDUAL_FIELDS
                stamps.append(stamp)
    return rows, stamps


def write_log(folder: Path, truth: AxisParams | None = None, joints=('elevation',), **kwargs) -> Path:
    truth = truth or truth_params()
    with ResidualLogWriter(folder) as writer:
        for j, joint in enumerate(joints):
            rows, stamps = detail_rows(truth, seed=j, **kwargs)
            for row, stamp in zip(rows, stamps, strict=True):
                assert len(row) == len(RESIDUAL_FIELDS)
                writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp + j,
                             make_float64_multi_array(row, joint))
    return folder


@pytest.fixture(scope='module')
def log_dir(tmp_path_factory) -> Path:
    return write_log(tmp_path_factory.mktemp('refit') / 'residuals')


def test_refit_writes_a_loadable_file_with_the_truth_viscosity(log_dir, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(log_dir), '--out', str(out)]) == 0
    shown = capsys.readouterr().out
    truth = truth_params()
    params = axis_params(load_parameters([out]), 'elevation')
    defaults = axis_params(load_parameters([]), 'elevation')
    assert params.walther_a != defaults.walther_a
    assert abs(params.walther_a - truth.walther_a) < 2e-3
    # only the refitted parameter changed
    assert params.replace(walther_a=defaults.walther_a) == defaults
    doc = yaml.safe_load(out.read_text())
    assert doc['/**'] == {'ros__parameters': {'axis': {'elevation': {'walther_a': params.walther_a}}}}
    # beside the parameters, as data the nodes ignore: the calibration offset fitted with them (report --compare)
    section = doc.pop('gimbal_friction_refit')['ros__parameters']
    assert set(doc) == {'/**'} and section['format_version'] == 1
    assert set(section['axis']['elevation']) == {'torque_offset_nm', 'torque_offset_se_nm', 'torque_offset_estimated',
                                                 'fitted_directions', 'model_fits', 'max_abs_z'}
    assert section['axis']['elevation']['model_fits'] is True   # the truth is of the model's form
    assert section['axis']['elevation']['fitted_directions'] == 'both'
    # the model with the refitted file reproduces the truth's viscosity where the data determine it
    nu_fit = friction_torque(params, [-40.0]).viscosity_cst[0]
    assert nu_fit == pytest.approx(float(viscosity_cst(truth, -40.0)), rel=0.03)
    m_fit = friction_torque(params, [-40.0]).m_total_nmm[0]
    assert m_fit == pytest.approx(friction_torque(truth, [-40.0]).m_total_nmm[0], rel=0.01)
    text = out.read_text()
    assert text.startswith('# gimbal-friction refit')
    assert str(log_dir.resolve()) in text and '1440 samples' in text and 'RMS residual' in text
    assert 'walther_a' in shown and 'identifiable' in shown and f'wrote {out}' in shown
    assert 'viscosity determined by the data at -40 degC only' in shown


def test_model_command_shows_the_refitted_viscosity(log_dir, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(log_dir), '--out', str(out), '--format', 'json']) == 0
    capsys.readouterr()
    assert main(['model', '--config', str(out), '--format', 'json', '-t', '-40,20']) == 0
    rec = json.loads(capsys.readouterr().out)
    truth = truth_params()
    assert rec[0]['viscosity_cst'] == pytest.approx(float(viscosity_cst(truth, -40.0)), rel=0.03)
    assert rec[0]['viscosity_cst'] > 1.5 * float(viscosity_cst(AxisParams(), -40.0))


def test_json_reports_values_intervals_identifiability_and_rms(log_dir, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(log_dir), '--out', str(out), '--format', 'json',
                 '--fit', 'walther_a,walther_b,viscosity_offset_cst']) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert f'wrote {out}' in captured.err
    rec = doc['axes']['elevation']
    truth = truth_params()
    lo, hi = rec['confidence_intervals_95']['walther_a']
    assert lo <= truth.walther_a <= hi
    assert rec['identifiability']['walther_a'] == {'identifiable': True, 'reason': ''}
    for name in ('walther_b', 'viscosity_offset_cst'):
        assert rec['identifiability'][name]['identifiable'] is False
        assert 'distinct temperature' in rec['identifiability'][name]['reason']
        assert rec['standard_errors'][name] is None
        assert rec['fitted'][name] == rec['base'][name]
    assert set(rec['written']) == {'walther_a'}
    assert rec['rms_after_nmm'] < 0.5 * rec['rms_before_nmm']
    assert rec['samples'] == 1440
    assert {(b['temperature_bin_c'], b['direction']) for b in rec['bins']} == \
        {(t, d) for t in PLATEAUS for d in ('cw', 'ccw')}
    cold = [b for b in rec['bins'] if b['temperature_bin_c'] == -40.0]
    assert all(b['viscous'] and b['rms_after_nmm'] < b['rms_before_nmm'] for b in cold)
    # walther_b and c1 were not identifiable: they are not in the file
    params = load_parameters([out], include_defaults=False)['axis']['elevation']
    assert set(params) == {'walther_a'}


def test_table_names_the_parameters_it_cannot_determine(log_dir, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(log_dir), '--out', str(out), '--fit', 'walther_a,walther_b']) == 0
    shown = capsys.readouterr().out
    assert 'walther_b: not identifiable: needs samples at 2 distinct temperatures' in shown
    assert 'NO (held)' in shown


@pytest.mark.slow
def test_second_cold_plateau_determines_two_constants(tmp_path, capsys):
    logs = write_log(tmp_path / 'log', plateaus=(-40.0, -35.0, -20.0, 0.0, 20.0, 40.0, 60.0))
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(logs), '--out', str(out), '--format', 'json', '--fit', 'walther_a,walther_b']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    assert set(rec['written']) == {'walther_a', 'walther_b'}
    params = axis_params(load_parameters([out]), 'elevation')
    np.testing.assert_allclose(viscosity_cst(params, [-40.0, -35.0]), viscosity_cst(truth_params(), [-40.0, -35.0]),
                               rtol=0.03)


@pytest.mark.slow
def test_two_axes_and_several_logs(tmp_path, capsys):
    first = write_log(tmp_path / 'a', joints=('elevation', 'azimuth'))
    second = write_log(tmp_path / 'b', joints=('azimuth',), plateaus=(-40.0, 20.0))
    cfg = tmp_path / 'two_axes.yaml'
    cfg.write_text(render_parameter_file(axes=['elevation', 'azimuth']))
    out = tmp_path / 'refit.yaml'
    plot = tmp_path / 'fig13.png'
    assert main(['refit', str(first), str(second), '--config', str(cfg), '--out', str(out), '--plot', str(plot),
                 '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc['axes']) == {'elevation', 'azimuth'}
    assert doc['axes']['azimuth']['samples'] == 1440 + 480
    merged = load_parameters([cfg, out])
    for axis in ('elevation', 'azimuth'):
        nu = friction_torque(axis_params(merged, axis), [-40.0]).viscosity_cst[0]
        assert nu == pytest.approx(float(viscosity_cst(truth_params(), -40.0)), rel=0.03)
    assert plot.stat().st_size > 10_000
    # without the two-axis config only elevation is configured: azimuth is ignored, with a note
    out2 = tmp_path / 'refit2.yaml'
    assert main(['refit', str(first), '--out', str(out2)]) == 0
    shown = capsys.readouterr().out
    assert 'joints not configured, ignored: azimuth' in shown
    assert set(load_parameters([out2], include_defaults=False)['axis']) == {'elevation'}


def test_plot_is_drawn(log_dir, tmp_path, capsys):
    out, plot = tmp_path / 'refit.yaml', tmp_path / 'fig' / 'fig13.png'
    assert main(['refit', str(log_dir), '--out', str(out), '--plot', str(plot), '--loss', 'soft_l1',
                 '--bin-width', '2']) == 0
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert f'plot: {plot}' in capsys.readouterr().out


# ---------------------------------------------------------------------------------------------- refusals
def _refused(argv: list[str], capsys, out: Path, match: str) -> str:
    assert main(argv) == 1
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith('gimbal-friction refit: error: ')
    assert match in err, err
    assert captured.out == ''
    assert not out.exists() or out.read_text() == 'keep me\n'
    return err


def test_refuses_an_empty_folder(tmp_path, capsys):
    empty = tmp_path / 'empty'
    empty.mkdir()
    out = tmp_path / 'refit.yaml'
    _refused(['refit', str(empty), '--out', str(out)], capsys, out, 'not a residual log')
    assert not out.exists()


def test_refuses_a_foreign_bag_and_keeps_an_existing_output(tmp_path, capsys):
    messages = [(TEMPERATURE, TEMPERATURE_TYPE, T0 + i, make_temperature(T0 + i, 20.0)) for i in range(5)]
    bag = write_chamber_bag(tmp_path / 'chamber', messages)
    out = tmp_path / 'refit.yaml'
    out.write_text('keep me\n')
    _refused(['refit', str(bag), '--out', str(out), '--force'], capsys, out, 'not a residual log')
    not_mcap = tmp_path / 'foreign'
    not_mcap.mkdir()
    (not_mcap / 'x.mcap').write_bytes(b'this is not mcap at all')
    _refused(['refit', str(not_mcap), '--out', str(out), '--force'], capsys, out, 'not an MCAP file')
    assert out.read_text() == 'keep me\n'


def test_an_existing_output_is_refused_unless_force(log_dir, tmp_path, capsys):
    """One rule for every command's outputs (replay refuses a folder that holds a log): nothing is overwritten
    without notice."""
    out = tmp_path / 'refit.yaml'
    out.write_text('keep me\n')
    err = _refused(['refit', str(log_dir), '--out', str(out)], capsys, out, 'already exists; nothing written')
    assert str(out) in err and '--force' in err
    plot = tmp_path / 'fig.png'
    plot.write_bytes(b'old')
    _refused(['refit', str(log_dir), '--out', str(tmp_path / 'new.yaml'), '--plot', str(plot)], capsys, out,
             '--plot')
    assert plot.read_bytes() == b'old' and not (tmp_path / 'new.yaml').exists()
    assert main(['refit', str(log_dir), '--out', str(out), '--force']) == 0
    assert 'walther_a' in yaml.safe_load(out.read_text())['/**']['ros__parameters']['axis']['elevation']


@pytest.mark.slow
def test_damaged_chunks_are_counted_in_the_output_and_the_json(tmp_path, capsys, damage_mcap_chunk):
    """Every command that skips data says how much: a damaged chunk of the log is a note and a JSON count."""
    from gimbal_friction.recording.mcap_scan import McapScanner
    folder = tmp_path / 'damaged'
    rows, stamps = detail_rows(truth_params())
    with ResidualLogWriter(folder, chunk_size=4096) as writer:
        for row, stamp in zip(rows, stamps, strict=True):
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp, make_float64_multi_array(row, 'elevation'))
    (path,) = folder.glob('*.mcap')
    damage_mcap_chunk(path, 3)  # the fourth chunk
    scan = McapScanner(path)
    sum(len(b) for b in scan.blocks())
    lost = scan.report.lost_messages
    assert lost > 0
    assert main(['refit', str(folder), '--out', str(tmp_path / 'a.yaml')]) == 0
    captured = capsys.readouterr()
    note = f'1 damaged chunks skipped ({lost} messages lost)'
    assert note in captured.err and note in captured.out.splitlines()[0]
    assert main(['refit', str(folder), '--out', str(tmp_path / 'b.yaml'), '--format', 'json']) == 0
    captured = capsys.readouterr()
    read = json.loads(captured.out)['read']
    assert (read['damaged_chunks'], read['lost_messages'], read['skipped']) == (1, lost, True)
    assert note in captured.err


def test_no_samples_in_the_asked_direction_is_refused_naming_why(tmp_path, capsys):
    folder = tmp_path / 'ccw'
    rows, stamps = detail_rows(truth_params())
    with ResidualLogWriter(folder) as writer:
        for row, stamp in zip(rows, stamps, strict=True):
            if row[3] < 0.0:  # CCW only
                writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp,
                             make_float64_multi_array(row, 'elevation'))
    out = tmp_path / 'refit.yaml'
    err = _refused(['refit', str(folder), '--out', str(out), '--direction', 'cw'], capsys, out,
                   "no usable samples of axis 'elevation'")
    assert '--direction cw' in err and str(folder) in err


def test_refuses_a_log_without_residual_samples(tmp_path, capsys):
    folder = tmp_path / 'quiet'
    with ResidualLogWriter(folder) as writer:
        writer.write(TEMPERATURE, TEMPERATURE_TYPE, T0, make_temperature(T0, 20.0))
        writer.write('/gimbal/friction/residual', 'sensor_msgs/msg/Temperature', T0, make_temperature(T0, 1.0))
    out = tmp_path / 'refit.yaml'
    _refused(['refit', str(folder), '--out', str(out)], capsys, out, 'holds no /gimbal/friction/residual_detail')


def test_refuses_too_few_samples(tmp_path, capsys):
    logs = write_log(tmp_path / 'short', plateaus=(-40.0,), n_per=8)
    out = tmp_path / 'refit.yaml'
    _refused(['refit', str(logs), '--out', str(out)], capsys, out, 'axis elevation: too few samples: 16')


def test_refuses_data_that_cannot_determine_the_viscosity(tmp_path, capsys):
    logs = write_log(tmp_path / 'warm', plateaus=(0.0, 20.0, 40.0))
    out = tmp_path / 'refit.yaml'
    _refused(['refit', str(logs), '--out', str(out)], capsys, out, "no samples in Palmgren's upper branch")


def test_refuses_bad_options(log_dir, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    _refused(['refit', str(log_dir), '--out', str(out), '--fit', 'walther_a,bogus'], capsys, out, 'unknown bogus')
    _refused(['refit', str(log_dir), '--out', str(out), '--axis', 'azimuth'], capsys, out, 'not configured')
    _refused(['refit', str(log_dir), '--out', str(tmp_path)], capsys, out, 'is a directory')


@pytest.mark.slow
def test_rows_without_a_value_or_at_standstill_are_skipped(tmp_path, capsys):
    rows, stamps = detail_rows(truth_params())
    rows[0][1] = math.nan                      # no temperature
    rows[1][5] = math.nan                      # no measurement
    rows[2][3] = 0.0                           # standstill: direction unknown
    folder = tmp_path / 'gaps'
    with ResidualLogWriter(folder) as writer:
        for row, stamp in zip(rows, stamps, strict=True):
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp, make_float64_multi_array(row, 'elevation'))
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(folder), '--out', str(out), '--format', 'json']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    assert (rec['rows'], rec['skipped_nonfinite'], rec['skipped_standstill'], rec['samples']) == (1440, 2, 1, 1437)


# ---------------------------------------------------------------------------------------------- issue 13 goals
# Full pipeline: synth-bag -> replay (estimator, residual log) -> refit, through main().

GOAL_BAG = ['--hold-s', '40', '--joint-rate-hz', '50', '--current-noise-a', '0.002']


@pytest.fixture(scope='module')
def paper_logs(tmp_path_factory) -> Path:
    """A chamber test reproducing the paper's four means (synth-bag --preset paper), replayed."""
    root = tmp_path_factory.mktemp('paper')
    assert main(['synth-bag', '--out', str(root / 'bag'), '--preset', 'paper', '--seed', '3', *GOAL_BAG,
                 '--format', 'json']) == 0
    assert main(['replay', str(root / 'bag'), '--out', str(root / 'replay'), '--format', 'json']) == 0
    return root / 'replay' / 'residuals'


@pytest.mark.slow
def test_goal_asymmetry_model_vs_paper_within_5_percent(paper_logs, tmp_path, capsys):
    from gimbal_friction.chamber.synth import PAPER_MEANS_NMM
    from gimbal_friction.physics.direction import ARRAY, direction_factor

    capsys.readouterr()
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(paper_logs), '--out', str(out), '--format', 'json',
                 '--fit', 'walther_a,palmgren_factor,direction_asymmetry']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    for name in ('walther_a', 'palmgren_factor', 'direction_asymmetry_cold', 'direction_asymmetry_warm'):
        assert rec['identifiability'][name]['identifiable'], name
        lo, hi = rec['confidence_intervals_95'][name]
        assert lo < rec['fitted'][name] < hi
    # the refitted parameter file, through the model and the direction factor (what the feedforward uses),
    # against the paper's four means at -40 and +60 degC
    params = axis_params(load_parameters([out]), 'elevation')
    for (t, d), mean in PAPER_MEANS_NMM.items():
        model = float(friction_torque(params, [t], 1 / 3).m_total_nmm[0]) * direction_factor(params, t, d, ARRAY)
        assert d * model == pytest.approx(mean, rel=0.05), (t, d)
    # and against the measured plateau groups of the same logs, both directions at both ends
    for b in rec['bins']:
        if b['temperature_bin_c'] in (-40.0, 60.0):
            assert b['model_after_nmm'] == pytest.approx(b['measured_mean_nmm'], rel=0.05), b
    # without the term, one direction is more than 5 % off at -40 degC
    assert main(['refit', str(paper_logs), '--out', str(tmp_path / 'plain.yaml'), '--format', 'json',
                 '--fit', 'walther_a,palmgren_factor']) == 0
    plain = json.loads(capsys.readouterr().out)['axes']['elevation']
    cold = [b for b in plain['bins'] if b['temperature_bin_c'] == -40.0]
    assert max(abs(b['model_after_nmm'] / b['measured_mean_nmm'] - 1.0) for b in cold) > 0.05


@pytest.fixture(scope='module')
def calibration(tmp_path_factory):
    """A calibrate-kt run (K_T 0.05, I_0 0) with its output file and the 1-sigma of I_0 [A]."""
    root = tmp_path_factory.mktemp('cal')
    rng = np.random.default_rng(11)
    current = np.concatenate([np.linspace(0.02, 0.2, 10), -np.linspace(0.02, 0.2, 10)])
    speed = np.sign(current) * 0.03
    torque = 0.05 * current + rng.normal(0.0, 2e-4, current.size)
    csv = root / 'cal.csv'
    csv.write_text('current_a,torque_nm,speed_rad_s\n' + ''.join(f'{i},{t},{s}\n' for i, t, s in
                                                                 zip(current, torque, speed, strict=True)))
    out = root / 'kt.yaml'
    assert main(['calibrate-kt', str(csv), '--out', str(out), '--format', 'json']) == 0
    return out


@pytest.fixture(scope='module')
def wrong_i0_logs(tmp_path_factory, calibration) -> tuple[Path, float]:
    """The default synthetic chamber test replayed with I_0 configured 2 calibration sigmas too high."""
    from gimbal_friction.recording.calibration import read_calibration

    root = tmp_path_factory.mktemp('i0')
    se_t0 = read_calibration(calibration).no_load_torque_se_nm
    se_i0 = se_t0 / 0.05
    cfg = root / 'wrong_i0.yaml'
    cfg.write_text(render_parameter_file({'no_load_current_a': 2.0 * se_i0, 'torque_constant_nm_per_a': 0.05}))
    assert main(['synth-bag', '--out', str(root / 'bag'), '--seed', '4', *GOAL_BAG, '--format', 'json']) == 0
    assert main(['replay', str(root / 'bag'), '--out', str(root / 'replay'), '--config', str(cfg),
                 '--format', 'json']) == 0
    return root / 'replay' / 'residuals', se_i0


@pytest.mark.slow
def test_goal_offset_keeps_the_cold_viscosity_within_5_percent(wrong_i0_logs, calibration, tmp_path, capsys):
    from gimbal_friction.chamber.synth import DEFAULT_TRUTH_OVERRIDES

    logs, se_i0 = wrong_i0_logs
    assert 0.5e-3 < se_i0 < 3e-3   # the calibration: I_0 known to 1-2 mA
    capsys.readouterr()
    truth = AxisParams().replace(**DEFAULT_TRUTH_OVERRIDES)
    nu_truth = float(viscosity_cst(truth, -40.0))
    out = tmp_path / 'refit.yaml'
    # --direction cw: the default synthetic test has a cold CCW-only asymmetry that is not the model's form
    assert main(['refit', str(logs), '--out', str(out), '--direction', 'cw', '--calibration', str(calibration),
                 '--format', 'json']) == 0
    captured = capsys.readouterr()
    rec = json.loads(captured.out)['axes']['elevation']
    off = rec['offset']
    assert off['estimated'] and off['mode'] == 'auto'
    c_true_nmm = -0.05 * 2.0 * se_i0 * 1e3
    assert off['ci95_nmm'][0] - 0.05 < c_true_nmm < off['ci95_nmm'][1] + 0.05   # plus the warm Palmgren floor
    assert off['exceeds_calibration'] is True
    assert 'warning: axis elevation: torque offset' in captured.err
    nu = float(viscosity_cst(axis_params(load_parameters([out]), 'elevation'), -40.0))
    assert nu == pytest.approx(nu_truth, rel=0.05)
    text = out.read_text()
    assert 'torque offset' in text and 'torque_offset' not in text.split('ros__parameters')[1]
    # switched off, the I_0 error leaks into the viscosity (or widens its interval until the fit is refused)
    code = main(['refit', str(logs), '--out', str(tmp_path / 'off.yaml'), '--direction', 'cw', '--offset', 'off',
                 '--format', 'json'])
    captured = capsys.readouterr()
    if code == 0:
        assert json.loads(captured.out)['axes']['elevation']['offset']['estimated'] is False
        nu_off = float(viscosity_cst(axis_params(load_parameters([tmp_path / 'off.yaml']), 'elevation'), -40.0))
        assert abs(nu_off / nu_truth - 1.0) > abs(nu / nu_truth - 1.0)
    else:
        assert 'walther_a: not identifiable: standard error' in captured.err


def test_offset_table_output_and_calibration_refusals(log_dir, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(log_dir), '--out', str(out), '--calibration-se', '1e-4']) == 0
    shown = capsys.readouterr().out
    assert 'torque offset' in shown and 'calibration T_0 1-sigma 0.1 N*mm: within it' in shown
    bad = tmp_path / 'not_kt.yaml'
    bad.write_text('# nothing\n')
    other = tmp_path / 'other.yaml'
    _refused(['refit', str(log_dir), '--out', str(other), '--calibration', str(bad)], capsys, other,
             'not a calibrate-kt output file')
    _refused(['refit', str(log_dir), '--out', str(other), '--calibration-se', '-1'], capsys, other, 'must be a finite')


# ---------------------------------------------------------------------------------------------- issue 19 item 1
# The shipped sample (truth walther_a 8.6345) replayed with the no-load current configured off by the typical
# calibrate-kt uncertainty (+/-1.7 mA = +/-0.085 N*mm on every plateau).
SAMPLE_BAG = Path(__file__).resolve().parents[2] / 'bags' / 'chamber_sample'
SAMPLE_TRUTH = SAMPLE_BAG.parent / 'chamber_sample.truth.yaml'
I0_ERROR_A = 0.0017


@pytest.fixture(scope='module')
def sample_wrong_i0(tmp_path_factory) -> dict[float, Path]:
    root = tmp_path_factory.mktemp('sample_i0')
    logs = {}
    for i0 in (I0_ERROR_A, -I0_ERROR_A):
        cfg = root / f'i0_{i0}.yaml'
        cfg.write_text(f'/**:\n  ros__parameters:\n    model:\n      no_load_current_a: {i0}\n')
        assert main(['replay', str(SAMPLE_BAG), '--out', str(root / f'run_{i0}'), '--config', str(cfg),
                     '--no-inputs', '--format', 'json']) == 0
        logs[i0] = root / f'run_{i0}' / 'residuals'
    return logs


def _cold_viscosity(argv: list[str], capsys) -> tuple[float, float, float, dict]:
    """(nu after, 95 % low, high) at the coldest viscous bin relative to the sample's truth, and the axis record."""
    capsys.readouterr()
    assert main([*argv, '--format', 'json']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    vi = min(rec['viscosity'], key=lambda v: v['temperature_c'])
    truth = axis_params(load_parameters([SAMPLE_TRUTH]), 'elevation')
    nu = float(viscosity_cst(truth, vi['temperature_c']))
    return vi['after_cst'] / nu - 1.0, vi['ci95_cst'][0] / nu - 1.0, vi['ci95_cst'][1] / nu - 1.0, rec


@pytest.mark.slow
def test_the_demo_refit_recovers_the_sample_lubricant_despite_a_calibration_error(sample_wrong_i0, tmp_path,
                                                                                 capsys):
    from gimbal_friction.cli.demo import REFIT_ARGS
    assert 'palmgren_factor' not in ','.join(REFIT_ARGS)
    for i0, log in sample_wrong_i0.items():
        rel, lo, hi, rec = _cold_viscosity(['refit', *REFIT_ARGS, str(log), '--out', str(tmp_path / f'{i0}.yaml')],
                                           capsys)
        assert abs(rel) < 0.05 and lo < 0.0 < hi, (i0, rel, lo, hi)
        assert rec['offset']['estimated']
        assert rec['offset']['value_nmm'] == pytest.approx(-1e3 * 0.05 * i0, abs=0.03)  # -K_T * dI_0


@pytest.mark.slow
def test_a_fit_set_confounded_with_the_offset_says_so_with_numbers(sample_wrong_i0, tmp_path, capsys):
    """The old demo refit (palmgren_factor switches the offset off): the calibration error goes into the viscosity,
    and the refit says which parameters are confounded and by how much a calibration offset moves them."""
    log = sample_wrong_i0[I0_ERROR_A]
    argv = ['refit', str(log), '--out', str(tmp_path / 'a.yaml'), '--direction', 'cw', '--fit',
            'walther_a,palmgren_factor']
    rel, lo, hi, rec = _cold_viscosity(argv, capsys)
    assert rel > 0.10 and not lo < 0.0 < hi  # what the issue saw: +16 %, the truth outside the interval
    conf = rec['offset_confounding']
    assert conf['checked'] and set(conf['confounded']) == {'walther_a', 'palmgren_factor'}
    assert conf['reference_offset_nmm'] == pytest.approx(0.05, rel=1e-6)  # K_T x 1 mA without a calibration
    # the linear response predicts what the 1.7 mA error did (nu from -1.4 % without the error to +16 % with it)
    predicted = math.exp(-1.7 * math.log1p(conf['viscosity_shift_percent'][0]['percent'] / 100.0)) - 1.0
    assert predicted == pytest.approx(0.17, abs=0.05)
    assert any('cannot be told apart from a calibration torque offset' in w for w in rec['warnings'])
    # the table says it too, with numbers, and never advises adding palmgren_factor
    assert main([*argv[:3], str(tmp_path / 'b.yaml'), *argv[4:], '--calibration-se', '8.5e-5']) == 0
    shown = capsys.readouterr()
    line = next(x for x in shown.out.splitlines() if 'cannot be told apart' in x)
    assert 'walther_a by' in line and 'standard errors' in line and 'the viscosity at -39.7 degC by' in line
    assert '0.085 N*mm (the calibration T_0 1-sigma)' in line and 'refit without palmgren_factor' in line
    assert 'cannot be told apart' in shown.err


@pytest.mark.slow
def test_the_offset_warning_advises_the_calibration_not_palmgren_factor(sample_wrong_i0, tmp_path, capsys):
    log = sample_wrong_i0[I0_ERROR_A]
    capsys.readouterr()
    assert main(['refit', str(log), '--out', str(tmp_path / 'a.yaml'), '--direction', 'cw',
                 '--calibration-se', '1e-5', '--format', 'json']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    (warning,) = rec['warnings']
    assert 'exceeds the calibration uncertainty' in warning and 'recalibrate' in warning
    assert 'do not add palmgren_factor' in warning and '--fit ...,palmgren_factor' not in warning
    assert not rec['offset_confounding']['checked']


# Learned correction (--correction-out): residuals against the refitted model.
@pytest.mark.slow
def test_correction_out_learns_the_residual_against_the_refitted_model(tmp_path, capsys):
    """A truth the refit of walther_a cannot reach (CCW 10 % below CW): the correction holds, per temperature bin
    and direction, the shrunk mean of measured - refitted model along the motion; the file loads with the refitted
    parameters; an existing file is refused unless --force. With the guard's defaults 120 samples a cell are too
    few to be scored out of sample: every cell holds back, and says so (the guard is set off for the rest)."""
    from gimbal_friction.controller import load_feedforward
    from gimbal_friction.feedforward.correction import CorrectionSettings, load
    from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings

    rows, stamps = detail_rows(truth_params())
    for r in rows:
        if r[3] < 0.0:
            r[5] *= 0.9   # measured_nm of CCW rows
    log = tmp_path / 'residuals'
    with ResidualLogWriter(log) as writer:
        for row, stamp in zip(rows, stamps, strict=True):
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp, make_float64_multi_array(row, 'elevation'))
    out, corr = tmp_path / 'refit.yaml', tmp_path / 'refit.correction.yaml'
    guarded = tmp_path / 'guarded.correction.yaml'
    assert main(['refit', str(log), '--out', str(tmp_path / 'g.yaml'), '--correction-out', str(guarded),
                 '--format', 'json']) == 0
    capsys.readouterr()
    held = load(guarded).cells('elevation')
    assert len(held) == 12 and not any(r['applied'] for r in held)
    assert all('scored by' in r['held_back'] for r in held)
    guard_off = tmp_path / 'guard_off.yaml'
    guard_off.write_text('friction_feedforward:\n  ros__parameters:\n    correction_guard_min_samples: 0\n'
                         '    correction_guard_z: 0.0\n    correction_trend: false\n'
                         '    correction_ripple_periods_max: 0\n')   # (one level per cell)
    assert main(['refit', str(log), '--config', str(guard_off), '--out', str(out), '--correction-out', str(corr),
                 '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    c = load(corr)
    refitted = Feedforward({'elevation': axis_params(load_parameters([out]), 'elevation')}, FeedforwardSettings())
    a = np.asarray(rows)
    t, v, measured = a[:, 1], a[:, 3], a[:, 5]
    residual_along = np.sign(v) * measured - refitted.model_nm('elevation', v, t, ARRAY)
    n0 = CorrectionSettings().prior_samples
    cells = {(r['direction'], r['centre_c']): r for r in c.cells('elevation')}
    assert len(cells) == 12 and len(doc['correction']['cells']) == 12
    for plateau in PLATEAUS:
        for sign, direction in ((1.0, 'cw'), (-1.0, 'ccw')):
            k = (np.sign(v) == sign) & (np.abs(t - plateau) < 1.0)
            cell = cells[(direction, plateau)]
            assert cell['samples'] == int(k.sum()) == 120
            # the part along the motion and the part independent of it are each shrunk like n0 samples: with
            # as many samples each way, a direction's level is its sum over n + n0 / 2
            assert cell['value_nm'] == pytest.approx(residual_along[k].sum() / (k.sum() + n0 / 2), rel=1e-3,
                                                     abs=1e-8)
            assert cell['std_error_nm'] == pytest.approx(residual_along[k].std(ddof=1) / math.sqrt(120), rel=1e-6)
    # CCW measured 10 % low: the correction's CCW cells lie below its CW cells at every plateau
    assert all(cells[('cw', p)]['value_nm'] > cells[('ccw', p)]['value_nm'] for p in PLATEAUS)
    rec = {(r['direction'], r['temperature_c']): r for r in doc['correction']['cells']}
    assert rec[('ccw', -40.0)]['value_nmm'] == pytest.approx(1e3 * cells[('ccw', -40.0)]['value_nm'])
    assert rec[('ccw', -40.0)]['temperature_bin_c'] == [-42.5, -37.5] and doc['correction']['out'] == str(corr)
    # the node / in-process API accept it with the refitted parameters (same model identity) ...
    ff = load_feedforward(out, correction=corr)
    ff.update_temperature(-40.0, 0.0)
    plain = load_feedforward(out)
    plain.update_temperature(-40.0, 0.0)
    assert ff.torque_nm('elevation', -SPEED_RAD_S, 0.0) > plain.torque_nm('elevation', -SPEED_RAD_S, 0.0)  # |.| less
    # ... the text output prints the cells; an existing correction is refused unless --force
    before = corr.read_bytes()
    assert main(['refit', str(log), '--out', str(tmp_path / 'again.yaml'), '--correction-out', str(corr)]) == 1
    assert 'already exists' in capsys.readouterr().err and corr.read_bytes() == before
    assert not (tmp_path / 'again.yaml').exists()
    assert main(['refit', str(log), '--config', str(guard_off), '--out', str(out), '--correction-out', str(corr),
                 '--force']) == 0
    shown = capsys.readouterr().out
    assert 'learned correction' in shown and '-42.5..-37.5' in shown and f'wrote {corr}' in shown
    assert load(corr).cells('elevation') == c.cells('elevation')


# ---------------------------------------------------------------------------------------------- issue 31 items 1, 2, 5
# The README tour: replay the shipped sample, refit it. Its truth (walther_a 8.6345) has a cold asymmetry that
# lowers CCW alone, which the model's direction term (one direction up, the other down by the same fraction)
# cannot describe: a both-direction refit must say that its model does not fit, name the bins, not call its
# interval a confidence interval, and say what to try; --direction cw fits and covers the truth.
SAMPLE_WALTHER_A = 8.6345


@pytest.fixture(scope='module')
def sample_log(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp('tour')
    assert main(['replay', str(SAMPLE_BAG), '--out', str(root / 'unit7'), '--format', 'json']) == 0
    return root / 'unit7'


def test_tour_refit_of_both_directions_says_its_model_does_not_fit(sample_log, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / 'refit.yaml'
    assert main(['refit', str(sample_log / 'residuals'), '--out', str(out), '--format', 'json']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    check = rec['fit_check']
    assert check['checked'] and not check['fits'] and not rec['intervals_are_confidence_intervals']
    bad = {(b['temperature_bin_c'], b['direction']) for b in check['bins_not_fitting']}
    assert {(-40.0, 'cw'), (-20.0, 'ccw')} <= bad
    for b in check['bins_not_fitting']:   # named with numbers: residual, standard error (batch means), z
        assert abs(b['z']) > check['z_critical']
        assert b['z'] == pytest.approx(b['residual_nmm'] / b['standard_error_nmm'])
        assert b['standard_error_nmm'] > 0.0
    lo, hi = rec['confidence_intervals_95']['walther_a']
    assert not lo <= SAMPLE_WALTHER_A <= hi    # the biased fit: which is why it must not be called a CI
    assert any('--direction cw' in tip for tip in check['advice'])
    tried = {a['options']: a for a in rec['alternatives']}
    cw = tried['--direction cw']
    assert cw['fits'] is True
    lo, hi = cw['confidence_intervals_95']['walther_a']
    assert lo <= SAMPLE_WALTHER_A <= hi
    assert tried['--direction ccw']['fits'] is False
    # the file says so in its header and its section
    text = out.read_text()
    assert 'NOT a 95% CI' in text and '; 95% CI [' not in text and '(95% CI [' not in text
    section = yaml.safe_load(text)['gimbal_friction_refit']['ros__parameters']['axis']['elevation']
    assert section['model_fits'] is False and section['bins_not_fitting']
    # and the human table
    assert main(['refit', str(sample_log / 'residuals'), '--out', str(tmp_path / 'b.yaml')]) == 0
    shown = capsys.readouterr().out
    assert 'interval (NOT a 95% CI: the model does not fit)' in shown
    assert 'fit check: the model does NOT fit' in shown and '-20.3' in shown
    assert '--direction cw: fits every bin' in shown


def test_tour_refit_of_cw_fits_covers_the_truth_and_says_it_is_not_for_ccw(sample_log, tmp_path, capsys):
    from gimbal_friction.cli.demo import REFIT_ARGS
    from gimbal_friction.refit.records import read_refit_validity, validity_text
    capsys.readouterr()
    out = tmp_path / 'refit.yaml'
    assert main(['refit', *REFIT_ARGS, str(sample_log / 'residuals'), '--out', str(out), '--format', 'json']) == 0
    rec = json.loads(capsys.readouterr().out)['axes']['elevation']
    assert rec['direction'] == 'cw' and rec['fit_check']['fits'] and rec['intervals_are_confidence_intervals']
    lo, hi = rec['confidence_intervals_95']['walther_a']
    assert lo <= SAMPLE_WALTHER_A <= hi
    held = rec['held_out_direction']
    assert held['checked'] and not held['fits']
    assert {b['direction'] for b in held['bins_not_fitting']} == {'ccw'}
    assert 'NOT for CCW' in rec['good_for']
    # the file (which the demo prints and report reads) says what it is good for
    validity = read_refit_validity(out)['elevation']
    assert validity['fitted_directions'] == 'cw' and validity['other_direction_fits'] is False
    assert 'good for CW motion; NOT for CCW' in validity_text(validity)
    assert 'good for: CW motion only' in out.read_text()
    # report --compare marks the CCW refit model as not fitted, in the table and the figure's legend
    figs = tmp_path / 'figs'
    assert main(['report', '--residuals', str(sample_log / 'residuals'), '--compare', str(out), '--out',
                 str(figs)]) == 0
    shown = capsys.readouterr().out
    assert 'NOT for CCW' in shown and '*: CCW, which the compared refit was not fitted on' in shown
    ccw_rows = [line for line in shown.splitlines() if line.startswith('elevation') and ' ccw ' in line]
    assert ccw_rows and all('*' in line for line in ccw_rows)


def _truncated_log(folder: Path) -> tuple[Path, int]:
    rows, stamps = detail_rows(truth_params())
    with ResidualLogWriter(folder, chunk_size=4096) as writer:
        for row, stamp in zip(rows, stamps, strict=True):
            writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp, make_float64_multi_array(row, 'elevation'))
    (path,) = folder.glob('*.mcap')
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * 0.6)])    # killed mid-write: no footer, the last chunk cut
    return path, len(rows)


def test_a_truncated_log_says_what_was_read_and_used(tmp_path, capsys):
    path, written = _truncated_log(tmp_path / 'cut')
    assert main(['refit', str(path.parent), '--out', str(tmp_path / 'a.yaml'), '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = doc['read']['rows']
    assert 0 < rows < written and doc['axes']['elevation']['rows'] == rows
    assert main(['refit', str(path.parent), '--out', str(tmp_path / 'b.yaml')]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert f'{rows} residual rows read from 1 file' in first
    assert f'not read: the end of 1 file cut short, after its last complete chunk ({path.name})' in first
    assert f'the fit below uses the {rows} rows read' in first


def test_a_replay_folder_is_refused_naming_its_residual_log(sample_log, tmp_path, capsys):
    out = tmp_path / 'refit.yaml'
    err = _refused(['refit', str(sample_log), '--out', str(out)], capsys, out, 'not a residual log')
    assert f'it holds the residual log {sample_log / "residuals"}: give that folder' in err
