"""Case ``chamber`` on a gimbal with an unbalance at every plateau (a constant torque and one with the angle, both
independent of the direction): the chamber's correction never makes a cell worse than the plain feedforward
(issue 33 item 3; before, one plateau of the short chamber test applied half the unbalance as a friction change: up
to 15x the feedforward)."""

from __future__ import annotations

import pytest

from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.study import FeedforwardSetup, run_study


@pytest.mark.slow
def test_the_chamber_case_is_never_worse_than_the_feedforward_with_an_unbalance_at_every_plateau():
    from gimbal_friction.chamber.learned import chamber_correction
    cfg = SimConfig().replace(disturbance_torque_nm=-1.5e-3, unbalance_torque_nm=2e-3, unbalance_phase_rad=-1.2)
    res = run_study(cfg, cases=['feedforward', 'chamber'], short=True,
                    feedforward=FeedforwardSetup(velocity_source='auto'), chamber=chamber_correction)
    rms = {(r['case'], r['profile'], r['temperature_c']): r['rate_error_rms_rad_s'] for r in res.records}
    cells = [(p, t) for c, p, t in rms if c == 'chamber']
    assert len(cells) == 24
    ratio = {cell: rms[('chamber', *cell)] / rms[('feedforward', *cell)] for cell in cells}
    assert max(ratio.values()) <= 1.05, sorted(ratio.items(), key=lambda kv: -kv[1])[:4]
    # and it learned the unbalance where it could tell it apart: most cells well below the feedforward
    assert sum(q < 0.9 for q in ratio.values()) >= 12
    assert res.learned is not None and res.learned['chamber'].summary()['max_abs_unbalance_nm'] > 1e-3
