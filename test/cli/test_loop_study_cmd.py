"""``gimbal-friction loop-study`` through main(): JSON per docs/cli.md, outputs, layering, one-line refusals."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml

from gimbal_friction.cli.main import main

CONTRACT_FIELDS = {'case', 'temperature_c', 'profile', 'rate_error_rms_rad_s', 'rate_error_peak_rad_s',
                   'position_error_rms_rad', 'position_error_peak_rad', 'reversal_error_peak_rad'}
SHORT = ['loop-study', '--short', '--profiles', 'tracking']


@pytest.fixture(scope='module')
def study_out(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, str]:
    out = tmp_path_factory.mktemp('loop') / 'study'
    import contextlib
    import io
    buf, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(err):
        code = main([*SHORT, '--temperatures', '-40,20', '--format', 'json', '--out', str(out)])
    assert code == 0, err.getvalue()
    return out, json.loads(buf.getvalue()), err.getvalue()


@pytest.mark.slow
def test_json_has_one_record_per_case_temperature_and_profile_with_the_contract_fields(study_out):
    _, doc, _ = study_out
    records = doc['records']
    cases = ('none', 'constant', 'feedforward', 'refit', 'learning', 'learned', 'chamber', 'bound', 'ideal')
    assert len(records) == len(cases) * 2
    assert {(r['case'], r['temperature_c']) for r in records} == {(c, t) for c in cases for t in (-40.0, 20.0)}
    for r in records:
        # (the learning run is scored on the service history it learned from)
        assert set(r) >= CONTRACT_FIELDS and r['profile'] == ('history' if r['case'] == 'learning' else 'tracking')
        assert r['mode'] == 'offline'
        assert ('learning_worst_window_ratio' in r) == (r['case'] == 'learning')
        assert all(isinstance(r[k], float) and math.isfinite(r[k]) for k in CONTRACT_FIELDS - {'case', 'profile'})
    rms = {(r['case'], r['temperature_c']): r['rate_error_rms_rad_s'] for r in records}
    assert rms[('ideal', -40.0)] <= rms[('feedforward', -40.0)] < rms[('none', -40.0)]
    assert {g['goal'] for g in doc['goals']} >= {'c_vs_a_cold', 'c_vs_a_all', 'c_vs_b_cold', 'd_near_e_cold',
                                                 'c_reversal', 'learned_vs_constant', 'learned_vs_bound',
                                                 'learning_cost', 'ff_vs_constant', 'refit_vs_ff', 'learned_vs_ff',
                                                 'chamber_vs_ff', 'chamber_vs_constant'}
    assert doc['explained'] is None   # --short: no attribution unless --explain
    # one configuration: the node's defaults but the learning rate, and the JSON says so
    assert set(doc['settings']['differs_from_node_default']) == {'learning_max_rate_nm_per_min'}
    assert doc['settings']['time_compression'] == pytest.approx(100.0 / 3.0)
    assert set(doc['learned']) == {'history', 'chamber'} and doc['chamber']['rows'] > 0
    assert doc['settings']['velocity_source'] == 'auto' and doc['refit']['accepted_by_method']['observer'] > 0


@pytest.mark.slow
def test_out_holds_the_document_the_table_the_figures_and_the_residual_log(study_out, capsys):
    out, doc, _ = study_out
    assert json.loads((out / 'loop_study.json').read_text()) == doc
    assert 'tracking: LOS rate error RMS' in (out / 'loop_study.txt').read_text()
    for name in ('error_vs_temperature_tracking.png', 'reversal_trace.png'):
        assert (out / 'figures' / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    # the whole loop: `gimbal-friction refit` on the residual log finds case (d)'s parameters again
    refit_file = out / 'refit.yaml'
    assert main(['refit', str(out / 'residuals'), '--out', str(refit_file), '--fit',
                 'walther_a,direction_asymmetry']) == 0
    capsys.readouterr()
    got = yaml.safe_load(refit_file.read_text())['/**']['ros__parameters']['axis']['elevation']
    for name, value in doc['refit']['fitted'].items():
        assert got[name] == pytest.approx(value, rel=1e-9), name


@pytest.mark.slow
def test_table_is_the_default_output_and_the_configuration_is_layered(tmp_path, capsys):
    cfg = tmp_path / 'wiring.yaml'
    cfg.write_text('/**:\n  ros__parameters:\n    velocity_source: "reference"\n    velocity_threshold_rad_s: 0.002\n'
                   'gimbal_sim:\n  ros__parameters:\n    feedforward_latency_s: 0.002\n')
    assert main([*SHORT, '--temperatures', '-40', '--cases', 'none,feedforward', '--config', str(cfg),
                 '--format', 'json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['settings']['velocity_source'] == 'reference' and doc['settings']['feedforward_latency_s'] == 0.002
    assert doc['settings']['velocity_threshold_rad_s'] == 0.002
    assert main([*SHORT, '--temperatures', '-40', '--cases', 'none', '--latency-s', '0.003']) == 0
    text = capsys.readouterr().out
    assert text.startswith('tracking: LOS rate error RMS') and 'none' in text


@pytest.mark.parametrize(('args', 'needle'), [
    (['--cases', 'magic'], '--cases'),
    (['--profiles', 'spiral'], '--profiles'),
    (['--temperatures', 'warm'], '--temperature'),
    (['--temperatures', '-90'], 'temperatures'),
    (['--latency-s', '-1'], '--latency-s'),
    (['--refit-fit', 'walther_z'], '--refit-fit'),
    (['--learn-position-bins', '32'], 'ripple periods are now found in the data'),
    (['--truths', '2', '--truth', 'config/truths/datasheet.yaml'], 'cannot be combined with --truths'),
    (['--truths', '0'], '--truths'),
    (['--config', '/nonexistent/file.yaml'], 'parameter file /nonexistent/file.yaml: cannot read'),
    (['--truth', '/nonexistent/truth.yaml'], 'parameter file /nonexistent/truth.yaml: cannot read'),
])
def test_bad_input_is_refused_in_one_line(args, needle, capsys):
    code = main(['loop-study', '--short', *args])
    captured = capsys.readouterr()
    assert code != 0 and captured.out == ''
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and 'Traceback' not in captured.err


def test_help_names_the_options(capsys):
    with pytest.raises(SystemExit) as info:
        main(['loop-study', '--help'])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for opt in ('--temperatures', '--profiles', '--cases', '--short', '--latency-s', '--out', '--live', '--seed',
                '--truth', '--truths', '--truth-seed', '--jobs'):
        assert opt in text


def _records(capsys, *args: str) -> tuple[dict, dict]:
    assert main([*SHORT, '--temperatures', '-40', '--cases', 'none,feedforward', '--format', 'json', *args]) == 0
    doc = json.loads(capsys.readouterr().out)
    return {r['case']: r['rate_error_rms_rad_s'] for r in doc['records']}, doc['settings']


@pytest.mark.slow
def test_the_feedforwards_configuration_does_not_move_the_truth_and_a_wrong_lubricant_costs(tmp_path, capsys):
    """--config with another lubricant (walther_a 0.03 below the truth's) changes the feedforward, not the truth:
    the uncompensated run is the same, the feedforward's error grows (the truth's lubricant is 8.6345)."""
    right, wrong = tmp_path / 'right.yaml', tmp_path / 'wrong.yaml'
    right.write_text('/**:\n  ros__parameters:\n    model:\n      walther_a: 8.6345\n')
    wrong.write_text('/**:\n  ros__parameters:\n    model:\n      walther_a: 8.6045\n')
    good, settings = _records(capsys, '--config', str(right))
    bad, _ = _records(capsys, '--config', str(wrong))
    assert bad['none'] == pytest.approx(good['none'], rel=1e-12)
    assert bad['feedforward'] > 1.3 * good['feedforward']
    assert settings['truth_differs_from_default'] == {}


@pytest.mark.slow
def test_truth_file_sets_the_simulated_truth_and_refuses_other_parameters(tmp_path, capsys):
    base, _ = _records(capsys)
    truth = tmp_path / 'truth.yaml'
    truth.write_text('gimbal_sim:\n  ros__parameters:\n    truth_walther_a: 8.6045\n    temperature_bias_c: 3.0\n')
    thin, settings = _records(capsys, '--truth', str(truth))
    assert settings['truth_differs_from_default'] == {'truth_walther_a': 8.6045, 'temperature_bias_c': 3.0}
    assert thin['none'] < 0.9 * base['none']          # a thinner truth lubricant: less friction in the cold
    bad = tmp_path / 'bad.yaml'
    bad.write_text('rate_bandwidth_hz: 30.0\n')
    assert main([*SHORT, '--truth', str(bad)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'rate_bandwidth_hz' in err[0] and 'not a truth parameter' in err[0]
    assert '--config' in err[0]


def test_without_a_terminal_each_stage_is_one_line_on_stderr(capsys):
    """Minutes of work are never silent: stderr that is not a terminal (a log, a pipe) gets one short line per stage
    with the time so far."""
    assert main([*SHORT, '--temperatures', '20', '--cases', 'none,feedforward']) == 0
    err = capsys.readouterr().err.splitlines()
    stages = [line for line in err if line.startswith('loop-study: ')]
    assert any(line.startswith('loop-study: tracking (none, feedforward) (') for line in stages), err
    assert stages[-1].startswith('loop-study: done (') and stages[-1].endswith('100 % done)'), err


def test_progress_lines_come_at_each_stage_and_every_so_often_within_a_long_one():
    import io

    from gimbal_friction.cli.loop_study_cmd import StageProgress
    now = [100.0]
    out = io.StringIO()
    show = StageProgress(100.0, stream=out, every_s=30.0, clock=lambda: now[0])
    for t, stage, frac in ((101, 'history', 0.01), (110, 'history', 0.1), (131, 'history', 0.3),
                           (140, 'history', 0.4), (141, 'tracking', 0.6), (150, 'done', 1.0)):
        now[0] = float(t)
        show(stage, frac)
    assert out.getvalue().splitlines() == [
        'loop-study: history (1 s, 1 % done)', 'loop-study: history (31 s, 30 % done)',   # (and not at 110, 140 s)
        'loop-study: tracking (41 s, 60 % done)', 'loop-study: done (50 s, 100 % done)']


def _record(case: str, profile: str, t_c: float, rms: float) -> dict:
    return {'case': case, 'profile': profile, 'temperature_c': t_c, 'rate_error_rms_rad_s': rms,
            'reversal_error_peak_rad': 1e-4, 'mode': 'offline'}


def test_the_table_labels_the_learning_run_and_explains_the_goal_names_it_prints():
    from gimbal_friction.runs.loop_study import LEARNING_RUN_TITLE, table_text
    doc = {'records': [_record('none', 'tracking', -40.0, 4e-3), _record('refit', 'tracking', -40.0, 1e-3),
                       _record('ideal', 'tracking', -40.0, 2e-4), _record('learning', 'history', -40.0, 0.452)],
           'goals': [{'goal': 'd_near_e_cold', 'profile': 'tracking', 'temperature_c': -40.0, 'value': 5.0,
                      'target': 1.2, 'met': False},
                     {'goal': 'c_vs_a_cold', 'profile': 'tracking', 'temperature_c': -40.0, 'value': 0.1,
                      'target': 0.6, 'met': False}]}
    lines = table_text(doc).splitlines()
    # the learning run is in a table of its own whose title says it is not a scored case
    title = lines.index(LEARNING_RUN_TITLE)
    assert 'not a scored case' in LEARNING_RUN_TITLE
    rows = [i for i, line in enumerate(lines) if line.split()[:1] == ['learning'] and i != title]
    assert rows == [title + 3] and '452.000 (0.10)' in lines[title + 3]   # (title, header, rule, the row)
    # every goal name printed is explained there
    assert '  d_near_e_cold: refit <= 1.2 x ideal at -40 degC' in lines
    assert any(line.startswith('  c_vs_a_cold: feedforward cuts') for line in lines)


def test_the_truths_table_explains_its_goal_names():
    from gimbal_friction.runs.truth_study import truths_text
    frac = {'met': 1, 'cells': 2, 'fraction': 0.5, 'truths_all_met': 0, 'worst': 1.2,
            'worst_at': {'seed': 3, 'profile': 'tracking', 'temperature_c': -40.0}}
    text = truths_text({'n': 1, 'first_seed': 3, 'short': True, 'fractions': {'learned_vs_ff': frac},
                        'truths': [{'describe': 'truth 3', 'goals': [{'goal': 'learned_vs_ff', 'met': False}]}]})
    assert '  learned_vs_ff: learned <= 1.05 x the plain feedforward' in text.splitlines(), text
