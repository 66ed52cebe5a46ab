"""LuGre model and truth friction: steady state = static Stribeck curve, exact z step, the paper's CW/CCW means."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.units import RAD_S_PER_RPM
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.lugre import (
    lugre_force_1995,
    lugre_g_1995,
    lugre_steady_state_z,
    lugre_z_step,
    stribeck_curve_LuGre_1995,
)
from gimbal_friction.sim.truth import TruthFriction, mean_factors, ripple, truth_asymmetry, truth_params

VELOCITIES = [-0.2, -0.01, -0.002, -0.0005, 0.0003, 0.001, 0.004, 0.0349, 0.5]


@pytest.mark.parametrize('v', VELOCITIES)
def test_lugre_steady_state_is_the_static_stribeck_curve(v):
    f_c, f_s, v_s, sigma0, sigma1, sigma2, h = 1e-3, 1.6e-3, 0.002, 100.0, 0.1, 0.01, 1e-2
    g = lugre_g_1995(v, f_c, f_s, v_s)
    z = 0.0
    for _ in range(3000):        # constant v from rest: z relaxes at rate sigma0 |v| / g
        z_new = lugre_z_step(z, v, g, sigma0, h)
        force = lugre_force_1995(z_new, (z_new - z) / h, v, sigma0, sigma1, sigma2)
        z = z_new
    assert float(force) == pytest.approx(float(stribeck_curve_LuGre_1995(v, f_c, f_s, v_s, sigma2)), rel=1e-9)
    assert float(z) == pytest.approx(float(lugre_steady_state_z(v, g, sigma0)), rel=1e-9)


def test_z_step_is_exact_for_constant_velocity():
    """One exact step equals a fine explicit-Euler integration of dz/dt = v - sigma0 |v| z / g."""
    v, g, sigma0, h = 0.003, 1.2e-3, 100.0, 2e-3
    z0 = -5e-6
    fine = z0
    n = 200000
    for _ in range(n):
        fine += (h / n) * (v - sigma0 * abs(v) * fine / g)
    assert float(lugre_z_step(z0, v, g, sigma0, h)) == pytest.approx(fine, rel=1e-5)


def test_z_step_never_overshoots_in_the_stiff_sliding_regime():
    g, sigma0 = 1e-3, 100.0
    z = np.array([-1e-5, 0.0, 1e-5])
    out = lugre_z_step(z, np.array([5.0, 5.0, -5.0]), g, sigma0, 1e-3)   # a h = 5e5
    assert np.all(np.abs(out) <= g / sigma0 * (1 + 1e-12))
    assert out.tolist() == pytest.approx([1e-5, 1e-5, -1e-5], rel=1e-12)
    # standstill keeps the deflection (pre-sliding memory)
    assert float(lugre_z_step(3e-6, 0.0, g, sigma0, 1e-3)) == 3e-6


def test_truth_static_torque_is_the_lugre_steady_state():
    truth = TruthFriction(SimConfig(truth_no_load_current_a=0.01))
    temps = np.array([-40.0, -20.0, 20.0, 60.0])
    theta = np.radians([0.3, 1.1, -2.0, 5.0])
    for v in VELOCITIES:
        vel = np.full(temps.shape, v)
        factor = 1.0 + ripple(truth.config, theta, temps)
        g = truth.stribeck_level_nm(truth.terms(temps), vel, factor)
        z = np.zeros(temps.shape)
        for _ in range(3000):
            z_new = lugre_z_step(z, vel, g, truth.sigma0, 1e-2)
            force = lugre_force_1995(z_new, (z_new - z) / 1e-2, vel, truth.sigma0, truth.sigma1)
            z = z_new
        np.testing.assert_allclose(force, truth.static_torque_nm(temps, vel, theta), rtol=1e-9)


def test_truth_reproduces_the_papers_four_measured_means_without_lubricant_shift():
    """CW 3.19 vs CCW -2.45 N*mm at -40 degC, 1.05 vs -1.34 at +60 (paper Sec. 6), at 1/3 rpm."""
    cfg = SimConfig(lubricant_walther_a_shift=0.0, ripple_amplitudes=(0.0, 0.0))
    truth = TruthFriction(cfg)
    v = RAD_S_PER_RPM / 3.0
    got = truth.static_torque_nm([-40.0, -40.0, 60.0, 60.0], [v, -v, v, -v]) * 1e3
    # (the truth's model part is the core's table: its interpolation of M_R + M_S is within 1e-6 of the model)
    assert got.tolist() == pytest.approx([3.19, -2.45, 1.05, -1.34], rel=1e-6)
    # the direction dependence is the core's form 1 + d a(t) with the measured asymmetry, times the mean factor;
    # between the anchors both are linear in temperature, beyond them held
    a_cold, a_warm = truth_asymmetry(cfg)
    assert a_cold == pytest.approx((3.19 - 2.45) / (3.19 + 2.45)) and a_warm == pytest.approx((1.05 - 1.34) / 2.39)
    m = mean_factors(cfg)
    terms = truth.terms(np.array([-60.0, 10.0, 100.0]))
    assert terms.k_positive[0] == pytest.approx(m.factors[0] * (1.0 + a_cold))
    assert terms.k_negative[2] == pytest.approx(m.factors[1] * (1.0 - a_warm))
    mid_m = 0.5 * (m.factors[0] + m.factors[1])
    assert terms.k_positive[1] == pytest.approx(mid_m * (1.0 + 0.5 * (a_cold + a_warm)))


def test_lubricant_shift_raises_the_cold_friction_only():
    base = TruthFriction(SimConfig(lubricant_walther_a_shift=0.0, ripple_amplitudes=(0.0, 0.0)))
    shifted = TruthFriction(SimConfig(ripple_amplitudes=(0.0, 0.0)))
    v = RAD_S_PER_RPM / 3.0
    cold = shifted.static_torque_nm(-40.0, v) / base.static_torque_nm(-40.0, v)
    warm = shifted.static_torque_nm(20.0, v) / base.static_torque_nm(20.0, v)
    assert float(cold) > 1.15              # more viscous lubricant: M_L grows on Palmgren's upper branch
    assert float(warm) == pytest.approx(1.0, abs=1e-12)   # lower branch at +20 degC: viscosity does not matter


def test_breakaway_is_breakaway_ratio_times_the_low_speed_level():
    cfg = SimConfig(ripple_amplitudes=(0.0, 0.0), asymmetry_enabled=False, breakaway_ratio=1.5)
    truth = TruthFriction(cfg)
    tiny = 1e-9
    near_zero = float(truth.static_torque_nm(20.0, tiny))
    sliding = float(truth.static_torque_nm(20.0, 20 * cfg.stribeck_velocity_rad_s))
    assert near_zero == pytest.approx(1.5 * sliding, rel=1e-6)
    assert math.isclose(float(truth.static_torque_nm(20.0, -tiny)), -near_zero, rel_tol=1e-12)


def test_the_truth_is_the_simulators_own_parameters():
    """Each truth parameter moves the truth the way its declaration says; the configured model has no way in."""
    v = RAD_S_PER_RPM / 3.0
    flat = {'ripple_amplitudes': (0.0, 0.0), 'asymmetry_enabled': False}
    base = TruthFriction(SimConfig(**flat))
    # the lubricant: a shift is relative to the truth's own walther_a; equal sums are the same lubricant
    same = TruthFriction(SimConfig(**flat, truth_walther_a=8.6245, lubricant_walther_a_shift=0.010))
    assert truth_params(same.config).walther_a == pytest.approx(truth_params(base.config).walther_a, abs=1e-12)
    assert float(same.static_torque_nm(-40.0, v)) == pytest.approx(float(base.static_torque_nm(-40.0, v)), rel=1e-9)
    thinner = TruthFriction(SimConfig(**flat, truth_walther_a=8.5895))
    assert float(thinner.static_torque_nm(-40.0, v)) < 0.8 * float(base.static_torque_nm(-40.0, v))
    steeper = TruthFriction(SimConfig(**flat, truth_walther_b=-21.4))
    assert float(steeper.static_torque_nm(-40.0, v)) != pytest.approx(float(base.static_torque_nm(-40.0, v)), rel=1e-3)
    # the Palmgren floor and the motor's no-load torque (T_0 = K_T I_0, against the motion)
    floor = TruthFriction(SimConfig(**flat, truth_palmgren_factor=2.2))
    assert float(floor.static_torque_nm(60.0, v)) > 1.05 * float(base.static_torque_nm(60.0, v))
    motor = TruthFriction(SimConfig(**flat, truth_torque_constant_nm_per_a=0.08, truth_no_load_current_a=0.01))
    assert float(motor.static_torque_nm(20.0, v) - base.static_torque_nm(20.0, v)) == pytest.approx(0.08 * 0.01)
    assert float(motor.static_torque_nm(20.0, -v) - base.static_torque_nm(20.0, -v)) == pytest.approx(-0.08 * 0.01)


@pytest.mark.parametrize(('name', 'value'), [('truth_walther_b', 0.5), ('truth_walther_a', -1.0),
                                             ('truth_torque_constant_nm_per_a', 0.0), ('truth_no_load_current_a', 3.0),
                                             ('truth_palmgren_factor', 0.0)])
def test_a_truth_parameter_out_of_range_is_refused_by_name(name, value):
    from gimbal_friction.common.errors import ConfigError

    with pytest.raises(ConfigError, match=name):
        SimConfig.from_mapping({name: value})
