"""``gimbal-friction fleet`` and gimbal_friction.chamber.fleet: units found, refitted on Dask, population and outliers.

Units are tiny residual logs written in the 12-column residual layout (plateaus -40..60 degC, both directions,
1/3 rpm, +/-5 % ripple, 0.1 mN*m noise) from truths that differ a little in lubricant and contact friction; one
unit has a different grease (walther_a + 0.05: nu(-40 degC) x 3).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from gimbal_friction.chamber.fleet import FitSettings, UnitSpec, discover_units, population, process_unit
from gimbal_friction.cli.main import main
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.bag_write import make_float64_multi_array
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL_DETAIL
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS

T0 = 1_700_000_000_000_000_000  # [ns]
SPEED = 2.0 * math.pi / 180.0   # 1/3 rpm [rad/s]


def write_unit(folder: Path, truth: AxisParams, seed: int, plateaus=(-40.0, -20.0, 0.0, 20.0, 40.0, 60.0),
               n_per: int = 80, **writer_kwargs) -> Path:
    rng = np.random.default_rng(seed)
    k = 0
    with ResidualLogWriter(folder, **writer_kwargs) as writer:
        for plateau in plateaus:
            for sign in (1.0, -1.0):
                t = plateau + rng.normal(0.0, 0.05, n_per)
                pos = np.linspace(-0.1, 0.19, n_per)
                tau = friction_torque(truth, t, 1 / 3).m_total_nmm * 1e-3
                tau = tau * (1.0 + 0.05 * np.sin(2.0 * np.pi * pos / math.radians(3.4)))
                measured = sign * (tau + rng.normal(0.0, 1e-4, n_per))
                for i in range(n_per):
                    stamp = T0 + k * 10_000_000
                    k += 1
                    row = [stamp * 1e-9, t[i], pos[i], sign * SPEED, measured[i] / 0.05, measured[i], math.nan,
                           math.nan, 0.0, 0.05, 0.0, 0.0]
                    assert len(row) == len(RESIDUAL_FIELDS)
                    writer.write(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE, stamp, make_float64_multi_array(row,
                                                                                                          'elevation'))
    return folder


@pytest.fixture(scope='module')
def fleet_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp('fleet') / 'line'
    root.mkdir()
    base = AxisParams()
    rng = np.random.default_rng(7)
    for i in range(6):
        truth = base.replace(walther_a=base.walther_a + 0.02 + rng.normal(0.0, 0.001),
                             sliding_friction_coefficient=0.095 * (1.0 + rng.normal(0.0, 0.01)))
        if i == 4:
            truth = truth.replace(walther_a=base.walther_a + 0.07)   # a different grease batch
        write_unit(root / f'seeker_{i:02d}', truth, seed=i)
    return root


@pytest.mark.slow
def test_fleet_finds_the_outlier_and_writes_json_csv_figure(fleet_dir, tmp_path, capsys):
    out = tmp_path / 'report'
    assert main(['fleet', str(fleet_dir), '--out', str(out), '--threads', '--workers', '2']) == 0
    captured = capsys.readouterr()
    assert 'fleet: 6/6' in captured.err and 'embedded local Dask cluster' in captured.err
    assert 'OUTLIER seeker_04 (elevation): walther_a' in captured.out
    doc = json.loads((out / 'fleet.json').read_text())
    assert [u['unit'] for u in doc['units']] == [f'seeker_{i:02d}' for i in range(6)]
    assert all(u['error'] is None for u in doc['units'])
    flagged = {(o['unit'], o['parameter']) for o in doc['population']['outliers']}
    assert ('seeker_04', 'walther_a') in flagged
    assert {u for u, _ in flagged} == {'seeker_04'}
    reason = next(o['reason'] for o in doc['population']['outliers'] if o['parameter'] == 'walther_a')
    assert 'above the median' in reason and 'grease batch' in reason
    pop = doc['population']['axes']['elevation']['walther_a']
    assert pop['n'] == 6 and pop['median'] == pytest.approx(AxisParams().walther_a + 0.02, abs=3e-3)
    assert pop['spread'] < 0.01
    unit0 = doc['units'][0]['axes']['elevation']
    lo, hi = unit0['ci95']['walther_a']
    assert lo < unit0['fitted']['walther_a'] < hi
    csv = (out / 'fleet.csv').read_text().splitlines()
    assert csv[0].startswith('unit,axis,kind,samples') and len(csv) == 7
    assert (out / 'fleet.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert doc['workers'] == 2 and doc['units_per_minute'] > 0


@pytest.mark.slow
def test_fleet_json_on_stdout_with_processes_and_a_bag(fleet_dir, tmp_path, capsys):
    # two log units and a chamber bag (replayed on the worker), on one worker process
    assert main(['synth-bag', '--out', str(tmp_path / 'bag_unit'), '--plateaus=-40,20', '--hold-s', '12',
                 '--joint-rate-hz', '25', '--format', 'json']) == 0
    capsys.readouterr()
    out = tmp_path / 'report'
    assert main(['fleet', str(fleet_dir / 'seeker_00'), str(fleet_dir / 'seeker_01'), str(tmp_path / 'bag_unit'),
                 '--out', str(out), '--workers', '1', '--fit', 'walther_a', '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    kinds = {u['unit']: u['kind'] for u in doc['units']}
    assert kinds == {'seeker_00': 'log', 'seeker_01': 'log', 'bag_unit': 'bag'}
    bag = next(u for u in doc['units'] if u['unit'] == 'bag_unit')
    assert bag['error'] is None and bag['axes']['elevation']['samples'] > 100
    assert bag['axes']['elevation']['identifiable']['walther_a']
    assert doc['population']['axes']['elevation']['walther_a']['n'] == 3 and doc['workers'] == 1


@pytest.mark.slow
def test_a_broken_unit_is_reported_not_fatal(fleet_dir, tmp_path, capsys):
    broken = tmp_path / 'broken'
    broken.mkdir()
    (broken / 'residuals_0.mcap').write_bytes(b'not an mcap file at all')
    out = tmp_path / 'report'
    assert main(['fleet', str(fleet_dir / 'seeker_01'), str(broken), '--out', str(out), '--threads']) == 0
    doc = json.loads((out / 'fleet.json').read_text())
    err = next(u['error'] for u in doc['units'] if u['unit'] == 'broken')
    assert err and 'mcap' in err.lower()
    assert 'broken' in capsys.readouterr().err


def test_damaged_chunks_of_a_unit_are_counted_and_said(tmp_path, damage_mcap_chunk):
    """Every command that skips data says how much: the unit's record carries the count, its progress line says it."""
    import io

    from gimbal_friction.chamber.fleet import progress_line
    from gimbal_friction.recording.mcap_scan import McapScanner
    folder = write_unit(tmp_path / 'unit', AxisParams().replace(walther_a=AxisParams().walther_a + 0.02), seed=3,
                        chunk_size=4096)
    (path,) = folder.glob('*.mcap')
    damage_mcap_chunk(path, 2)  # the third chunk
    scan = McapScanner(path)
    sum(len(b) for b in scan.blocks())
    lost = scan.report.lost_messages
    settings = FitSettings(axes={'elevation': AxisParams()}, config_paths=(), fit=('walther_a',))
    rec = process_unit(UnitSpec('unit', str(folder), 'log'), settings)
    assert rec['error'] is None and rec['axes']['elevation']['samples'] == 960 - lost
    assert (rec['read']['damaged_chunks'], rec['read']['lost_messages'], rec['read']['skipped']) == (1, lost, True)
    line = io.StringIO()
    progress_line(1, 1, rec, stream=line)
    assert (f'ok; {960 - lost} residual rows read from 1 file; not read: 1 damaged chunks skipped ({lost} messages '
            'lost)') in line.getvalue()


@pytest.mark.slow
def test_an_earlier_run_in_out_is_refused_unless_force(fleet_dir, tmp_path, capsys):
    out = tmp_path / 'o'
    out.mkdir()
    (out / 'fleet.json').write_text('{}')
    assert main(['fleet', str(fleet_dir / 'seeker_01'), '--out', str(out), '--threads']) == 1
    err = capsys.readouterr().err.strip()
    assert 'fleet.json already exists; nothing written' in err and '--force' in err
    assert (out / 'fleet.json').read_text() == '{}'


def test_refusals_are_one_line(tmp_path, capsys):
    empty = tmp_path / 'empty'
    empty.mkdir()
    for argv, match in ((['fleet', str(tmp_path / 'missing'), '--out', str(tmp_path / 'o')], 'no such file'),
                        (['fleet', str(empty), '--out', str(tmp_path / 'o')], 'neither a residual log'),
                        (['fleet', str(empty), '--out', str(tmp_path / 'o'), '--workers', '0'], 'must be >= 1')):
        assert main(argv) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith('gimbal-friction fleet: error: ') and match in err


@pytest.mark.slow
def test_discover_units_kinds(fleet_dir, tmp_path):
    replay_out = tmp_path / 'replay_out'
    (replay_out / 'residuals').mkdir(parents=True)
    (replay_out / 'residuals' / 'residuals_0.mcap').write_bytes(b'')
    units = discover_units([fleet_dir, replay_out, fleet_dir / 'seeker_00'])
    names = [u.name for u in units]
    assert names[:6] == [f'seeker_{i:02d}' for i in range(6)]
    assert units[6] == UnitSpec('replay_out', str(replay_out / 'residuals'), 'log')
    assert names[7] == 'seeker_00#2'


def test_population_is_robust_and_noise_aware():
    def rec(unit, a, se=1e-4):
        return {'unit': unit, 'axes': {'x': {'fitted': {'walther_a': a}, 'standard_errors': {'walther_a': se},
                                             'identifiable': {'walther_a': True}, 'viscosity_m40_cst': 1.0,
                                             'offset': {'estimated': False}}}}
    same = [rec(f'u{i}', 8.64 + 1e-7 * i) for i in range(8)]      # identical within their own noise
    assert population(same)['outliers'] == []
    spread = [rec(f'u{i}', 8.64 + 0.001 * i) for i in range(8)] + [rec('bad', 8.70)]
    pop = population(spread)
    assert [o['unit'] for o in pop['outliers']] == ['bad']
    assert pop['axes']['x']['walther_a']['median'] == pytest.approx(8.644)


@pytest.mark.slow
def test_process_unit_records_an_unconfigured_joint(fleet_dir):
    settings = FitSettings(axes={'azimuth': AxisParams()}, config_paths=())
    rec = process_unit(UnitSpec('u', str(fleet_dir / 'seeker_00'), 'log'), settings)
    assert rec['error'].startswith('no samples of a configured axis (joints present: elevation')


def test_a_bag_unit_without_a_configured_axis_says_which_joints_it_has(tmp_path):
    """A chamber bag read by fleet goes through the reader's rule (issue 19, 3): its record's error names the joints
    recorded in the bag (not 'joints present: none'), the mapping and the fix."""
    from gimbal_friction.recording.bag_write import make_joint_state, make_temperature, write_chamber_bag
    from gimbal_friction.recording.topics import (
        JOINT_STATE_TYPE,
        JOINT_STATES,
        MOTOR_CURRENT,
        TEMPERATURE,
        TEMPERATURE_TYPE,
    )

    msgs = []
    for i in range(50):
        t = 1_000_000_000 + i * 20_000_000
        msgs += [(TEMPERATURE, TEMPERATURE_TYPE, t, make_temperature(t, 20.0)),
                 (JOINT_STATES, JOINT_STATE_TYPE, t, make_joint_state(t, ['joint_2'], [0.0], [0.035])),
                 (MOTOR_CURRENT, JOINT_STATE_TYPE, t + 1, make_joint_state(t, ['joint_2'], effort=[0.2]))]
    bag = write_chamber_bag(tmp_path / 'robot_bag', msgs)
    rec = process_unit(UnitSpec('u', str(bag), 'bag'), FitSettings(axes={'elevation': AxisParams()},
                                                                    config_paths=()))
    assert "no configured axis is in /joint_states (axes: 'elevation'; joints recorded: 'joint_2'" in rec['error']
    assert '--joint elevation=joint_2' in rec['error'] and rec['axes'] == {}


@pytest.mark.slow
def test_a_bag_unit_is_read_in_windows_with_the_same_statistics(tmp_path, capsys):
    """A chamber bag is fed to the estimator window by window (bounded memory): the same samples and statistics
    as one pass over the whole bag, and as many samples as the offline replay accepts."""
    from gimbal_friction.chamber.fleet import unit_stats_from_bag
    from gimbal_friction.chamber.replay import replay_bag

    assert main(['synth-bag', '--out', str(tmp_path / 'bag'), '--plateaus=-40,20', '--hold-s', '8',
                 '--joint-rate-hz', '25', '--format', 'json']) == 0
    capsys.readouterr()
    whole = unit_stats_from_bag(str(tmp_path / 'bag'), [], 'both', window_messages=10**9)
    small = unit_stats_from_bag(str(tmp_path / 'bag'), [], 'both', window_messages=97)
    replayed = replay_bag(tmp_path / 'bag', None, log_inputs=False).measurements
    assert set(whole) == set(small) == {'elevation'}
    a, b = whole['elevation'], small['elevation']
    assert a.n_samples == b.n_samples == int(np.sum(replayed.joint == 'elevation')) > 100
    np.testing.assert_array_equal(a.t_index, b.t_index)
    np.testing.assert_array_equal(a.samples, b.samples)
    np.testing.assert_allclose(b.mean_y, a.mean_y, rtol=1e-12)
    np.testing.assert_allclose(b.sum_t, a.sum_t, rtol=1e-12)


@pytest.mark.parametrize('missing', ['dask', 'distributed'])
def test_without_dask_fleet_says_how_to_install_it(tmp_path, capsys, monkeypatch, missing):
    """Dask is optional (only fleet uses it): without it, one line naming the module and the install command,
    exit 1, and no output written."""
    import sys

    monkeypatch.setitem(sys.modules, missing, None)  # `import <missing>` now raises ModuleNotFoundError
    assert main(['fleet', str(tmp_path), '--out', str(tmp_path / 'o')]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith('gimbal-friction fleet: error: ')
    assert repr(missing) in err and "pip install 'dask[distributed]'" in err
    assert not (tmp_path / 'o').exists()


@pytest.mark.slow
def test_correction_out_writes_each_units_refit_and_correction_as_refit_does(fleet_dir, tmp_path, capsys):
    """fleet --correction-out DIR: per unit, DIR/<unit>.refit.yaml and DIR/<unit>.correction.yaml, the same
    correction refit --correction-out learns from that unit's log with the same fit; named in fleet.json; loadable
    together; refused on a second run unless --force."""
    from gimbal_friction.controller import load_feedforward
    from gimbal_friction.feedforward.correction import load

    units = [fleet_dir / 'seeker_00', fleet_dir / 'seeker_04']
    out, corr = tmp_path / 'fleet', tmp_path / 'corrections'
    assert main(['fleet', *map(str, units), '--out', str(out), '--threads', '--correction-out', str(corr)]) == 0
    shown = capsys.readouterr().out
    assert 'learned corrections: 2 unit(s)' in shown
    doc = json.loads((out / 'fleet.json').read_text())
    for rec in doc['units']:
        c = rec['correction']
        assert c['out'] == str((corr / f'{rec["unit"]}.correction.yaml').resolve())
        assert c['params'] == str((corr / f'{rec["unit"]}.refit.yaml').resolve())
        assert c['samples'] == 960 and len(c['cells']) == 12
    # the same as refit --correction-out of the unit's log with the fleet's fit (both default: walther_a)
    assert main(['refit', str(units[1]), '--out', str(tmp_path / 'r.yaml'), '--correction-out',
                 str(tmp_path / 'r.correction.yaml')]) == 0
    capsys.readouterr()
    mine, theirs = load(corr / 'seeker_04.correction.yaml'), load(tmp_path / 'r.correction.yaml')
    assert mine.identity == theirs.identity
    for a, b in zip(mine.cells('elevation'), theirs.cells('elevation'), strict=True):
        assert a['samples'] == b['samples'] and a['value_nm'] == pytest.approx(b['value_nm'], rel=1e-9, abs=1e-15)
    ff = load_feedforward(corr / 'seeker_04.refit.yaml', correction=corr / 'seeker_04.correction.yaml')
    assert ff.correction is not None and ff.correction.summary()['samples'] == 960
    # a second run is refused (nothing replaced) unless --force
    before = (corr / 'seeker_00.correction.yaml').read_bytes()
    assert main(['fleet', *map(str, units), '--out', str(tmp_path / 'fleet2'), '--threads', '--correction-out',
                 str(corr)]) == 1
    assert 'already exists' in capsys.readouterr().err
    assert (corr / 'seeker_00.correction.yaml').read_bytes() == before


SAMPLE = Path(__file__).resolve().parents[2] / 'bags' / 'chamber_sample'


@pytest.mark.slow
def test_the_default_fit_refits_the_shipped_sample(tmp_path, capsys):
    """Issue 11: a new user's first fleet run (the shipped sample, default options) succeeds. Was: exit 1, the
    sliding coefficient (then in the default fit, beside the calibration offset) ran to its bound."""
    out = tmp_path / 'fleet'
    assert main(['fleet', str(SAMPLE), '--out', str(out), '--threads', '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    (unit,) = doc['units']
    axis = unit['axes']['elevation']
    assert unit['error'] is None and doc['fit'] == ['walther_a'] and axis['identifiable'] == {'walther_a': True}
    assert axis['offset']['estimated']             # as refit's default: the lubricant, the offset beside it
    lo, hi = axis['ci95']['walther_a']
    assert lo < axis['fitted']['walther_a'] < hi and abs(axis['fitted']['walther_a'] - 8.6345) < 0.03


@pytest.mark.slow
def test_the_old_default_fit_says_what_to_run_instead_and_stays_available(tmp_path, capsys):
    """The former default (the lubricant and the contact friction, beside the offset) fails on the sample with one
    line naming what to run instead; with --offset off it is still there."""
    old = ['--fit', 'walther_a,sliding_friction_coefficient']
    assert main(['fleet', str(SAMPLE), '--out', str(tmp_path / 'a'), '--threads', *old]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert 'fleet: 1/1 chamber_sample' in captured.err and ') ok' not in captured.err   # not 'ok' when it failed
    assert err[-1].startswith('gimbal-friction fleet: error: no unit could be refitted (chamber_sample: ')
    assert 'sliding_friction_coefficient ran to the edge' in err[-1]
    assert err[-1].endswith('run the default fit (leave out --fit), or add --offset off to fit '
                            'sliding_friction_coefficient without the calibration offset')
    assert main(['fleet', str(SAMPLE), '--out', str(tmp_path / 'b'), '--threads', *old, '--offset', 'off',
                 '--format', 'json']) == 0
    axis = json.loads(capsys.readouterr().out)['units'][0]['axes']['elevation']
    assert axis['identifiable'] == {'walther_a': True, 'sliding_friction_coefficient': True}


def test_a_unit_whose_every_axis_failed_is_no_ok_in_its_progress_line():
    import io

    from gimbal_friction.chamber.fleet import progress_line
    line = io.StringIO()
    rec = {'unit': 'u', 'error': None, 'seconds': 0.5, 'axes': {'elevation': {'error': 'the fit diverged'}}}
    progress_line(1, 1, rec, stream=line)
    assert line.getvalue() == 'fleet: 1/1 u (0.5 s) error: elevation: the fit diverged\n'
    rec['axes']['azimuth'] = {'samples': 10}
    line = io.StringIO()
    progress_line(1, 1, rec, stream=line)
    assert line.getvalue() == 'fleet: 1/1 u (0.5 s) ok; elevation failed: the fit diverged\n'
