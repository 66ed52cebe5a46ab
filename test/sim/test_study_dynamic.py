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
