"""Refit on sufficient statistics (refit.sufficient + refit.fit): equal to the per-sample refit, associative,
the direction asymmetry and the calibration offset.

Synthetic samples as in test_refit.py: plateaus with 0.05 degC sensor noise, both directions, +/-5 % position
ripple, 0.1 mN*m white noise, stamps at 100 Hz.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gimbal_friction.common.errors import FitError
from gimbal_friction.common.units import RAD_S_PER_RPM
from gimbal_friction.physics.direction import ARRAY, direction_factor
from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import refit_model, refit_stats
from gimbal_friction.refit.sufficient import SufficientStats, accumulate_rows
from gimbal_friction.streams.residual_row import ResidualRows

PLATEAUS = (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0)


def samples(truth, plateaus=PLATEAUS, n_per=400, offset_nm=0.0, seed=1, noise_nm=1e-4, rate_hz=100.0):
    """(t, n, y, d, stamp) of the truth (with its direction factor) plus a constant offset [N*m]."""
    rng = np.random.default_rng(seed)
    cols: list[list[np.ndarray]] = [[], [], [], [], []]
    clock = 0.0
    for plateau in plateaus:
        for _ in range(4):                       # sweeps alternate direction
            for d in (1.0, -1.0):
                t = plateau + rng.normal(0.0, 0.05, n_per // 4)
                pos = np.linspace(0.0, 0.3, n_per // 4)
                tau = friction_torque(truth, t, 1 / 3).m_total_nmm * 1e-3 * direction_factor(truth, t, d, ARRAY)
                tau = tau * (1.0 + 0.05 * np.sin(2.0 * np.pi * pos / 0.06)) + offset_nm
                cols[0].append(t)
                cols[1].append(np.full(t.size, 1 / 3))
                cols[2].append(tau + rng.normal(0.0, noise_nm, t.size))
                cols[3].append(np.full(t.size, d))
                cols[4].append(clock + np.arange(t.size) / rate_hz)
                clock += t.size / rate_hz
    return tuple(np.concatenate(c) for c in cols)


@pytest.fixture(scope='module')
def data():
    """10 Hz stamps: each (plateau, direction) group spans 40 one-second batches (a real plateau: thousands)."""
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.02)
    return truth, samples(truth, rate_hz=10.0)


def test_binned_refit_equals_the_per_sample_refit(data):
    _truth, (t, n, y, d, stamp) = data
    names = ('walther_a', 'palmgren_factor', 'sliding_friction_coefficient')
    binned = refit_model(AxisParams(), t, n, y, d, fit=names, time_s=stamp)
    exact = refit_model(AxisParams(), t, n, y, d, fit=names, time_s=stamp, exact=True)
    assert binned.n_bins < t.size / 10 and exact.n_bins == t.size
    for name in names:
        assert binned.identifiability[name] == exact.identifiability[name]
        # stated tolerance: 2 % of the parameter's own standard error (bin curvature, cell-level batch split)
        assert abs(binned.fitted[name] - exact.fitted[name]) < 0.02 * exact.standard_errors[name], name
        assert binned.standard_errors[name] == pytest.approx(exact.standard_errors[name], rel=0.05), name
    assert binned.rms_after_nm == pytest.approx(exact.rms_after_nm, rel=1e-3)
    for a, b in zip(binned.bins, exact.bins, strict=True):
        assert (a.temperature_bin_c, a.direction, a.n) == (b.temperature_bin_c, b.direction, b.n)
        assert a.measured_mean_nm == pytest.approx(b.measured_mean_nm, rel=1e-12)
        assert a.model_after_nm == pytest.approx(b.model_after_nm, rel=1e-5)
        assert a.measured_se_nm == pytest.approx(b.measured_se_nm, rel=0.1)


def test_statistics_merge_in_any_grouping(data):
    _, (t, n, y, d, stamp) = data
    whole = SufficientStats.from_arrays(t, n, y, d, time=stamp)
    cuts = [0, 1234, 5000, 5001, 9000, t.size]
    parts = [SufficientStats.from_arrays(t[a:b], n[a:b], y[a:b], d[a:b], time=stamp[a:b])
             for a, b in itertools.pairwise(cuts)]
    left = parts[0].merge(parts[1]).merge(parts[2].merge(parts[3], parts[4]))
    right = parts[4].merge(parts[2], parts[0], parts[3]).merge(parts[1])
    for merged in (left, right):
        assert merged.n_samples == whole.n_samples
        for name in ('t_index', 'direction', 's_index', 'batch'):
            np.testing.assert_array_equal(getattr(merged, name), getattr(whole, name))
        np.testing.assert_array_equal(merged.samples, whole.samples)
        np.testing.assert_allclose(merged.mean_y, whole.mean_y, rtol=1e-12)
        np.testing.assert_allclose(merged.m2_y, whole.m2_y, rtol=1e-9, atol=1e-24)
        np.testing.assert_allclose(merged.sum_t, whole.sum_t, rtol=1e-12)
    a = refit_stats(AxisParams(), left)
    b = refit_stats(AxisParams(), whole)
    assert a.fitted['walther_a'] == pytest.approx(b.fitted['walther_a'], abs=1e-12)


def test_statistics_from_residual_rows_skip_and_count(data):
    _, (t, n, y, d, stamp) = data
    k = 600
    v = d[:k] * n[:k] * RAD_S_PER_RPM
    v[3] = 0.0
    temp = t[:k].copy()
    temp[5] = math.nan
    f = np.full(k, math.nan)
    cols = (np.array(['elevation'] * k), stamp[:k], temp, np.zeros(k), v, np.zeros(k), y[:k] * d[:k], f, f,
            np.zeros(k), np.full(k, 0.05), np.full(k, 0.002), np.zeros(k, dtype=np.int8))
    stats: dict[str, SufficientStats] = {}
    accumulate_rows(ResidualRows(*(c[:300] for c in cols)), stats)   # two chunks of a log
    accumulate_rows(ResidualRows(*(c[300:] for c in cols)), stats)
    s = stats['elevation']
    assert (s.tally.rows, s.tally.skipped_nonfinite, s.tally.skipped_standstill) == (k, 1, 1)
    assert s.n_samples == k - 2
    assert s.tally.torque_constant_nm_per_a == pytest.approx(0.05)
    assert s.tally.no_load_current_a == pytest.approx(0.002)
    ok = np.ones(k, dtype=bool)
    ok[[3, 5]] = False
    ref = SufficientStats.from_arrays(t[:k][ok], n[:k][ok], y[:k][ok], d[:k][ok], time=stamp[:k][ok])
    np.testing.assert_allclose(s.mean_y, ref.mean_y, rtol=1e-12)


@pytest.mark.slow
def test_direction_asymmetry_is_recovered_with_intervals():
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.02, direction_asymmetry_cold=0.13,
                         direction_asymmetry_warm=-0.12)
    t, n, y, d, stamp = samples(truth)
    res = refit_model(base, t, n, y, d, fit=('walther_a', 'direction_asymmetry_cold', 'direction_asymmetry_warm'),
                      time_s=stamp)
    for name in ('walther_a', 'direction_asymmetry_cold', 'direction_asymmetry_warm'):
        assert res.identifiability[name].identifiable, name
        lo, hi = res.confidence_intervals[name]
        assert lo <= getattr(truth, name) <= hi, name
    assert res.fitted['direction_asymmetry_cold'] == pytest.approx(0.13, abs=0.01)
    assert res.fitted['direction_asymmetry_warm'] == pytest.approx(-0.12, abs=0.01)
    assert float(viscosity_cst(res.params, -40.0)) == pytest.approx(float(viscosity_cst(truth, -40.0)), rel=0.03)
    # model (with its direction factor) vs measured: every plateau, both directions, within 2 %
    for b in res.bins:
        assert b.model_after_nm == pytest.approx(b.measured_mean_nm, rel=0.02), b
    # without the term the cold plateau is off by about the asymmetry in each direction
    plain = refit_model(base, t, n, y, d, time_s=stamp)
    cold = [b for b in plain.bins if b.temperature_bin_c == -40.0]
    assert max(abs(b.model_after_nm / b.measured_mean_nm - 1.0) for b in cold) > 0.1


def test_asymmetry_needs_both_directions_and_its_anchor_range():
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.02)
    t, n, y, d, _stamp = samples(truth, plateaus=(-40.0, -20.0))
    pos = d > 0
    res = refit_model(base, t[pos], n[pos], y[pos], d[pos], fit=('walther_a', 'direction_asymmetry_cold'))
    assert res.identifiability['direction_asymmetry_cold'].reason == 'needs samples moving in both directions'
    cold = t < -39.0  # only at the cold anchor: the warm anchor has no effect there
    res = refit_model(base, t[cold], n[cold], y[cold], d[cold],
                      fit=('walther_a', 'direction_asymmetry_cold', 'direction_asymmetry_warm'))
    ident = res.identifiability['direction_asymmetry_warm']
    assert not ident.identifiable and ('standard error' in ident.reason or 'above direction_asymmetry_cold_c' in
                                       ident.reason)
    assert res.identifiability['direction_asymmetry_cold'].identifiable
    above = refit_model(base, t[t < -40.0], n[t < -40.0], y[t < -40.0], d[t < -40.0],
                        fit=('walther_a', 'direction_asymmetry_warm'))
    assert 'above direction_asymmetry_cold_c = -40 degC' in above.identifiability['direction_asymmetry_warm'].reason


@pytest.mark.slow
def test_offset_keeps_the_viscosity_when_the_calibration_is_off():
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.02)
    kt, sigma_i0 = 0.05, 1.5e-3                    # calibration: I_0 known to 1.5 mA (T_0 to 0.075 N*mm)
    c = -kt * 2.0 * sigma_i0                       # I_0 configured 2 sigma too high: |tau| low by 0.15 N*mm
    t, n, y, d, stamp = samples(truth, offset_nm=c)
    nu_truth = float(viscosity_cst(truth, -40.0))
    res = refit_model(base, t, n, y, d, time_s=stamp, calibration_se_nm=kt * sigma_i0)
    assert res.offset.estimated and res.offset.mode == 'auto'
    lo, hi = res.offset.confidence_interval_nm
    assert lo <= c <= hi
    assert float(viscosity_cst(res.params, -40.0)) == pytest.approx(nu_truth, rel=0.05)
    assert res.offset.exceeds_calibration is True
    assert len(res.warnings) == 1 and 'exceeds the calibration uncertainty' in res.warnings[0]
    assert res.offset.implied_no_load_current_a == pytest.approx(c / kt, abs=2e-4)  # I_0 in the data: 0
    # switched off, the offset leaks into the viscosity
    off = refit_model(base, t, n, y, d, time_s=stamp, offset='off')
    assert not off.offset.estimated and off.offset.reason == 'switched off'
    assert abs(float(viscosity_cst(off.params, -40.0)) / nu_truth - 1.0) > 0.05
    # within the calibration's uncertainty: no warning
    small = refit_model(base, *samples(truth, offset_nm=-0.3 * kt * sigma_i0)[:4], calibration_se_nm=kt * sigma_i0)
    assert small.offset.exceeds_calibration is False and small.warnings == ()


def test_offset_auto_needs_cold_and_warm_plateaus():
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.02)
    t, n, y, d, _ = samples(truth, plateaus=(-40.0,))
    res = refit_model(base, t, n, y, d)
    assert not res.offset.estimated and res.offset.reason.startswith('auto: off')
    with pytest.raises(FitError, match='offset'):
        refit_model(base, t, n, y, d, offset='sometimes')


def test_offset_gives_way_to_a_requested_palmgren_factor(data):
    _truth, (t, n, y, d, stamp) = data
    res = refit_model(AxisParams(), t, n, y, d, fit=('walther_a', 'palmgren_factor'), time_s=stamp)
    assert res.identifiability['palmgren_factor'].identifiable
    assert not res.offset.estimated and 'palmgren_factor is fitted' in res.offset.reason
    both = refit_model(AxisParams(), t, n, y, d, fit=('walther_a', 'palmgren_factor'), time_s=stamp, offset='on')
    # the warm Palmgren floor is (nearly) a constant torque: either the offset is held, or both carry intervals
    assert (not both.offset.estimated and 'collinear' in both.offset.reason) or both.offset.standard_error_nm > 0.0
