"""Eqs. (20)-(22) against the paper's Table 2 (Krytox 143AA), derivatives and the fitter."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.common.errors import FitError, ModelDomainError
from gimbal_friction.physics.viscosity import (
    KRYTOX_143AA_WALTHER,
    KRYTOX_143AA_WALTHER_IMPROVED,
    TABLE2_ERR1_PCT,
    TABLE2_ERR2_PCT,
    TABLE2_FIT1_CST,
    TABLE2_FIT2_CST,
    TABLE2_NU_CST,
    TABLE2_T_C,
    dnu_dT_Walther,
    fit_Walther,
    nu_Walther,
    nu_Walther_fitting_jacobian,
    viscosity_errors_pct,
)

T_K = np.asarray(TABLE2_T_C) + 273.0
CASES = [('walther', KRYTOX_143AA_WALTHER, TABLE2_FIT1_CST, TABLE2_ERR1_PCT),
         ('walther_improved', KRYTOX_143AA_WALTHER_IMPROVED, TABLE2_FIT2_CST, TABLE2_ERR2_PCT)]


@pytest.mark.parametrize(('model', 'consts', 'printed_fit', 'printed_err'), CASES)
def test_table2_fitting_viscosity_and_errors(model, consts, printed_fit, printed_err):
    """Table 2: every printed fitting viscosity to 0.05 %, every error column to 0.001 points."""
    nu = nu_Walther(T_K, *consts, model=model)
    rel = np.abs(nu - np.asarray(printed_fit)) / np.asarray(printed_fit)
    assert rel.max() < 5e-4, rel
    err = viscosity_errors_pct(nu, TABLE2_NU_CST)
    assert np.abs(err - np.asarray(printed_err)).max() < 1e-3


def test_t_plus_273_15_would_not_reproduce_table2():
    """The convention matters: T = t + 273.15 misses Table 2 by up to ~2 %, so the test above can fail."""
    nu = nu_Walther(np.asarray(TABLE2_T_C) + 273.15, *KRYTOX_143AA_WALTHER_IMPROVED)
    assert (np.abs(nu / np.asarray(TABLE2_FIT2_CST) - 1)).max() > 0.01


def test_model_md_viscosity_row():
    """docs/model.md §5 viscosities from the Eq. (21) fit, to 0.1 %."""
    t = np.array([-40.0, -30.0, -20.0, 0.0, 20.0, 60.0])
    expected = np.array([44702.0, 8916.0, 2407.0, 338.0, 85.8, 15.1])
    nu = nu_Walther(t + 273.0, *KRYTOX_143AA_WALTHER_IMPROVED)
    np.testing.assert_allclose(nu, expected, rtol=4e-3)  # printed to 3-5 significant digits


@pytest.mark.parametrize('model', ['walther', 'walther_improved'])
def test_refit_table2_recovers_constants_that_do_as_well(model):
    consts = KRYTOX_143AA_WALTHER if model == 'walther' else KRYTOX_143AA_WALTHER_IMPROVED
    paper_err = viscosity_errors_pct(nu_Walther(T_K, *consts, model=model), TABLE2_NU_CST)
    fit = fit_Walther(TABLE2_T_C, TABLE2_NU_CST, model)
    assert fit.rms_error_pct <= np.sqrt(np.mean(paper_err**2)) + 1e-9
    assert fit.max_abs_error_pct <= np.abs(paper_err).max() + 0.05
    assert all(np.isfinite(fit.standard_errors))
    np.testing.assert_allclose(fit.error_pct, viscosity_errors_pct(fit.nu_fit_cst, TABLE2_NU_CST))


@pytest.mark.parametrize('model', ['walther', 'walther_improved'])
def test_fit_recovers_synthetic_truth(model):
    truth = (8.7, -21.0, 0.9) if model == 'walther_improved' else (9.5, -3.75, 0.8)
    t = np.linspace(-40, 150, 12)
    nu = nu_Walther(t + 273.0, *truth, model=model)
    fit = fit_Walther(t, nu, model)
    np.testing.assert_allclose((fit.a1, fit.b1, fit.c1), truth, rtol=1e-6, atol=1e-6)
    assert fit.max_abs_error_pct < 1e-6


@pytest.mark.parametrize('model', ['walther', 'walther_improved'])
def test_jacobian_and_derivative_against_finite_differences(model):
    a, b, c = KRYTOX_143AA_WALTHER_IMPROVED if model == 'walther_improved' else KRYTOX_143AA_WALTHER
    T = np.array([240.0, 300.0, 400.0])
    J = nu_Walther_fitting_jacobian(T, a, b, c, model)
    h = 1e-7
    for k, (da, db, dc) in enumerate([(h, 0, 0), (0, h, 0), (0, 0, h)]):
        fd = (nu_Walther(T, a + da, b + db, c + dc, model) - nu_Walther(T, a - da, b - db, c - dc, model)) / (2 * h)
        np.testing.assert_allclose(J[:, k], fd, rtol=1e-5)
    hT = 1e-4
    fd_T = (nu_Walther(T + hT, a, b, c, model) - nu_Walther(T - hT, a, b, c, model)) / (2 * hT)
    np.testing.assert_allclose(dnu_dT_Walther(T, a, b, c, model), fd_T, rtol=1e-6)
    assert np.all(dnu_dT_Walther(T, a, b, c, model) < 0)


def test_fit_refusals():
    with pytest.raises(FitError, match='at least 4'):
        fit_Walther([0, 20, 40], [300, 85, 30])
    with pytest.raises(FitError, match='finite'):
        fit_Walther([0, 20, 40, np.nan], [300, 85, 30, 10])
    with pytest.raises(FitError, match='> 0'):
        fit_Walther([0, 20, 40, 60], [300, 85, 0, 10])
    with pytest.raises(ModelDomainError):
        nu_Walther([-300.0], *KRYTOX_143AA_WALTHER_IMPROVED)
