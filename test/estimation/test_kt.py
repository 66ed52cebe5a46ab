"""K_T calibration (paper Eq. 23): Eq. 23 itself, its Jacobian, robust recovery of known constants, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.common.errors import FitError
from gimbal_friction.estimation.kt import KtFit, fit_kt, friction_from_current_Eq23, friction_from_current_Eq23_jacobian

K_T_TRUE = 0.0523   # [N*m/A]
I_0_TRUE = 0.012    # [A]
NOISE_NM = 2e-4     # torque sensor noise, 1 sigma [N*m]


def synthetic(seed: int, n: int = 200, *, outlier_fraction: float = 0.05, both_directions: bool = False):
    """Calibration points with known K_T, I_0, Gaussian torque noise and gross outliers (25-100 sigma)."""
    rng = np.random.default_rng(seed)
    current = rng.uniform(0.05, 1.0, n)
    speed = None
    direction = np.ones(n)
    if both_directions:
        direction = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
        current = current * direction
        speed = 0.0349 * direction  # 1/3 rpm [rad/s]
    torque = K_T_TRUE * (current - direction * I_0_TRUE) + rng.normal(0.0, NOISE_NM, n)
    n_out = int(round(outlier_fraction * n))
    bad = rng.choice(n, n_out, replace=False)
    torque[bad] += rng.choice([-1.0, 1.0], n_out) * rng.uniform(25 * NOISE_NM, 100 * NOISE_NM, n_out)
    return current, torque, speed, np.sort(bad)


def test_eq23_scalar_vector_and_direction():
    assert friction_from_current_Eq23(0.5, 0.05, 0.01) == pytest.approx(0.0245)
    assert isinstance(friction_from_current_Eq23(0.5, 0.05, 0.01), float)
    out = friction_from_current_Eq23([0.5, -0.5, 0.0], 0.05, 0.01, direction=[1.0, -1.0, 0.0])
    np.testing.assert_allclose(out, [0.0245, -0.0245, 0.0])
    # no-load torque T_0 = K_T I_0 is what the motor spends before any load torque appears
    assert friction_from_current_Eq23(0.01, 0.05, 0.01) == pytest.approx(0.0)


def test_eq23_jacobian_matches_finite_differences():
    current = np.array([-0.8, -0.1, 0.2, 0.9])
    direction = np.sign(current)
    K_T, I_0 = 0.0523, 0.012
    jac = friction_from_current_Eq23_jacobian(current, K_T, I_0, direction)
    h = 1e-7
    d_K = (friction_from_current_Eq23(current, K_T + h, I_0, direction)
           - friction_from_current_Eq23(current, K_T - h, I_0, direction)) / (2 * h)
    d_I = (friction_from_current_Eq23(current, K_T, I_0 + h, direction)
           - friction_from_current_Eq23(current, K_T, I_0 - h, direction)) / (2 * h)
    np.testing.assert_allclose(jac, np.column_stack([d_K, d_I]), rtol=1e-7, atol=1e-12)


def test_synthetic_recovery_within_reported_uncertainty():
    current, torque, _, bad = synthetic(seed=7)
    fit = fit_kt(current, torque)
    assert isinstance(fit, KtFit)
    assert fit.n == 200
    # recovered within the reported 1-sigma standard errors (4 sigma bound)
    assert abs(fit.K_T - K_T_TRUE) < 4 * fit.se_K_T
    assert abs(fit.I_0 - I_0_TRUE) < 4 * fit.se_I_0
    assert abs(fit.T_0 - K_T_TRUE * I_0_TRUE) < 4 * fit.se_T_0
    # the standard errors are of the size the noise implies, not inflated by the outliers
    assert fit.se_K_T < 1e-4
    assert fit.residual_std == pytest.approx(NOISE_NM, rel=0.2)
    assert fit.r2 > 0.999
    # every gross outlier is flagged, and hardly any good point
    assert not fit.inliers[bad].any()
    assert len(bad) <= fit.n_outliers <= len(bad) + 2
    assert fit.n_inliers == int(fit.inliers.sum())
    np.testing.assert_allclose(fit.residuals, torque - (fit.K_T * current - fit.T_0), atol=1e-15)
    # plain least squares is pulled off by the same outliers
    A = np.column_stack([current, -np.ones_like(current)])
    ols = np.linalg.lstsq(A, torque, rcond=None)[0]
    assert abs(ols[0] - K_T_TRUE) > abs(fit.K_T - K_T_TRUE)


def test_synthetic_recovery_both_directions_with_speed():
    current, torque, speed, bad = synthetic(seed=11, both_directions=True)
    fit = fit_kt(current, torque, speed)
    assert abs(fit.K_T - K_T_TRUE) < 4 * fit.se_K_T
    assert abs(fit.I_0 - I_0_TRUE) < 4 * fit.se_I_0
    assert not fit.inliers[bad].any()
    np.testing.assert_array_equal(fit.direction, np.sign(speed))


def test_standard_errors_are_calibrated():
    """Over repeated synthetic experiments the error divided by the reported se has a spread of about 1."""
    z_K, z_I = [], []
    for seed in range(100, 260):
        current, torque, _, _ = synthetic(seed)
        fit = fit_kt(current, torque)
        z_K.append((fit.K_T - K_T_TRUE) / fit.se_K_T)
        z_I.append((fit.I_0 - I_0_TRUE) / fit.se_I_0)
    assert 0.8 < float(np.std(z_K)) < 1.25
    assert 0.8 < float(np.std(z_I)) < 1.25
    assert abs(float(np.mean(z_K))) < 0.3


def test_exact_data_without_outliers():
    current = np.linspace(0.1, 1.0, 10)
    fit = fit_kt(current, 0.05 * (current - 0.02))
    assert pytest.approx(0.05, rel=1e-12) == fit.K_T
    assert pytest.approx(0.02, rel=1e-9) == fit.I_0
    assert fit.n_outliers == 0
    assert fit.se_K_T < 1e-12


def test_quantised_data_gives_no_spurious_outliers():
    """Torque rounded to the sensor resolution (0.1 mN*m): many equal residuals must not collapse the scale."""
    current = np.repeat(np.linspace(0.1, 0.5, 5), 4)
    torque = np.round(K_T_TRUE * (current - I_0_TRUE), 4)
    fit = fit_kt(current, torque)
    assert fit.n_outliers == 0
    assert abs(fit.K_T - K_T_TRUE) < 4 * fit.se_K_T + 1e-4


@pytest.mark.parametrize(('current', 'torque', 'speed', 'reason'), [
    ([0.1, 0.2], [0.005, 0.01], None, 'too few points: 2'),
    ([], [], None, 'too few points: 0'),
    ([0.0, 0.0, 0.0, 0.0], [0.001, 0.002, 0.0, 0.001], None, 'all-zero current'),
    ([0.1, 0.2, np.nan, 0.4], [0.005, 0.01, 0.015, 0.02], None, "non-finite values in column 'current_a'"),
    ([0.1, 0.2, 0.3, 0.4], [0.005, np.inf, 0.015, 0.02], None, "non-finite values in column 'torque_nm'"),
    ([0.1, 0.2, 0.3, 0.4], [0.005, 0.01, 0.015, 0.02], [1.0, np.nan, 1.0, 1.0],
     "non-finite values in column 'speed_rad_s'"),
    ([0.1, 0.2, 0.3, 0.4], [-0.005, -0.01, -0.015, -0.02], None, 'K_T = -0.05 N*m/A is not positive'),
    ([0.3, 0.3, 0.3, 0.3], [0.01, 0.011, 0.012, 0.01], None, 'all currents equal'),
    ([0.1, 0.2, 0.3], [0.005, 0.01], None, 'different lengths'),
    ([0.1, 0.2, 0.3, 0.4], [0.005, 0.01, 0.015, 0.02], [0.0, 0.0, 0.0, 0.0], 'speed_rad_s is 0 in every point'),
])
def test_refusals_name_the_reason(current, torque, speed, reason):
    with pytest.raises(FitError, match=None) as info:
        fit_kt(current, torque, speed)
    assert reason in str(info.value)
