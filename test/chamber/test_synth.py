"""Synthetic chamber test (gimbal_friction.chamber.synth) and the ``gimbal-friction synth-bag`` command."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

from gimbal_friction.chamber.synth import (
    PAPER_COLD_RATIO,
    SynthConfig,
    chamber_and_bearing,
    generate,
    message_order,
    schedule,
    sweep,
)
from gimbal_friction.cli.main import main
from gimbal_friction.common.errors import ConfigError
from gimbal_friction.config.loader import axis_params, load_parameters
from gimbal_friction.recording import topics

V_NOMINAL = 2.0 * math.pi / 180.0   # 1/3 rpm = 2 deg/s [rad/s]


@pytest.fixture(scope='module')
def data():
    """The default test, shortened holds (still >= 2 full sweeps per direction per hold)."""
    return generate(SynthConfig(hold_s=40.0, joint_rate_hz=50.0, seed=3))


def _hold_mask(data, plateau, t_s, latter=0.0):
    start = plateau.hold_start_s + latter * (plateau.hold_end_s - plateau.hold_start_s)
    return (t_s >= start) & (t_s <= plateau.hold_end_s)


def _steady(data):
    """Current samples at constant sweep speed (reversals excluded)."""
    return np.abs(np.abs(data.truth_velocity_rad_s[:, 0]) - V_NOMINAL) < 1e-9


# ---------------------------------------------------------------------------------------------- generator
def test_same_seed_same_output_other_seed_differs():
    cfg = SynthConfig(plateaus_c=(-40.0, 20.0), hold_s=20.0, joint_rate_hz=50.0, seed=7)
    a, b = generate(cfg), generate(cfg)
    for name in ('joint_stamp_ns', 'joint_log_ns', 'position_rad', 'velocity_rad_s', 'current_a',
                 'temperature_c', 'temperature_log_ns', 'current_log_ns', 'truth_friction_nm'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = generate(SynthConfig(plateaus_c=(-40.0, 20.0), hold_s=20.0, joint_rate_hz=50.0, seed=8))
    assert not np.array_equal(a.current_a, c.current_a)
    np.testing.assert_array_equal(a.truth_friction_nm, c.truth_friction_nm)   # noise only


def test_plateaus_reached_and_bearing_lags_chamber(data):
    t_c = data.seconds(data.current_stamp_ns)
    t_t = data.seconds(data.temperature_stamp_ns)
    assert [p.temperature_c for p in data.plateaus] == [-40.0, -20.0, 0.0, 20.0, 40.0, 60.0]
    for p in data.plateaus:
        assert p.hold_end_s - p.hold_start_s == pytest.approx(40.0)
        m = _hold_mask(data, p, t_c, latter=0.5)
        assert m.sum() > 0
        assert np.max(np.abs(data.bearing_temperature_c[m] - p.temperature_c)) < 0.5
        mt = _hold_mask(data, p, t_t, latter=0.5)
        assert np.max(np.abs(data.temperature_c[mt] - p.temperature_c)) < 0.5   # measured, with sensor noise
    # during a ramp the bearing lags the chamber (warming: bearing below chamber) by about rate * tau
    p1 = data.plateaus[1]
    ramp = (t_c > p1.reached_s - 10.0) & (t_c < p1.reached_s)
    lag = data.chamber_temperature_c[ramp] - data.bearing_temperature_c[ramp]
    assert np.all(lag > 0.0)
    assert lag.max() == pytest.approx(15.0 / 60.0 * 30.0, rel=0.1)
    # chamber ramps at 15 degC/min
    assert p1.reached_s - data.plateaus[0].hold_end_s == pytest.approx(20.0 / 15.0 * 60.0)


def test_bearing_lag_is_integrated_exactly():
    cfg = SynthConfig(plateaus_c=(-40.0, 0.0, -20.0), hold_s=30.0, bearing_lag_s=25.0, ramp_rate_c_per_min=10.0)
    _, _, total = schedule(cfg)
    dt = 1e-3
    t = np.arange(0.0, total, dt)
    chamber, bearing = chamber_and_bearing(cfg, t)
    ref = np.empty_like(t)   # fine RK2 (Heun) integration of tau db/dt = c - b
    ref[0] = -40.0
    for k in range(t.size - 1):
        d1 = (chamber[k] - ref[k]) / 25.0
        pred = ref[k] + dt * d1
        ref[k + 1] = ref[k] + 0.5 * dt * (d1 + (chamber[k + 1] - pred) / 25.0)
    assert np.max(np.abs(bearing - ref)) < 1e-3
    assert chamber.min() == pytest.approx(-40.0) and chamber.max() == pytest.approx(0.0)


def test_sweep_speed_and_travel(data):
    deg = np.degrees(data.truth_position_rad[:, 0])
    assert deg.min() == pytest.approx(-6.0, abs=1e-3)
    assert deg.max() == pytest.approx(11.0, abs=1e-3)
    vel = data.truth_velocity_rad_s[:, 0]
    steady = _steady(data)
    assert steady.mean() > 0.95                   # reversals are short
    assert np.abs(vel).max() == pytest.approx(V_NOMINAL)
    rpm = np.abs(vel[steady]) * 60.0 / (2.0 * math.pi)
    np.testing.assert_allclose(rpm, 1.0 / 3.0, rtol=1e-12)
    # measured stream: same speed within the velocity noise, both directions present
    mv = data.velocity_rad_s[:, 0]
    fast = np.abs(mv) > 0.9 * V_NOMINAL
    assert np.mean(np.abs(mv[fast])) == pytest.approx(V_NOMINAL, rel=1e-3)
    assert (mv > 0).sum() > 0.4 * mv.size and (mv < 0).sum() > 0.4 * mv.size
    # position and velocity are consistent (velocity is the derivative of position)
    t = np.linspace(0.0, 60.0, 600001)
    pos, v, acc = sweep(data.config, t)
    np.testing.assert_allclose(np.gradient(pos, t)[1:-1], v[1:-1], atol=2e-3 * V_NOMINAL)
    assert np.abs(acc).max() == pytest.approx(2.0 * V_NOMINAL / 0.2)


def test_full_sweeps_in_each_direction_on_every_plateau(data):
    t_c = data.seconds(data.current_stamp_ns)
    vel = data.truth_velocity_rad_s[:, 0]
    pos = np.degrees(data.truth_position_rad[:, 0])
    for p in data.plateaus:
        m = (t_c >= p.reached_s) & (t_c <= p.hold_end_s) & (np.abs(data.bearing_temperature_c - p.temperature_c)
                                                             < 0.5)
        sgn = np.sign(vel[m])
        seg = np.flatnonzero(np.diff(sgn) != 0) + 1
        parts = np.split(np.arange(m.sum()), seg)
        full = {1.0: 0, -1.0: 0}
        for part in parts:
            s = sgn[part[0]]
            if s != 0 and np.ptp(pos[m][part]) > 16.9:
                full[s] += 1
        assert full[1.0] >= 2 and full[-1.0] >= 2, (p, full)


def test_current_follows_velocity_and_eq23(data):
    vel = data.truth_velocity_rad_s[:, 0]
    cur = data.current_a[:, 0]
    moving = np.abs(vel) > 0.5 * V_NOMINAL
    assert np.all(np.sign(cur[moving]) == np.sign(vel[moving]))
    # Eq. 23 with the truth K_T = 0.05 N*m/A, I_0 = 0: steady-state current = friction / K_T + noise
    steady = _steady(data)
    resid = cur[steady] - data.truth_friction_nm[steady, 0] / 0.05
    assert abs(resid.mean()) < 2e-4
    assert resid.std() == pytest.approx(2e-3, rel=0.05)


def _direction_ratio(data, temperature, values):
    p = next(p for p in data.plateaus if p.temperature_c == temperature)
    t_c = data.seconds(data.current_stamp_ns)
    m = _hold_mask(data, p, t_c) & _steady(data)
    vel = data.truth_velocity_rad_s[:, 0]
    cw, ccw = values[m & (vel > 0)], values[m & (vel < 0)]
    return np.mean(np.abs(ccw)) / np.mean(cw), np.mean(cw)


def test_cold_direction_asymmetry(data):
    cfg = data.config
    assert cfg.asym_ratio_cold == pytest.approx(2.45 / 3.19)
    ratio, cw = _direction_ratio(data, -40.0, data.truth_friction_nm[:, 0])
    assert ratio == pytest.approx(PAPER_COLD_RATIO, abs=0.01)
    assert cw > 3e-3                                   # truth friction at -40 degC is > 3 N*mm
    ratio_meas, _ = _direction_ratio(data, -40.0, data.current_a[:, 0])   # visible in the measured current
    assert ratio_meas == pytest.approx(PAPER_COLD_RATIO, abs=0.02)
    ratio20, cw20 = _direction_ratio(data, 20.0, data.truth_friction_nm[:, 0])
    assert ratio20 == pytest.approx(1.0, abs=0.01)
    assert cw20 < 0.5 * cw                             # friction much lower when warm
    assert float(cfg.ccw_ratio(20.0)) == 1.0 and float(cfg.ccw_ratio(60.0)) == 1.0
    # configurable
    other = generate(SynthConfig(plateaus_c=(-40.0,), hold_s=40.0, joint_rate_hz=50.0, asym_ratio_cold=0.9))
    assert _direction_ratio(other, -40.0, other.truth_friction_nm[:, 0])[0] == pytest.approx(0.9, abs=0.01)


def test_truth_differs_from_defaults():
    cfg = SynthConfig()
    truth = cfg.truth_params()
    assert truth.walther_a != 8.6195 and truth.palmgren_factor != 1.917
    with pytest.raises(ConfigError, match=r'truth\.no_such'):
        SynthConfig(truth_overrides={'no_such': 1.0})


@pytest.mark.parametrize('change', [{'hold_s': -1.0}, {'plateaus_c': ()}, {'travel_deg': (11.0, -6.0)},
                                    {'joint_rate_hz': 0.0}, {'joints': ('a', 'a')}, {'plateaus_c': (-100.0,)},
                                    {'ripple_amplitude': (0.6, 0.3)}, {'log_jitter_s': 0.1}])
def test_invalid_config_refused(change):
    with pytest.raises(ConfigError):
        SynthConfig(**change)


def test_two_joints_and_message_order():
    d = generate(SynthConfig(plateaus_c=(0.0,), hold_s=10.0, joints=('elevation', 'azimuth'), joint_rate_hz=20.0,
                             temperature_rate_hz=1.0))
    assert d.position_rad.shape == (200, 2) and d.current_a.shape == (200, 2)
    assert not np.allclose(d.position_rad[:, 0], d.position_rad[:, 1])
    log, stream, index = message_order(d)
    assert np.all(np.diff(log) >= 0)
    assert log.size == sum(d.message_counts().values())
    for k, stamps in enumerate((d.temperature_stamp_ns, d.joint_stamp_ns, d.current_stamp_ns)):
        assert np.all(np.diff(index[stream == k]) == 1)
        assert np.all(np.diff(stamps) > 0)
    assert np.all(d.joint_log_ns >= d.joint_stamp_ns)
    assert np.all(d.joint_log_ns - d.joint_stamp_ns < 2e5)   # jitter < 0.2 ms


def test_ten_minute_bag_generates_fast():
    cfg = SynthConfig(duration_s=600.0, joint_rate_hz=100.0)
    t0 = time.perf_counter()
    d = generate(cfg)
    elapsed = time.perf_counter() - t0
    assert d.joint_stamp_ns.size == 60000
    assert elapsed < 2.0


# ---------------------------------------------------------------------------------------------- CLI
SMALL = ['--plateaus=-40,20', '--hold-s', '20', '--joint-rate-hz', '20', '--temperature-rate-hz', '1']


def _read_bag(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_KILTED)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        last = -1
        for conn, log_ns, raw in reader.messages():
            assert log_ns >= last
            last = log_ns
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return types, out


def test_cli_writes_readable_bag(tmp_path, capsys):
    out = tmp_path / 'bag'
    truth_out = tmp_path / 'truth.yaml'
    assert main(['synth-bag', '--out', str(out), '--seed', '5', *SMALL, '--truth-out', str(truth_out),
                 '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (out / 'metadata.yaml').is_file()
    assert not list(tmp_path.glob('.*partial'))           # no staging left behind
    types, msgs = _read_bag(out)
    assert types == topics.CHAMBER_TOPICS
    assert {t: len(m) for t, m in msgs.items()} == doc['messages']
    js = msgs[topics.JOINT_STATES][10]
    assert list(js.name) == ['elevation'] and len(js.position) == 1 and len(js.velocity) == 1
    cur = msgs[topics.MOTOR_CURRENT][10]
    assert list(cur.name) == ['elevation'] and len(cur.effort) == 1
    temp = msgs[topics.TEMPERATURE][0]
    assert temp.temperature == pytest.approx(-40.0, abs=0.3)
    assert doc['plateaus'][0]['temperature_c'] == -40.0 and doc['size_bytes'] > 0
    # the bag holds exactly what generate() gives for the same options
    d = generate(SynthConfig(plateaus_c=(-40.0, 20.0), hold_s=20.0, joint_rate_hz=20.0, temperature_rate_hz=1.0,
                             seed=5))
    eff = np.array([m.effort[0] for m in msgs[topics.MOTOR_CURRENT]])
    np.testing.assert_array_equal(eff, d.current_a[:, 0])
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs[topics.JOINT_STATES]])
    np.testing.assert_array_equal(stamps, d.joint_stamp_ns)
    # the truth parameter file layers over the defaults and gives the truth model
    truth = axis_params(load_parameters([truth_out]), 'elevation')
    assert truth == d.config.truth_params()
    assert doc['truth']['elevation']['differs_from_defaults']['walther_a'] == truth.walther_a


def test_cli_refuses_non_empty_out(tmp_path, capsys):
    out = tmp_path / 'bag'
    out.mkdir()
    (out / 'keep.txt').write_text('precious')
    assert main(['synth-bag', '--out', str(out), *SMALL]) == 1
    err = capsys.readouterr().err
    assert 'not empty' in err and len(err.strip().splitlines()) == 1
    assert [p.name for p in out.iterdir()] == ['keep.txt']
    # --force does not delete a directory that is not a bag
    assert main(['synth-bag', '--out', str(out), *SMALL, '--force']) == 1
    assert 'not a rosbag2 bag' in capsys.readouterr().err
    assert (out / 'keep.txt').read_text() == 'precious'


@pytest.mark.slow
def test_cli_force_replaces_bag_and_empty_dir_ok(tmp_path, capsys):
    out = tmp_path / 'bag'
    out.mkdir()                                          # empty: fine without --force
    assert main(['synth-bag', '--out', str(out), *SMALL, '--seed', '1']) == 0
    assert main(['synth-bag', '--out', str(out), *SMALL]) == 1
    capsys.readouterr()
    assert main(['synth-bag', '--out', str(out), '--force', '--plateaus', '-20,0', '--hold-s', '10',
                 '--joint-rate-hz', '10', '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [p['temperature_c'] for p in doc['plateaus']] == [-20.0, 0.0]
    _types, msgs = _read_bag(out)
    assert len(msgs[topics.JOINT_STATES]) == doc['messages'][topics.JOINT_STATES]


@pytest.mark.slow
def test_cli_sqlite3_and_truth_file(tmp_path, capsys):
    truth = tmp_path / 'my_truth.yaml'
    truth.write_text('/**:\n  ros__parameters:\n    model:\n      walther_a: 8.63\n')
    out = tmp_path / 'bag3'
    assert main(['synth-bag', '--out', str(out), *SMALL, '--storage', 'sqlite3', '--truth', str(truth),
                 '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['truth']['elevation']['differs_from_defaults'] == {'walther_a': 8.63}
    assert list(out.glob('*.db3'))
    types, _ = _read_bag(out)
    assert types == topics.CHAMBER_TOPICS


def test_cli_bad_input_one_line(tmp_path, capsys):
    assert main(['synth-bag', '--out', str(tmp_path / 'x'), '--plateaus=-40,abc']) == 1
    err = capsys.readouterr().err
    assert '--plateaus' in err and len(err.strip().splitlines()) == 1
    assert main(['synth-bag', '--out', str(tmp_path / 'x'), '--hold-s', '-5']) == 1
    assert 'hold_s' in capsys.readouterr().err
    assert not (tmp_path / 'x').exists()


def test_cli_table_output(tmp_path, capsys):
    assert main(['synth-bag', '--out', str(tmp_path / 'b'), *SMALL]) == 0
    text = capsys.readouterr().out
    assert '/gimbal/motor_current' in text and 'walther_a' in text and 'plateau' in text


@pytest.mark.slow
def test_cli_compression_choices(tmp_path, capsys):
    plain = tmp_path / 'plain'
    packed = tmp_path / 'packed'
    assert main(['synth-bag', '--out', str(plain), *SMALL, '--compression', 'none', '--format', 'json']) == 0
    size_plain = json.loads(capsys.readouterr().out)['size_bytes']
    assert main(['synth-bag', '--out', str(packed), *SMALL, '--format', 'json']) == 0   # mcap default: zstd
    doc = json.loads(capsys.readouterr().out)
    assert doc['compression'] == 'zstd' and doc['size_bytes'] < 0.6 * size_plain
    assert _read_bag(packed)[1].keys() == _read_bag(plain)[1].keys()
    assert main(['synth-bag', '--out', str(tmp_path / 'q'), *SMALL, '--storage', 'sqlite3', '--compression',
                 'zstd']) == 1
    assert 'mcap' in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- shipped sample
BAGS = Path(__file__).resolve().parents[2] / 'bags'


def _regenerate_args() -> list[str]:
    import shlex

    line = next(x for x in (BAGS / 'regenerate.sh').read_text().splitlines()
                if 'synth-bag' in x and not x.lstrip().startswith('#'))
    words = shlex.split(line)
    return words[words.index('synth-bag'):]


@pytest.mark.slow
def test_shipped_sample_is_small_complete_and_reproducible(tmp_path, capsys):
    from gimbal_friction.recording.bag import open_chamber_bag

    sample = BAGS / 'chamber_sample'
    size = sum(p.stat().st_size for p in sample.iterdir())
    assert size <= 3_000_000
    bag = open_chamber_bag(sample)
    assert 50_000 <= bag.message_count <= 100_000
    shipped = bag.read_arrays()
    # every plateau: >= 2 full sweeps in each direction while the bearing is within 0.5 degC of the plateau
    js = shipped.joint_states
    temp = np.interp(js.stamp_ns, shipped.temperature.stamp_ns, shipped.temperature.temperature_c)
    pos = np.degrees(js.position['elevation'])
    vel = js.velocity['elevation']
    for plateau in (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0):
        on = np.abs(temp - plateau) < 0.5
        runs = {1: 0, -1: 0}
        idx = np.flatnonzero(on)
        for part in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            sgn = np.where(vel[part] > 0, 1, -1)
            for seg in np.split(part, np.flatnonzero(np.diff(sgn) != 0) + 1):
                if np.ptp(pos[seg]) > 16.5:
                    runs[1 if vel[seg].mean() > 0 else -1] += 1
        assert runs[1] >= 2 and runs[-1] >= 2, (plateau, runs)
    # What the vectorised math computes may differ by an ulp between CPU instruction sets; the written streams are
    # rounded to a grid (synth.*_RESOLUTION_*) so that they do not. Tolerance check of the unrounded values: within
    # half a step (+ 1e-12 of a step) of the shipped ones. Margin check: no unrounded value of this configuration
    # lies within 1e-6 of a step of a rounding boundary, i.e. within 1e-12 A / 1e-10 degC / 1e-15 rad(/s) -- a
    # thousand times more than any cross-machine difference (a few ulp: < 1e-16 A, 1e-14 degC, 1e-16 rad) -- so
    # every machine rounds to the same grid point and the exact checks below hold everywhere.
    from gimbal_friction.chamber.synth import (
        CURRENT_RESOLUTION_A,
        POSITION_RESOLUTION_RAD,
        TEMPERATURE_RESOLUTION_C,
        VELOCITY_RESOLUTION_RAD_S,
        half_step_margin,
    )
    from gimbal_friction.cli.main import build_parser
    from gimbal_friction.cli.synth_bag_cmd import build_config

    raw = generate(build_config(build_parser().parse_args(_regenerate_args())), quantise=False)
    for unrounded, written, step in ((raw.current_a[:, 0], shipped.motor_current.effort['elevation'],
                                      CURRENT_RESOLUTION_A),
                                     (raw.temperature_c, shipped.temperature.temperature_c, TEMPERATURE_RESOLUTION_C),
                                     (raw.position_rad[:, 0], js.position['elevation'], POSITION_RESOLUTION_RAD),
                                     (raw.velocity_rad_s[:, 0], js.velocity['elevation'], VELOCITY_RESOLUTION_RAD_S)):
        np.testing.assert_allclose(written, unrounded, rtol=0.0, atol=step * (0.5 + 1e-12))
        assert half_step_margin(unrounded, step) > 1e-6, step
        assert np.array_equal(written, np.rint(written / step) * step), step   # on the grid
    # bags/regenerate.sh regenerates exactly the shipped contents
    args = _regenerate_args()
    args[args.index('--out') + 1] = str(tmp_path / 'again')
    args[args.index('--truth-out') + 1] = str(tmp_path / 'truth.yaml')
    assert main(args) == 0
    capsys.readouterr()
    again = open_chamber_bag(tmp_path / 'again').read_arrays()
    np.testing.assert_array_equal(again.motor_current.effort['elevation'], shipped.motor_current.effort['elevation'])
    np.testing.assert_array_equal(again.joint_states.position['elevation'], js.position['elevation'])
    np.testing.assert_array_equal(again.joint_states.velocity['elevation'], js.velocity['elevation'])
    np.testing.assert_array_equal(again.temperature.temperature_c, shipped.temperature.temperature_c)
    np.testing.assert_array_equal(again.motor_current.log_time_ns, shipped.motor_current.log_time_ns)
    np.testing.assert_array_equal(again.temperature.log_time_ns, shipped.temperature.log_time_ns)
    assert (tmp_path / 'truth.yaml').read_text() == (BAGS / 'chamber_sample.truth.yaml').read_text()


# ---------------------------------------------------------------------------------------------- preset 'paper'
def test_paper_preset_reproduces_the_four_measured_means():
    from gimbal_friction.chamber.synth import PAPER_MEANS_NMM, preset_config, truth_summary

    cfg = preset_config('paper', hold_s=20.0, joint_rate_hz=50.0)
    assert cfg.asym_ratio_cold == 1.0   # the synthetic CCW-only asymmetry is off: the model's own term is the truth
    rows = {r['temperature_c']: r for r in truth_summary(cfg)['elevation']['plateaus']}
    for (t, d), mean in PAPER_MEANS_NMM.items():
        got = rows[t]['truth_cw_nmm'] if d > 0 else rows[t]['truth_ccw_nmm']
        assert got == pytest.approx(mean, rel=1e-3), (t, d)
    # the generated friction at constant speed on the hold of each end plateau has those means (ripple averages out)
    data = generate(cfg)
    t_c = data.seconds(data.current_stamp_ns)
    vel = data.truth_velocity_rad_s[:, 0]
    steady = _steady(data)
    for p in data.plateaus:
        if p.temperature_c not in (-40.0, 60.0):
            continue
        m = _hold_mask(data, p, t_c) & steady
        for d in (1, -1):
            sel = m & (np.sign(vel) == d)
            mean = 1e3 * float(np.mean(data.truth_friction_nm[sel, 0]))
            assert mean == pytest.approx(PAPER_MEANS_NMM[(p.temperature_c, d)], rel=0.02), (p.temperature_c, d)


@pytest.mark.slow
def test_cli_paper_preset_and_truth_file(tmp_path, capsys):
    out, truth = tmp_path / 'bag', tmp_path / 'truth.yaml'
    assert main(['synth-bag', '--out', str(out), '--preset', 'paper', '--plateaus=-40,60', '--hold-s', '10',
                 '--joint-rate-hz', '20', '--truth-out', str(truth), '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    cw = {r['temperature_c']: (r['truth_cw_nmm'], r['truth_ccw_nmm']) for r in doc['truth']['elevation']['plateaus']}
    assert cw[-40.0] == pytest.approx((3.19, -2.45), rel=1e-3) and cw[60.0] == pytest.approx((1.05, -1.34), rel=1e-3)
    p = axis_params(load_parameters([truth]), 'elevation')
    assert (p.direction_asymmetry_cold, p.direction_asymmetry_warm) == (0.13121, -0.12134)
    assert 'asymmetry' not in truth.read_text().split('ros__parameters')[0].split('Not part of the truth')[1]
