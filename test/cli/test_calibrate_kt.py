"""``gimbal-friction calibrate-kt`` through main(): parameter file, JSON/table output, plot, bag input, refusals.

``test/data/kt_calibration.csv`` was generated with K_T = 0.0523 N*m/A, I_0 = 0.012 A, 20 points per direction
(currents ±0.05…1.0 A, speed ±0.0349 rad/s = 1/3 rpm), torque noise 0.1 mN*m (numpy seed 2017) and one gross
outlier of +10 mN*m on data row 17 (file line 18).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gimbal_friction.cli.main import main
from gimbal_friction.config.loader import axis_params, load_parameters, render_parameter_file
from gimbal_friction.estimation.kt import fit_kt

DATA = Path(__file__).resolve().parent.parent / 'data' / 'kt_calibration.csv'
K_T_TRUE, I_0_TRUE = 0.0523, 0.012


def write_csv(path: Path, rows, header='current_a,torque_nm') -> Path:
    path.write_text(header + '\n' + ''.join(','.join(str(v) for v in r) + '\n' for r in rows))
    return path


@pytest.fixture
def synthetic_csv(tmp_path):
    rng = np.random.default_rng(3)
    current = rng.uniform(0.05, 1.0, 200)
    torque = K_T_TRUE * (current - I_0_TRUE) + rng.normal(0.0, 2e-4, 200)
    bad = rng.choice(200, 10, replace=False)
    torque[bad] += rng.choice([-1.0, 1.0], 10) * rng.uniform(5e-3, 2e-2, 10)
    path = write_csv(tmp_path / 'cal.csv', zip(current.tolist(), torque.tolist()))
    return path, current, torque, bad


def test_writes_loadable_layerable_parameter_file(synthetic_csv, tmp_path, capsys):
    path, current, torque, bad = synthetic_csv
    out = tmp_path / 'kt.yaml'
    assert main(['calibrate-kt', str(path), '--axis', 'elevation', '--out', str(out)]) == 0
    fit = fit_kt(current, torque)
    cfg = load_parameters([out])
    params = axis_params(cfg, 'elevation')
    assert params.torque_constant_nm_per_a == fit.K_T
    assert params.no_load_current_a == fit.I_0
    assert abs(fit.K_T - K_T_TRUE) < 4 * fit.se_K_T
    # layerable: everything else stays at the packaged defaults
    defaults = axis_params(load_parameters([]), 'elevation')
    assert params.replace(torque_constant_nm_per_a=defaults.torque_constant_nm_per_a,
                          no_load_current_a=defaults.no_load_current_a) == defaults
    text = out.read_text()
    assert text.startswith('# gimbal-friction calibrate-kt')
    assert str(path.resolve()) in text and 'points: 200' in text and '+/-' in text
    shown = capsys.readouterr().out
    assert 'K_T' in shown and 'I_0' in shown and 'R^2' in shown and f'wrote {out}' in shown
    assert '10 outlier(s) rejected' in shown


def test_output_is_usable_with_config_by_other_commands(synthetic_csv, tmp_path, capsys):
    path, *_ = synthetic_csv
    out = tmp_path / 'kt.yaml'
    assert main(['calibrate-kt', str(path), '--out', str(out)]) == 0
    capsys.readouterr()
    assert main(['model', '--config', str(out), '-t', '20', '--format', 'json']) == 0
    assert json.loads(capsys.readouterr().out)[0]['temperature_c'] == 20.0


def test_json_is_one_document_with_fit_quality(synthetic_csv, tmp_path, capsys):
    path, current, torque, bad = synthetic_csv
    out = tmp_path / 'kt.yaml'
    assert main(['calibrate-kt', str(path), '--out', str(out), '--format', 'json']) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    fit = fit_kt(current, torque)
    assert doc['axis'] == 'elevation'
    assert doc['torque_constant_nm_per_a'] == pytest.approx(fit.K_T, rel=1e-12)
    assert doc['torque_constant_se_nm_per_a'] == pytest.approx(fit.se_K_T, rel=1e-12)
    assert doc['no_load_current_a'] == pytest.approx(fit.I_0, rel=1e-12)
    for key in ('no_load_current_se_a', 'no_load_torque_nm', 'no_load_torque_se_nm', 'r2', 'residual_std_nm',
                'n', 'n_outliers', 'outlier_rows'):
        assert key in doc
    assert doc['n'] == 200 and doc['n_outliers'] >= 10
    assert set((bad + 2).tolist()) <= set(doc['outlier_rows'])  # CSV line numbers (header is line 1)
    assert 'wrote' in captured.err


@pytest.mark.slow
def test_shipped_example_with_speed_and_plot(tmp_path, capsys):
    out, png = tmp_path / 'kt.yaml', tmp_path / 'fig' / 'kt.png'
    assert main(['calibrate-kt', str(DATA), '--out', str(out), '--plot', str(png), '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['n'] == 40 and doc['direction'] == 'speed_rad_s'
    assert doc['outlier_rows'] == [18]
    assert abs(doc['torque_constant_nm_per_a'] - K_T_TRUE) < 4 * doc['torque_constant_se_nm_per_a']
    assert abs(doc['no_load_current_a'] - I_0_TRUE) < 4 * doc['no_load_current_se_a']
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_second_configured_axis(synthetic_csv, tmp_path, capsys):
    path, current, torque, _ = synthetic_csv
    cfg = tmp_path / 'two_axes.yaml'
    cfg.write_text(render_parameter_file(axes=['elevation', 'azimuth']))
    out = tmp_path / 'kt_az.yaml'
    assert main(['calibrate-kt', str(path), '--config', str(cfg), '--axis', 'azimuth', '--out', str(out)]) == 0
    merged = load_parameters([cfg, out])
    assert axis_params(merged, 'azimuth').torque_constant_nm_per_a == fit_kt(current, torque).K_T
    assert axis_params(merged, 'elevation').torque_constant_nm_per_a == \
        axis_params(load_parameters([]), 'elevation').torque_constant_nm_per_a


# ------------------------------------------------------------------------------------------------ refusals
GOOD = [(0.1, 0.0046), (0.2, 0.0098), (0.3, 0.0151), (0.4, 0.0203), (0.5, 0.0256)]


@pytest.mark.parametrize(('header', 'rows', 'reason'), [
    ('current_a,torque', GOOD, "missing column 'torque_nm' (header: current_a, torque)"),
    ('amps,torque_nm', GOOD, "missing column 'current_a'"),
    ('current_a,torque_nm', GOOD[:2] + [(0.3, 'abc')] + GOOD[3:], "row 3 (line 4), column 'torque_nm': 'abc' "
     'is not a number'),
    ('current_a,torque_nm', GOOD[:2], 'too few points: 2'),
    ('current_a,torque_nm', [(0.0, t) for _, t in GOOD], 'all-zero current'),
    ('current_a,torque_nm', GOOD[:1] + [(0.2, 'nan')] + GOOD[2:], "non-finite values in column 'torque_nm'"),
    ('current_a,torque_nm', [(i, -t) for i, t in GOOD], 'is not positive'),
    ('current_a,torque_nm', [(0.3, t) for _, t in GOOD], 'all currents equal'),
    ('current_a,torque_nm,speed_rad_s', [(i, t, 'inf') for i, t in GOOD],
     "non-finite values in column 'speed_rad_s'"),
])
def test_refusals_are_one_line_and_keep_existing_output(tmp_path, capsys, header, rows, reason):
    path = write_csv(tmp_path / 'bad.csv', rows, header)
    out = tmp_path / 'kt.yaml'
    out.write_text('# previous calibration\n')
    assert main(['calibrate-kt', str(path), '--out', str(out), '--force']) == 1
    err = capsys.readouterr().err
    assert err.startswith('gimbal-friction calibrate-kt: error: ')
    assert reason in err
    assert err.count('\n') == 1
    assert out.read_text() == '# previous calibration\n'  # nothing lost
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bad.csv', 'kt.yaml']  # no temp file left


def test_an_existing_output_is_refused_unless_force(synthetic_csv, tmp_path, capsys):
    path, *_ = synthetic_csv
    out = tmp_path / 'kt.yaml'
    out.write_text('# previous calibration\n')
    assert main(['calibrate-kt', str(path), '--out', str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'already exists; nothing written' in err and '--force' in err
    assert out.read_text() == '# previous calibration\n'
    assert main(['calibrate-kt', str(path), '--out', str(out), '--force']) == 0
    assert out.read_text().startswith('# gimbal-friction calibrate-kt')


def test_refused_fit_creates_no_file(tmp_path, capsys):
    path = write_csv(tmp_path / 'bad.csv', GOOD[:2])
    out = tmp_path / 'new' / 'kt.yaml'
    assert main(['calibrate-kt', str(path), '--out', str(out)]) == 1
    assert not out.exists()


def test_unconfigured_axis_and_missing_input(tmp_path, capsys):
    path = write_csv(tmp_path / 'ok.csv', GOOD)
    assert main(['calibrate-kt', str(path), '--axis', 'roll', '--out', str(tmp_path / 'kt.yaml')]) == 1
    assert "axis 'roll' is not configured" in capsys.readouterr().err
    assert main(['calibrate-kt', str(tmp_path / 'nope.csv'), '--out', str(tmp_path / 'kt.yaml')]) == 1
    assert 'no such file' in capsys.readouterr().err
    assert not (tmp_path / 'kt.yaml').exists()


def test_out_is_required_and_help_works(capsys):
    with pytest.raises(SystemExit) as info:
        main(['calibrate-kt', str(DATA)])
    assert info.value.code == 2
    assert '--out' in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(['calibrate-kt', '--help'])
    assert info.value.code == 0
    assert 'K_T' in capsys.readouterr().out


# ------------------------------------------------------------------------------------------------ bag input
def _write_bag(path: Path, *, torque_type: str = 'std_msgs/msg/Float64', with_torque: bool = True):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.LATEST)
    JointState = ts.types['sensor_msgs/msg/JointState']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']
    Float64 = ts.types['std_msgs/msg/Float64']
    rng = np.random.default_rng(5)
    current = np.concatenate([np.linspace(0.1, 1.0, 15), -np.linspace(0.1, 1.0, 15)])
    speed = np.where(current > 0, 0.0349, -0.0349)
    torque = K_T_TRUE * (current - np.sign(speed) * I_0_TRUE) + rng.normal(0.0, 1e-4, current.size)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        c_conn = writer.add_connection('/gimbal/calibration/current', 'sensor_msgs/msg/JointState', typestore=ts)
        t_conn = writer.add_connection('/gimbal/calibration/torque', torque_type, typestore=ts) \
            if with_torque else None
        for k, (i, w, tq) in enumerate(zip(current, speed, torque)):
            t_ns = 1_000_000_000 + k * 100_000_000
            stamp = Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id='')
            msg = JointState(header=stamp, name=['elevation'], position=np.array([0.0]),
                             velocity=np.array([w]), effort=np.array([i]))
            writer.write(c_conn, t_ns, ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))
            if t_conn is not None:
                if torque_type == 'std_msgs/msg/Float64':
                    tmsg = Float64(data=float(tq))
                else:
                    tmsg = JointState(header=stamp, name=['elevation'], position=np.array([0.0]),
                                      velocity=np.array([w]), effort=np.array([tq]))
                writer.write(t_conn, t_ns + 2_000_000, ts.serialize_cdr(tmsg, torque_type))
    return current, torque, speed


@pytest.mark.parametrize('torque_type', ['std_msgs/msg/Float64', 'sensor_msgs/msg/JointState'])
def test_bag_input_pairs_by_nearest_stamp(tmp_path, capsys, torque_type):
    bag = tmp_path / 'cal_bag'
    current, torque, speed = _write_bag(bag, torque_type=torque_type)
    out = tmp_path / 'kt.yaml'
    assert main(['calibrate-kt', str(bag), '--out', str(out), '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    fit = fit_kt(current, torque, speed)
    assert doc['input_kind'] == 'bag' and doc['n'] == 30 and doc['direction'] == 'speed_rad_s'
    assert doc['torque_constant_nm_per_a'] == pytest.approx(fit.K_T, rel=1e-12)
    assert axis_params(load_parameters([out]), 'elevation').no_load_current_a == pytest.approx(fit.I_0, rel=1e-12)
    # a bare .mcap file inside the bag is accepted too
    (mcap,) = bag.glob('*.mcap')
    assert main(['calibrate-kt', str(mcap), '--out', str(tmp_path / 'kt2.yaml'), '--format', 'json']) == 0
    assert json.loads(capsys.readouterr().out)['n'] == 30


def test_bag_without_torque_topic_is_refused(tmp_path, capsys):
    bag = tmp_path / 'cal_bag'
    _write_bag(bag, with_torque=False)
    assert main(['calibrate-kt', str(bag), '--out', str(tmp_path / 'kt.yaml')]) == 1
    err = capsys.readouterr().err
    assert 'bag has no topic /gimbal/calibration/torque' in err
