"""Hertz contact (docs/model.md §4 values), the spin closed form (Eq. 6) and Palmgren (Eq. 9)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.physics.friction import (
    hysteresis_force_Jiang,
    spin_torque_contact_Eq6,
    spin_torque_contact_numerical,
    viscous_torque_Palmgren_1959,
)
from gimbal_friction.physics.hertz import ellipticity_Harris, hertz_contact, load_deflection_constant, reduced_modulus
from gimbal_friction.physics.params import AxisParams

E_STAR = reduced_modulus(208000.0, 0.3, 208000.0, 0.3)
A15 = math.radians(15.0)


def test_reduced_modulus():
    assert pytest.approx(114286, rel=1e-5) == E_STAR


def test_table1_derived_geometry():
    """docs/model.md §1.1: d_m = 21.5, B = 0.10, P_d = 0.0162 mm, alpha0 = 14.988 deg (15 deg as Table 1)."""
    p = AxisParams()
    assert p.pitch_diameter_mm == pytest.approx(21.5, abs=1e-9)
    assert p.pitch_diameter_mm == pytest.approx((p.outside_diameter_mm + p.bore_diameter_mm) / 2, abs=1e-9)
    assert p.total_curvature == pytest.approx(0.10, abs=1e-12)
    assert p.radial_clearance_mm == pytest.approx(0.0162, abs=1e-9)
    assert p.free_contact_angle_deg == pytest.approx(14.988, abs=1e-3)
    assert p.free_contact_angle_deg == pytest.approx(15.0, abs=0.05)
    # Table 1 was generated from 15 deg: P_d = 2A(1 - cos 15) = 0.016226, rounded to 4 decimals
    assert 2 * 0.2381 * (1 - math.cos(A15)) == pytest.approx(p.radial_clearance_mm, abs=5e-5)


@pytest.mark.parametrize(('outer', 'f', 'a_um', 'b_um', 'kappa'), [(False, 0.56, 97.2, 21.0, 4.63),
                                                                     (True, 0.54, 111.5, 21.9, 5.10)])
def test_hertz_table1_ball_15deg_5N(outer, f, a_um, b_um, kappa):
    """docs/model.md §4 worked values, to the printed digits."""
    c = hertz_contact(5.0, 2.381, 21.5, A15, f, E_STAR, outer=outer)
    assert float(c.a) * 1e3 == pytest.approx(a_um, abs=0.06)
    assert float(c.b) * 1e3 == pytest.approx(b_um, abs=0.06)
    assert float(c.kappa) == pytest.approx(kappa, abs=0.006)
    assert float(c.p_max) == pytest.approx(3 * 5.0 / (2 * math.pi * float(c.a) * float(c.b)))


def test_total_approach_and_kn():
    ci = hertz_contact(5.0, 2.381, 21.5, A15, 0.56, E_STAR, outer=False)
    co = hertz_contact(5.0, 2.381, 21.5, A15, 0.54, E_STAR, outer=True)
    assert float(ci.delta + co.delta) * 1e3 == pytest.approx(1.20, abs=0.006)
    K_n = float(load_deflection_constant(2.381, 21.5, A15, 0.56, 0.54, E_STAR))
    assert K_n == pytest.approx(1.202e5, rel=1e-3)
    K = K_n * (0.1 * 2.381) ** 1.5 / 2.381**2
    assert pytest.approx(2463, rel=1e-3) == K


def test_ellipticity_solves_its_equation_and_circle_limit():
    from scipy.special import ellipe, ellipk
    for F in (0.05, 0.5, 0.9, 0.99):
        k = float(ellipticity_Harris(F))
        m = 1 - 1 / k**2
        assert ((k**2 + 1) * ellipe(m) - 2 * ellipk(m)) / ((k**2 - 1) * ellipe(m)) == pytest.approx(F, rel=1e-10)
    assert float(ellipticity_Harris(0.0)) == 1.0


@pytest.mark.filterwarnings('ignore::scipy.integrate.IntegrationWarning')
@pytest.mark.parametrize(('a', 'b'), [(0.1115, 0.0219), (0.05, 0.05), (0.166, 0.0327)])
@pytest.mark.slow
def test_spin_closed_form_matches_double_integral(a, b):
    mu, Q = 0.095, 16.6
    e2 = 1 - (b / a) ** 2
    from scipy.special import ellipe
    closed = float(spin_torque_contact_Eq6(mu, Q, a, ellipe(e2)))
    numeric = spin_torque_contact_numerical(mu, Q, a, b)
    assert closed == pytest.approx(numeric, rel=1e-8)


def test_spin_circle_limit():
    assert float(spin_torque_contact_Eq6(0.1, 10.0, 0.1, math.pi / 2)) == pytest.approx(3 * math.pi / 16 * 0.1)


def test_palmgren_branches():
    s0, dm = 1.917, 21.5
    low = float(viscous_torque_Palmgren_1959(s0, 100.0, 1 / 3, dm))
    assert low == pytest.approx(160e-7 * s0 * dm**3)
    # constant below nu*n = 2000, (nu n)^(2/3) above, meeting within 0.8 %
    assert float(viscous_torque_Palmgren_1959(s0, 5999.0, 1 / 3, dm)) == pytest.approx(low)
    below = float(viscous_torque_Palmgren_1959(s0, 1999.999, 1.0, dm))
    above = float(viscous_torque_Palmgren_1959(s0, 2000.0, 1.0, dm))
    assert above == pytest.approx(1e-7 * s0 * 2000 ** (2 / 3) * dm**3)
    assert abs(above / below - 1) < 0.008
    hi = float(viscous_torque_Palmgren_1959(s0, 44702.0, 1 / 3, dm))
    assert hi == pytest.approx(1e-7 * s0 * (44702 / 3) ** (2 / 3) * dm**3)
    # speed sign does not matter
    assert float(viscous_torque_Palmgren_1959(s0, 44702.0, -1 / 3, dm)) == pytest.approx(hi)


def test_hysteresis_force():
    assert float(hysteresis_force_Jiang(0.01, 10.0, 0.02, 1.0)) == pytest.approx(3 / 16 * 0.01 * 10 * 0.02)
    np.testing.assert_allclose(hysteresis_force_Jiang(0.01, np.array([1.0, 2.0]), 0.02, 1.0),
                               [3 / 16 * 0.0002, 3 / 16 * 0.0004])
