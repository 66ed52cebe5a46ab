"""Case ``dynamic`` of the loop study: the learned correction plus the pre-sliding term learned from the same
service history; the compensator is exactly the learned feedforward where the term is off."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.feedforward.presliding import PreslidingSettings, PreslidingTerm
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.compensation import CASES, ControllerInputs, dynamic_feedforward, suite_feedforward
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.study import REPORT_ORDER, FeedforwardSetup, run_study

AUTO = FeedforwardSetup(velocity_source='auto')


def _inputs(k: int, v: np.ndarray) -> ControllerInputs:
    n = v.size
    return ControllerInputs(k * 1e-3, np.full(n, -40.0), np.zeros(n), np.zeros(n), v, v, v)


def test_the_case_is_known_in_report_order():
    assert 'dynamic' in CASES and REPORT_ORDER.index('dynamic') == REPORT_ORDER.index('learned') + 1


def test_off_the_dynamic_feedforward_is_the_static_one_and_on_it_switches_with_displacement():
    axis = AxisParams()
    v = np.array([0.03, -0.03, 1e-3])
    static = suite_feedforward(axis, velocity_source='reference').torque
    term = PreslidingTerm(PreslidingSettings(), ('elevation',))      # nothing learned: off everywhere
    off = dynamic_feedforward(axis, velocity_source='reference', presliding=term).torque
    for k in range(3):
        assert np.array_equal(off(_inputs(k, v)), static(_inputs(k, v)))
    term.distances['elevation'][:] = 1e-5                              # applied everywhere
    on = dynamic_feedforward(axis, velocity_source='reference', presliding=term).torque
    first = on(_inputs(0, v))
    assert np.array_equal(first, static(_inputs(0, v)))               # starts at the static sign
    # a reversal: 1 mrad/s for 10 ticks moves 10 urad = one distance: s = 1 - 2/e (from -1), not tanh(0.5)
    rev = np.array([-0.03])
    on(_inputs(1, rev))
    for k in range(2, 12):
        out = on(_inputs(k, np.array([1e-3])))
    level = float(static(_inputs(12, np.array([1e-3])))[0]) / np.tanh(0.5)       # k_d M at 1 mrad/s
    assert float(out[0]) == pytest.approx((1.0 - 2.0 * np.exp(-1.0)) * level, rel=1e-6)


@pytest.mark.slow
def test_the_dynamic_case_runs_from_the_service_history_and_is_never_much_worse_than_learned():
    res = run_study(SimConfig(), temperatures=[20.0], profiles=['scan'], cases=['learned', 'dynamic'], short=True,
                    feedforward=AUTO)
    rms = {r['case']: r['rate_error_rms_rad_s'] for r in res.records if r['profile'] == 'scan'}
    assert set(rms) >= {'learned', 'dynamic'}
    assert rms['dynamic'] <= 1.05 * rms['learned']
    assert res.presliding is not None
    assert any(n.startswith('dynamic (pre-sliding term') for n in res.notes)


def _rec(case: str, t: float, rms: float, rev: float) -> dict[str, object]:
    return {'case': case, 'temperature_c': t, 'profile': 'tracking', 'rate_error_rms_rad_s': rms,
            'reversal_error_peak_rad': rev}


def test_the_dynamic_goals_are_judged_where_the_issue_says():
    from gimbal_friction.sim.study import goal_checks
    recs = [_rec('learned', -40.0, 0.6, 3e-5), _rec('dynamic', -40.0, 0.3, 2e-5), _rec('bound', -40.0, 0.6, 3e-5),
            _rec('ideal', -40.0, 0.17, 2e-5),
            _rec('learned', -20.0, 0.3, 3e-5), _rec('dynamic', -20.0, 0.33, 3e-5), _rec('bound', -20.0, 0.3, 3e-5),
            _rec('ideal', -20.0, 0.2, 2e-5),     # ideal > 0.5 x bound: no cold goal here
            _rec('learned', 20.0, 0.3, 3e-5), _rec('dynamic', 20.0, 0.2, 3e-5), _rec('bound', 20.0, 0.3, 3e-5),
            _rec('ideal', 20.0, 0.1, 2e-5)]      # not a cold plateau: no cold goal
    got = {(g['goal'], g['temperature_c']): (round(g['value'], 3), g['met']) for g in goal_checks(recs)
           if g['goal'].startswith('dynamic')}
    assert got == {('dynamic_vs_learned', -40.0): (0.5, True), ('dynamic_vs_learned', -20.0): (1.1, False),
                   ('dynamic_vs_learned', 20.0): (0.667, True), ('dynamic_vs_bound_cold', -40.0): (0.5, True),
                   ('dynamic_reversal_cold', -40.0): (0.667, True)}


def test_the_identification_reads_the_estimators_samples_through_a_reversal_and_the_feedforwards_own_inputs():
    from gimbal_friction.estimation.estimator import EstimatorSettings
    from gimbal_friction.sim.engine import Run, simulate
    from gimbal_friction.sim.profiles import make_profile
    from gimbal_friction.sim.study import presliding_runs
    cfg = SimConfig().replace(tracking_duration_s=5.5)
    axis = AxisParams()
    prof = make_profile(cfg, 'tracking')
    res = simulate(cfg, axis, prof, [Run('feedforward', -40.0)], {'feedforward': AUTO.compensator(axis)})
    (run,) = presliding_runs(res, [0], axis, AUTO, None, EstimatorSettings())
    assert np.array_equal(run.velocity_rad_s, res.traces.reference_velocity_rad_s[:, 0])   # auto: the reference
    assert np.array_equal(run.even_nm, np.zeros(run.time_s.size))                          # no correction
    assert np.all(run.level_nm > 0.0)
    t_rev = prof.reversal_times_s[0]
    near = (np.abs(run.time_s - t_rev) < 0.05) & (np.abs(res.traces.joint_velocity_rad_s[:, 0]) < 0.005)
    # the samples the static path refuses (slower than the observer's 0.01 rad/s) are there
    assert np.count_nonzero(np.isfinite(run.friction_nm[near])) > 10
