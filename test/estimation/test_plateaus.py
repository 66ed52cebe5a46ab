"""The one plateau rule (estimation/plateaus.py): which samples belong to which plateau (summary and refit)."""

from __future__ import annotations

import numpy as np

from gimbal_friction.estimation.plateaus import plateau_of
from gimbal_friction.estimation.residuals import plateau_summary
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import refit_model


def _chamber(seed: int = 0):
    """10 Hz samples: -40 degC held 120 s, a 15 degC/min ramp to +20, +20 held 120 s; both directions alternate
    every 5 s; the package model's friction at 1/3 rpm [N*m]."""
    rng = np.random.default_rng(seed)
    time = np.arange(0.0, 480.0, 0.1)
    t = np.interp(time, [0.0, 120.0, 360.0, 480.0], [-40.0, -40.0, 20.0, 20.0]) + rng.normal(0.0, 0.05, time.size)
    sign = np.where((time // 5.0) % 2 == 0, 1.0, -1.0)
    v = sign * 2.0 * np.pi / 180.0
    y = friction_torque(AxisParams(), t, 1 / 3).m_total_nmm * 1e-3 + rng.normal(0.0, 1e-5, time.size)
    return time, t, v, sign * y


def test_plateaus_count_every_sample_of_their_bin_and_ramps_are_not_plateaus():
    time, t, v, m = _chamber()
    summary = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time)
    assert sorted({r['plateau_c'] for r in summary}) == [-40.0, 20.0]  # the ramp's bins are no plateaus
    bins = plateau_of(t, 5.0)
    for r in summary:
        sel = (bins == r['plateau_c']) & (np.sign(v) == r['sign'])
        assert r['samples'] == int(sel.sum())  # every sample of the bin, the ramp's end included
    # the refit groups the same samples into the same bins
    res = refit_model(AxisParams(), t,
                      np.abs(v) * 30.0 / np.pi, m * np.sign(v), np.sign(v), time_s=time, offset='off')
    counts: dict[tuple[float, int], int] = {}
    for b in res.bins:
        counts[(b.temperature_bin_c, b.direction)] = counts.get((b.temperature_bin_c, b.direction), 0) + b.n
    for r in summary:
        assert counts[(r['plateau_c'], r['sign'])] == r['samples']


def test_a_temperature_stream_on_another_clock_does_not_change_the_plateaus():
    """The summary judges steadiness on the samples' own temperatures: no second time base to misalign."""
    time, t, v, m = _chamber(1)
    own = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time)
    shifted = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time + 1e9)
    assert [(r['plateau_c'], r['direction'], r['samples']) for r in own] == \
        [(r['plateau_c'], r['direction'], r['samples']) for r in shifted]
    assert len(own) == 4
