"""The study's case ``learned`` judged by the loop (sim/study.py, feedforward/correction/judge.py): on a truth where
the residual guard alone makes the loop worse than the plain feedforward, the loop's judge keeps it within the
margin; the judge sees the learning run's measured loop error and the frozen correction applies its cells only."""

from __future__ import annotations

import pytest

from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.study import LearnSetup, run_study, study_settings
from gimbal_friction.sim.truths import draw_truth

#: a generated truth (Stribeck 0.0085 rad/s ×1.96, an unbalance of -2 N·mm + 1.5 N·mm sin θ at every plateau, an
#: inertia 18 % off, a lagging sensor) on which the residual guard alone is worse than the plain feedforward at +20 °C
TRUTH_SEED = 504
MARGIN = 1.05


def _ratios(res) -> dict[str, float]:
    rms = {(r['profile'], r['case']): r['rate_error_rms_rad_s'] for r in res.records}
    return {p: rms[(p, 'learned')] / rms[(p, 'feedforward')] for p in ('tracking', 'scan')}


@pytest.mark.slow
def test_the_loop_judge_keeps_learning_within_the_margin_where_the_residual_guard_alone_did_not():
    cfg = draw_truth(TRUTH_SEED).config(SimConfig())
    kw = {'temperatures': [20.0], 'profiles': ['tracking', 'scan'], 'cases': ['feedforward', 'learned'],
          'short': True}
    guard = run_study(cfg, learn=LearnSetup(judge=None), **kw)
    judged = run_study(cfg, **kw)
    worse = _ratios(guard)
    assert max(worse.values()) > 1.1, worse            # the premise: the residual guard alone hurts here
    ratios = _ratios(judged)
    assert max(ratios.values()) <= MARGIN, ratios
    assert guard.judges is None and judged.judges is not None
    judge = judged.judges['history']
    assert judge.frozen and judge.samples > 10000
    assert any('judged by the loop' in n for n in judged.notes)
    assert any('not judged by the loop' in n for n in guard.notes)
    (learning,) = [r for r in judged.records if r['case'] == 'learning']
    assert learning['learning_worst_window_ratio'] <= 1.1   # the cost of the test itself


def test_the_study_judges_with_the_nodes_defaults_and_says_when_it_does_not():
    assert 'learning_judge' not in study_settings(LearnSetup())['differs_from_node_default']
    off = study_settings(LearnSetup(judge=None))['differs_from_node_default']
    assert off['learning_judge'] == {'study': 'off', 'node': 'auto'}
