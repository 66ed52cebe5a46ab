"""The main job on a short synthetic bag: three live nodes + chamber_replay, then refit and report.

Also checks that the offline ``replay`` of the same bag gives the live nodes' numbers for the same samples.
"""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.chamber.replay import replay_bag
from gimbal_friction.chamber.synth import SynthConfig
from gimbal_friction.cli import demo
from gimbal_friction.cli.main import main
from gimbal_friction.config.loader import axis_params, load_parameters
from gimbal_friction.recording.residual_read import read_residual_rows

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp('bag') / 'bag'
    assert main(['synth-bag', '--out', str(bag), '--plateaus=-40,20', '--hold-s', '30', '--joint-rate-hz', '25',
                 '--seed', '7', '--format', 'json']) == 0
    return bag


@pytest.fixture(scope='module')
def pipeline(tmp_path_factory, short_bag):
    out = tmp_path_factory.mktemp('pipeline') / 'demo'
    assert demo.main(['--bag', str(short_bag), '--rate', '20', '--out', str(out)]) == 0
    return short_bag, out


def test_main_job_outputs_and_refit_moves_toward_truth(pipeline, capsys):
    _bag, out = pipeline
    capsys.readouterr()
    assert (out / 'residuals' / 'metadata.yaml').exists()  # closed cleanly by SIGINT
    rows, report = read_residual_rows([out / 'residuals'])
    assert len(rows) > 2000 and not report.truncated_files
    figures = sorted(p.name for p in (out / 'figures').glob('*.png'))
    assert 'fig13_model_vs_measured.png' in figures and 'fig11_components.png' in figures
    truth = SynthConfig().truth_params()
    base = axis_params(load_parameters(), 'elevation')
    refit = axis_params(load_parameters([out / 'refit.yaml']), 'elevation')
    assert truth.walther_a != base.walther_a
    assert abs(refit.walther_a - truth.walther_a) < 0.5 * abs(base.walther_a - truth.walther_a)
    for name in ('friction_feedforward', 'friction_estimator', 'residual_logger', 'chamber_replay'):
        text = (out / 'logs' / f'{name}.log').read_text()
        assert 'Traceback' not in text, name


def test_offline_replay_gives_the_live_numbers(pipeline, tmp_path):
    """Live nodes and the offline replay of the same bag: the same samples, the same numbers (one code path, one
    freshness rule on stamps), to the transport: a sample DDS dropped at 20x is missing, nothing differs."""
    bag, out = pipeline
    live, _ = read_residual_rows([out / 'residuals'])
    offline = replay_bag(bag, None).rows
    key_live = {(j, round(s * 1e6)): i for i, (j, s) in enumerate(zip(live.joint.tolist(), live.stamp_s.tolist()))}
    pairs = [(key_live[(j, round(s * 1e6))], i) for i, (j, s) in
             enumerate(zip(offline.joint.tolist(), offline.stamp_s.tolist())) if (j, round(s * 1e6)) in key_live]
    li = np.array([a for a, _ in pairs])
    oi = np.array([b for _, b in pairs])
    assert len(pairs) >= 0.9 * min(len(live), len(offline)), (len(pairs), len(live), len(offline))
    for name in ('measured_nm', 'current_a', 'position_rad', 'velocity_rad_s', 'torque_constant_nm_per_a'):
        np.testing.assert_array_equal(getattr(live, name)[li], getattr(offline, name)[oi], err_msg=name)
    np.testing.assert_array_equal(live.temperature_c[li], offline.temperature_c[oi])
    both = np.isfinite(live.predicted_nm[li])
    assert both.mean() > 0.9
    np.testing.assert_allclose(live.predicted_nm[li][both], offline.predicted_nm[oi][both], rtol=1e-12, atol=0.0)


def test_the_main_job_says_what_the_live_nodes_counted(pipeline):
    """demo.json (and the printed account) hold what each live node counted, from its own /diagnostics once the
    counts settled: what chamber_replay sent is the bag; each node's received + lost is what was sent (the logger
    counts what never arrived against the replay's count); the rows the logger says it logged are the log's."""
    import json

    from gimbal_friction.recording import topics
    from gimbal_friction.recording.bag import open_chamber_bag
    bag, out = pipeline
    live = json.loads((out / 'demo.json').read_text())['live']
    assert live['settled']
    in_bag = {t: open_chamber_bag(bag).topics[t].messages for t in topics.CHAMBER_TOPICS}
    assert live['chamber_replay'] == {'state': 'finished', 'sent': in_bag}
    logger = live['residual_logger']
    for topic, n in in_bag.items():
        got = logger['transport'][topic]
        assert got['received'] + got['lost'] == n == logger['sent'][topic], topic
    rows, _ = read_residual_rows([out / 'residuals'])
    assert logger['residuals_logged'] == len(rows)
    assert logger['paired_with_feedforward'] == int(np.isfinite(rows.predicted_nm).sum())
    assert live['friction_estimator']['accepted'] >= logger['residuals_logged'] > 0
    assert live['friction_feedforward']['published'] > 0 and live['friction_feedforward']['reports'] > 0


def test_a_stale_temperature_at_the_feedforward_is_named_by_the_main_job_and_its_report(short_bag, tmp_path,
                                                                                       monkeypatch, capsys):
    """What a busy machine does to the live feedforward (its joint states late, its temperature stale: the
    fallback temperature is used), made certain here by a feedforward whose temperature is fresh for 1 ms only:
    the main job says the live run degraded and why, from the feedforward's own reports, and the report's table
    names the plateau where the feedforward as published is not the model at the plateau's temperature. The
    main job used to print the same lines as for a clean run."""
    import contextlib

    from gimbal_friction.runs.supervisor import packaged_params_file

    @contextlib.contextmanager
    def stale_feedforward():
        with packaged_params_file() as packaged:
            params = tmp_path / 'params.yaml'
            params.write_text(packaged.read_text() + '\nfriction_feedforward:\n  ros__parameters:\n'
                              '    temperature_timeout_s: 0.001\n')
            yield params

    monkeypatch.setattr(demo, 'packaged_params_file', stale_feedforward)
    capsys.readouterr()
    assert demo.main(['--bag', str(short_bag), '--rate', '20', '--out', str(tmp_path / 'demo')]) == 0
    out = capsys.readouterr().out
    verdict = next(line for line in out.splitlines() if 'the live run' in line).strip()
    assert verdict.startswith('the live run degraded: friction_feedforward') and 'had no fresh temperature' in verdict
    assert 'fallback_temperature' in verdict
    note = next(line for line in out.splitlines() if line.startswith('note: the feedforward as published differs'))
    assert 'degC cw' in note
