"""The refit's lack-of-fit check: a model of the data's form fits (also with correlated noise), a truth of another
form does not, bin by bin with numbers, and the interval is then not called a confidence interval."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import check_model, refit_model
from gimbal_friction.refit.fit_check import z_critical
from gimbal_friction.refit.model import measurement_model_nmm
from gimbal_friction.refit.sufficient import SufficientStats

PLATEAUS = (-40.0, -30.0, -20.0, 0.0, 20.0, 40.0, 60.0)


def chamber(truth: AxisParams, seed: int, *, ccw_cold_ratio: float = 1.0, n: int = 3000):
    """Plateaus, both directions at 1/3 rpm, with a slow correlated noise (a ripple in time, AR(1)) on top of white
    noise; ``ccw_cold_ratio`` lowers CCW in the cold as the sample bag's truth does (1 at +20 degC and above)."""
    rng = np.random.default_rng(seed)
    t, d, y, time = [], [], [], []
    clock = 0.0
    for plateau in PLATEAUS:
        for sign in (1.0, -1.0):
            tt = plateau + rng.normal(0.0, 0.05, n)
            tau = measurement_model_nmm(truth, tt, np.full(n, 1 / 3), np.full(n, sign)) * 1e-3
            w = np.clip((20.0 - tt) / 60.0, 0.0, 1.0)
            if sign < 0:
                tau = tau * (1.0 - (1.0 - ccw_cold_ratio) * w)
            ar = np.zeros(n)
            e = rng.normal(0.0, 0.01, n)
            for i in range(1, n):
                ar[i] = 0.9 * ar[i - 1] + e[i]
            y.append(tau * (1.0 + ar + rng.normal(0.0, 0.01, n)))
            t.append(tt)
            d.append(np.full(n, sign))
            time.append(clock + np.arange(n) * 0.01)
            clock += n * 0.01 + 10.0
    return (np.concatenate(t), np.full(len(PLATEAUS) * 2 * n, 1 / 3), np.concatenate(y), np.concatenate(d),
            np.concatenate(time))


TRUTH = AxisParams().replace(walther_a=AxisParams().walther_a + 0.015)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_model_of_the_datas_form_fits_and_its_interval_covers_the_truth(seed):
    t, n, y, d, time = chamber(TRUTH, seed)
    res = refit_model(AxisParams(), t, n, y, d, time_s=time)
    assert res.fit_check.checked and res.fit_check.fits, [b.z for b in res.fit_check.bins]
    assert res.intervals_are_confidence_intervals
    lo, hi = res.confidence_intervals['walther_a']
    assert lo <= TRUTH.walther_a <= hi


def test_a_one_sided_asymmetry_does_not_fit_and_is_named_with_numbers():
    t, n, y, d, time = chamber(TRUTH, 0, ccw_cold_ratio=0.768)
    res = refit_model(AxisParams(), t, n, y, d, time_s=time)
    check = res.fit_check
    assert check.checked and not check.fits and not res.intervals_are_confidence_intervals
    assert check.z_critical == pytest.approx(z_critical(len(check.bins)))
    assert check.misfits and all(abs(b.z) > check.z_critical for b in check.misfits)
    assert [abs(b.z) for b in check.misfits] == sorted((abs(b.z) for b in check.misfits), reverse=True)
    worst = check.misfits[0]
    assert worst.z == pytest.approx(worst.residual_nm / worst.standard_error_nm)
    assert 'the two directions differ (CCW below CW)' in check.pattern
    assert any('--direction cw' in tip for tip in check.advice)
    # CW alone is of the model's form: it fits, and the CCW it left out does not fit the CW fit
    cw = d > 0
    alone = refit_model(AxisParams(), t[cw], n[cw], y[cw], d[cw], time_s=time[cw])
    assert alone.fit_check.fits
    ccw = SufficientStats.from_arrays(t[~cw], n[~cw], y[~cw], d[~cw], time=time[~cw])
    held = check_model(alone.params, ccw, offset_nm=alone.offset.value_nm)
    assert held.checked and not held.fits and {b.direction for b in held.misfits} == {-1}


def test_the_standard_error_is_not_the_raw_count():
    """The correlated noise makes the batch-means standard error several times s/sqrt(n): with the raw count the
    same data would fail the check."""
    t, n, y, d, time = chamber(TRUTH, 0)
    res = refit_model(AxisParams(), t, n, y, d, time_s=time)
    for b in (b for b in res.bins if b.used):
        sel = (np.abs(t - b.temperature_c) < 1.0) & (d == b.direction)
        iid = float(np.std(y[sel], ddof=1) / np.sqrt(sel.sum()))
        assert b.measured_se_nm > 2.0 * iid
