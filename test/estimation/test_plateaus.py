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


def test_without_a_temperature_stream_the_samples_own_temperatures_stand_in():
    """A log without its inputs has no temperature stream: steadiness is judged on the samples' own temperatures
    (per joint), so it needs no second time base and does not depend on the clock of the stamps."""
    time, t, v, m = _chamber(1)
    own = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time)
    shifted = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time + 1e9)
    assert [(r['plateau_c'], r['direction'], r['samples']) for r in own] == \
        [(r['plateau_c'], r['direction'], r['samples']) for r in shifted]
    assert len(own) == 4


def _short_sweeps(seed: int = 0):
    """The issue's chamber test as arrays: -40, 0, +60 degC; the bearing temperature stream (2 Hz) held within
    +/-0.1 degC for 90 s at each plateau (a 60 s soak, then the measurement), 15 degC/min ramps between; the axis
    still but for one 7 s sweep each way per plateau (samples at 100 Hz, the package model's friction [N*m])."""
    rng = np.random.default_rng(seed)
    knots_t, knots_c, sweeps = [0.0], [-40.0], []
    for c in (-40.0, 0.0, 60.0):
        if c != knots_c[-1]:                                   # a 15 degC/min ramp from the plateau before
            knots_t.append(knots_t[-1] + abs(c - knots_c[-1]) * 4.0)
            knots_c.append(c)
        sweeps.append(knots_t[-1] + 60.0)                      # soak 60 s, then sweep cw 7 s and ccw 7 s
        knots_t.append(knots_t[-1] + 90.0)
        knots_c.append(c)
    stream_t = np.arange(0.0, knots_t[-1], 0.5)
    stream_c = np.interp(stream_t, knots_t, knots_c) + rng.uniform(-0.05, 0.05, stream_t.size)
    time = np.concatenate([start + np.arange(0.0, 14.0, 0.01) for start in sweeps])
    sign = np.where(((time - np.repeat(sweeps, 1400)) < 7.0), 1.0, -1.0)
    t = np.interp(time, stream_t, stream_c)
    y = friction_torque(AxisParams(), t, 1 / 3).m_total_nmm * 1e-3 + rng.normal(0.0, 1e-5, time.size)
    return time, t, sign * 2.0 * np.pi / 180.0, sign * y, (stream_t, stream_c)


def test_a_plateau_whose_temperature_held_counts_however_short_its_sweeps():
    """Issue 8: with a 60 s soak and one 7 s sweep each way, the samples' own temperatures span only 14 s; judged on
    the temperature stream every plateau and direction is listed, with every one of its samples (the refit's)."""
    time, t, v, m, stream = _short_sweeps()
    summary = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time, temperature_stream=stream)
    assert [(r['plateau_c'], r['direction'], r['samples']) for r in summary] == [
        (p, d, 700) for p in (-40.0, 0.0, 60.0) for d in ('cw', 'ccw')]
    res = refit_model(AxisParams(), t, np.abs(v) * 30.0 / np.pi, m * np.sign(v), np.sign(v), time_s=time,
                      offset='off')
    assert sorted((b.temperature_bin_c, b.direction, b.n) for b in res.bins) == sorted(
        (r['plateau_c'], r['sign'], r['samples']) for r in summary)
    # the samples alone cannot show the hold: without the stream these sweeps make no plateau
    assert plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time) == []


def test_a_ramp_in_the_temperature_stream_is_no_plateau_however_the_samples_look():
    """The other way round: samples taken while the stream ramps (3 degC/min) are no plateau, whatever their own
    temperatures say; readings outside the estimator's valid range are left out of the stream, not taken as a ramp."""
    from gimbal_friction.estimation.plateaus import temperature_stream

    time, t, v, m, (st, sc) = _short_sweeps(1)
    ramp = (st, sc + 0.05 * st)                                  # 3 degC/min on top of everything
    assert plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time, temperature_stream=ramp) == []
    dropout = np.where((st >= 295.0) & (st <= 305.0), 1e6, sc)   # 10 s of absurd readings before the 0 degC sweeps
    raw = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time, temperature_stream=(st, dropout))
    assert {r['plateau_c'] for r in raw} == {-40.0, 60.0}
    valid = temperature_stream(st, dropout, -60.0, 120.0)         # the estimator's valid range: they are skipped
    summary = plateau_summary(t, v, m, np.full(t.shape, np.nan), stamp_s=time, temperature_stream=valid)
    assert {r['plateau_c'] for r in summary} == {-40.0, 0.0, 60.0}
