"""Refit of the lubricant parameters (refit.fit): recovery of a synthetic truth, identifiability, refusals.

The synthetic truth is the package model with ``walther_a`` shifted by +0.02 (ν(−40 °C) 44.7k -> 74k cSt);
samples sit on temperature plateaus (sensor noise 0.05 °C), both directions, with a position ripple of ±5 % and
white noise of 0.1 mN*m per sample (the synthetic chamber's 2 mA × K_T).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import FitError
from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import FIT_PARAMETERS, SampleModel, refit_model

PLATEAUS = (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0)
SHIFT = 0.02
VISCOSITY = ('walther_a', 'walther_b', 'viscosity_offset_cst')


def synth(plateaus=PLATEAUS, speeds=(1.0 / 3.0,), n_per=300, noise_nm=1e-4, ripple=0.05, seed=1, truth=None):
    """Samples of the truth model: (truth, temperature, speed, |measured| along the motion, direction)."""
    rng = np.random.default_rng(seed)
    base = AxisParams()
    truth = truth or base.replace(walther_a=base.walther_a + SHIFT)
    cols: list[list[np.ndarray]] = [[], [], [], []]
    for plateau in plateaus:
        for speed in speeds:
            for d in (1.0, -1.0):
                t = plateau + rng.normal(0.0, 0.05, n_per)
                position = np.linspace(0.0, math.radians(51.0), n_per)
                k = truth.scale_positive if d > 0 else truth.scale_negative
                tau = k * friction_torque(truth, t, speed).m_total_nmm * 1e-3
                tau = tau * (1.0 + ripple * np.sin(2.0 * np.pi * position / math.radians(3.4)))
                cols[0].append(t)
                cols[1].append(np.full(n_per, speed))
                cols[2].append(tau + rng.normal(0.0, noise_nm, n_per))
                cols[3].append(np.full(n_per, d))
    t, n, y, d = (np.concatenate(c) for c in cols)
    return truth, t, n, y, d


@pytest.fixture(scope='module')
def one_cold():
    return synth()


def test_recovers_walther_a_and_the_cold_viscosity(one_cold):
    truth, t, n, y, d = one_cold
    base = AxisParams()
    res = refit_model(base, t, n, y, d)
    a = res.fitted['walther_a']
    lo, hi = res.confidence_intervals['walther_a']
    assert lo <= truth.walther_a <= hi
    assert abs(a - truth.walther_a) < 1e-3
    assert res.identifiability['walther_a'].identifiable
    assert res.params.walther_a == a and res.params.walther_b == base.walther_b
    nu_truth, nu_fit = float(viscosity_cst(truth, -40.0)), float(viscosity_cst(res.params, -40.0))
    assert nu_fit == pytest.approx(nu_truth, rel=0.03)
    # before: the cold plateau is off by ~0.9 N*mm; after: only noise and ripple remain
    assert res.rms_before_nm > 3e-4 and res.rms_after_nm < 1.5e-4
    cold = [b for b in res.bins if b.temperature_bin_c == -40.0]
    assert {b.direction for b in cold} == {1, -1} and all(b.viscous for b in cold)
    assert all(abs(b.model_after_nm - b.measured_mean_nm) < 3 * b.measured_se_nm + 1e-5 for b in cold)
    assert not any(b.viscous for b in res.bins if b.temperature_bin_c > -30.0)
    assert res.viscous_temperatures_c == (-40.0,)
    (vi,) = res.viscosity
    assert vi.low_cst <= nu_truth <= vi.high_cst and vi.before_cst == pytest.approx(44702.0, rel=2e-3)
    assert res.n_samples == t.size and res.n_dropped == 0 and res.success
    assert len(res.bins) == 2 * len(PLATEAUS)


def test_one_cold_plateau_determines_only_walther_a(one_cold):
    truth, t, n, y, d = one_cold
    base = AxisParams()
    res = refit_model(base, t, n, y, d, fit=VISCOSITY)
    assert res.identifiability['walther_a'].identifiable
    for name in ('walther_b', 'viscosity_offset_cst'):
        ident = res.identifiability[name]
        assert not ident.identifiable
        assert str(ident).startswith('not identifiable: ')
        assert 'distinct temperature' in ident.reason and '-40' in ident.reason
        assert res.fitted[name] == getattr(base, name)          # held at the base value
        assert math.isnan(res.standard_errors[name])
        assert all(math.isnan(x) for x in res.confidence_intervals[name])
    assert set(res.refitted) == {'walther_a'}
    assert float(viscosity_cst(res.params, -40.0)) == pytest.approx(float(viscosity_cst(truth, -40.0)), rel=0.03)


@pytest.mark.parametrize('extra', ['second_cold_plateau', 'faster_runs'])
def test_more_viscous_data_determines_two_constants(extra):
    if extra == 'second_cold_plateau':
        truth, t, n, y, d = synth(plateaus=(-40.0, -35.0, -20.0, 0.0, 20.0, 40.0, 60.0))
        check_t = (-40.0, -35.0)
    else:
        truth, t, n, y, d = synth(speeds=(1.0 / 3.0, 20.0))   # 20 rpm: nu*n >= 2000 down to about 0 degC
        check_t = (-40.0, -20.0, 0.0)
    res = refit_model(AxisParams(), t, n, y, d, fit=VISCOSITY)
    assert res.identifiability['walther_a'].identifiable
    assert res.identifiability['walther_b'].identifiable
    assert len(res.viscous_temperatures_c) >= 2
    assert not res.identifiability['viscosity_offset_cst'].identifiable
    for name in ('walther_a', 'walther_b'):
        lo, hi = res.confidence_intervals[name]
        assert lo <= getattr(truth, name) <= hi
    assert [round(vi.temperature_c) for vi in res.viscosity] == [round(x) for x in res.viscous_temperatures_c]
    for vi in res.viscosity:  # the 95 % interval of the viscosity holds the truth, and is narrow
        assert vi.low_cst <= float(viscosity_cst(truth, vi.temperature_c)) <= vi.high_cst
        assert vi.high_cst / vi.low_cst < 1.1
    np.testing.assert_allclose(viscosity_cst(res.params, check_t), viscosity_cst(truth, check_t), rtol=0.03)


def test_no_cold_data_refuses_with_the_palmgren_reason():
    _, t, n, y, d = synth(plateaus=(0.0, 20.0, 40.0))
    with pytest.raises(FitError, match=r"none of the requested.*walther_a: not identifiable: no samples in "
                                       r"Palmgren's upper branch.*t <= -27 degC"):
        refit_model(AxisParams(), t, n, y, d)


def test_warm_data_still_determine_the_palmgren_floor():
    base = AxisParams()
    truth = base.replace(palmgren_factor=2.2)
    _, t, n, y, d = synth(plateaus=(0.0, 20.0, 40.0), truth=truth)
    res = refit_model(base, t, n, y, d, fit=('walther_a', 'palmgren_factor'))
    assert not res.identifiability['walther_a'].identifiable
    assert res.identifiability['palmgren_factor'].identifiable
    assert res.fitted['palmgren_factor'] == pytest.approx(2.2, rel=0.02)
    assert set(res.refitted) == {'palmgren_factor'}


def test_direction_factors_and_palmgren_factor():
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + SHIFT, palmgren_factor=2.0, scale_negative=0.9)
    _, t, n, y, d = synth(truth=truth)
    res = refit_model(base, t, n, y, d, fit=('walther_a', 'palmgren_factor', 'scale_negative'))
    assert all(res.identifiability[k].identifiable for k in res.fitted)
    for name in res.fitted:
        lo, hi = res.confidence_intervals[name]
        assert lo <= getattr(truth, name) <= hi, name
    assert res.fitted['scale_negative'] == pytest.approx(0.9, rel=0.01)


def test_direction_factor_without_samples_in_that_direction(one_cold):
    _, t, n, y, d = one_cold
    pos = d > 0
    res = refit_model(AxisParams(), t[pos], n[pos], y[pos], d[pos], fit=('walther_a', 'scale_negative'))
    assert res.identifiability['scale_negative'].reason == 'no samples moving in the negative direction'
    assert res.identifiability['walther_a'].identifiable


def test_collinear_parameters_are_not_fitted(one_cold):
    truth, t, n, y, d = one_cold
    cold = np.abs(t + 40.0) < 1.0
    # at one temperature M_L = s0 * f(nu): the Palmgren factor and the viscosity act the same way
    res = refit_model(AxisParams(), t[cold], n[cold], y[cold], d[cold], fit=('walther_a', 'palmgren_factor'))
    ident = res.identifiability['palmgren_factor']
    assert not ident.identifiable and ident.reason.startswith('collinear with walther_a')
    assert res.fitted['palmgren_factor'] == AxisParams().palmgren_factor
    assert float(viscosity_cst(res.params, -40.0)) == pytest.approx(float(viscosity_cst(truth, -40.0)), rel=0.03)


def test_weakly_determined_parameters_get_wide_intervals_that_hold_the_truth(one_cold):
    truth, t, n, y, d = one_cold
    names = ('walther_a', 'palmgren_factor', 'sliding_friction_coefficient', 'scale_positive', 'scale_negative')
    res = refit_model(AxisParams(), t, n, y, d, fit=names)
    for name in names:
        if res.identifiability[name].identifiable:
            lo, hi = res.confidence_intervals[name]
            assert lo <= getattr(truth, name) <= hi, name
        else:
            assert 'standard error' in res.identifiability[name].reason or 'collinear' in \
                res.identifiability[name].reason


@pytest.mark.slow
def test_weights_and_robust_loss_options(one_cold):
    truth, t, n, y, d = one_cold
    y = y.copy()
    warm = (np.abs(t - 20.0) < 1.0) & (d > 0)
    y[warm] *= 1.3  # one bad plateau (e.g. a wrong temperature tag)
    for kwargs in ({'weights': 'relative'}, {'loss': 'soft_l1'}):
        res = refit_model(AxisParams(), t, n, y, d, **kwargs)
        assert float(viscosity_cst(res.params, -40.0)) == pytest.approx(float(viscosity_cst(truth, -40.0)),
                                                                        rel=0.03)
    base = AxisParams()
    pal = {'fit': ('walther_a', 'palmgren_factor')}
    plain = refit_model(base, t, n, y, d, **pal).fitted['palmgren_factor']
    robust = refit_model(base, t, n, y, d, loss='soft_l1', **pal).fitted['palmgren_factor']
    assert abs(robust - base.palmgren_factor) < abs(plain - base.palmgren_factor)


# ---------------------------------------------------------------------------------------------- the sample model
def test_sample_model_matches_the_full_model():
    base = AxisParams()
    rng = np.random.default_rng(5)
    t = rng.uniform(-45.0, 65.0, 400)
    n = rng.choice([1.0 / 3.0, 3.0, 30.0], 400)
    d = rng.choice([-1.0, 1.0], 400)
    model = SampleModel(base, t, n, d)
    changes = {'walther_a': 8.63, 'palmgren_factor': 2.1, 'sliding_friction_coefficient': 0.12,
               'scale_positive': 1.1, 'scale_negative': 0.8}
    got = model.torque_nmm(model.values(changes))
    p = base.replace(**changes)
    want = friction_torque(p, t, n).m_total_nmm * np.where(d > 0, 1.1, 0.8)
    np.testing.assert_allclose(got, want, rtol=2e-5)  # M_R, M_S interpolated on a 0.05 degC grid


def test_sample_model_jacobian_against_finite_differences():
    base = AxisParams()
    rng = np.random.default_rng(6)
    t = rng.uniform(-45.0, 65.0, 200)
    n = rng.choice([1.0 / 3.0, 30.0], 200)
    d = rng.choice([-1.0, 1.0], 200)
    model = SampleModel(base, t, n, d)
    v = model.values({'palmgren_factor': 2.0, 'scale_negative': 0.9})
    J = model.jacobian_nmm(v, FIT_PARAMETERS)
    steps = {'walther_a': 1e-7, 'walther_b': 1e-7, 'viscosity_offset_cst': 1e-5}
    upper = model.upper_branch(v)
    for k, name in enumerate(FIT_PARAMETERS):
        h = steps.get(name, 1e-6)
        fd = (model.torque_nmm({**v, name: v[name] + h}) - model.torque_nmm({**v, name: v[name] - h})) / (2 * h)
        near = np.abs(model.viscosity_cst(v) * n / 2000.0 - 1.0) < 1e-3  # skip the Palmgren branch switch
        np.testing.assert_allclose(J[~near, k], fd[~near], rtol=1e-5, atol=1e-9, err_msg=name)
    assert np.all(J[~upper, 0] == 0.0)  # below nu*n = 2000 the torque does not depend on viscosity


# ---------------------------------------------------------------------------------------------- refusals
def test_refuses_too_few_samples(one_cold):
    _, t, n, y, d = one_cold
    with pytest.raises(FitError, match=r'too few samples: 19 \(need at least 20\)'):
        refit_model(AxisParams(), t[:19], n[:19], y[:19], d[:19])


def test_refuses_when_no_bin_has_five_samples():
    t = np.linspace(-40.0, 60.0, 30)  # every sample in its own 1 degC bin
    d = np.where(np.arange(30) % 2, 1.0, -1.0)
    y = friction_torque(AxisParams(), t).m_total_nmm * 1e-3
    with pytest.raises(FitError, match='too few samples per temperature bin'):
        refit_model(AxisParams(), t, np.full(30, 1 / 3), y, d, bin_width_c=1.0)


def test_refuses_non_finite_data(one_cold):
    _, t, n, y, d = one_cold
    y = y.copy()
    y[5] = np.nan
    with pytest.raises(FitError, match='non-finite data: 1 sample'):
        refit_model(AxisParams(), t, n, y, d)


def test_refuses_bad_arguments(one_cold):
    _, t, n, y, d = one_cold
    with pytest.raises(FitError, match='cannot fit kelvin_offset_k'):
        refit_model(AxisParams(), t, n, y, d, fit=('kelvin_offset_k',))
    with pytest.raises(FitError, match='direction must be'):
        refit_model(AxisParams(), t, n, y, d * 2.0)
    with pytest.raises(FitError, match='zero speed'):
        refit_model(AxisParams(), t, n * 0.0, y, d)


def test_refuses_a_diverging_fit():
    _, t, n, y, d = synth(plateaus=(-40.0, 20.0))
    y[t < -30.0] *= 1e4  # an absurd cold plateau: the viscosity would have to rise a million-fold
    with pytest.raises(FitError, match='diverged: walther_a ran to the edge of its plausible range'):
        refit_model(AxisParams(), t, n, y, d)


def test_refuses_a_fit_that_does_not_converge(one_cold):
    _, t, n, y, d = one_cold
    with pytest.raises(FitError, match='did not converge'):
        refit_model(AxisParams(), t, n, y, d, max_nfev=1)
