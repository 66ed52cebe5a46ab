"""Thermal coupling (Eqs. 11-19) and the whole model against docs/model.md and the paper's headline numbers."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.thermal import (
    axial_coupling,
    contact_angle_Harris_Eq19,
    loose_fit_temperature,
    press_fit_Lame_Eq14,
    radial_coupling,
)

P0 = AxisParams()
T_GRID = np.round(np.arange(-40.0, 60.0001, 0.1), 6)


def test_lame_same_material_limit_is_shigley():
    """Same material, small interference: Shigley Eq. 3-57 p = E d/(2R^3) (ro^2-R^2)(R^2-ri^2)/(ro^2-ri^2)."""
    E, nu = 200000.0, 0.3
    D, ri, ro = 26.0, 23.9 / 2, 80.0 / 2
    delta_d = 1e-6
    p, D2, dO2, DL2 = press_fit_Lame_Eq14(D, 2 * ri, D - delta_d, 2 * ro, E, nu, E, nu)
    R = D / 2
    shigley = E * (delta_d / 2) / (2 * R**3) * (ro**2 - R**2) * (R**2 - ri**2) / (ro**2 - ri**2)
    assert float(p) == pytest.approx(shigley, rel=1e-5)
    assert D - delta_d < float(D2) < D


def test_lame_loose_fit_gives_zero_pressure():
    p, _, dO2, _ = press_fit_Lame_Eq14(26.0, 23.9, 26.001, 80.0, 208000, 0.3, 70000, 0.33)
    assert float(p) == 0.0 and float(dO2) == 23.9


def test_radial_sanity_values_delta0_minus40():
    """docs/model.md §3 sanity values (Delta = 0, -40 degC)."""
    p = P0.replace(interference_mm=0.0)
    assert pytest.approx(0.0156) == 26.0 * (21.7e-6 - 11.7e-6) * 60
    r = radial_coupling(p, -40.0)
    assert float(r.fit_pressure) == pytest.approx(7.7, abs=0.05)
    assert float(r.d_O2) == pytest.approx(23.8610, abs=5e-5)
    assert pytest.approx(23.8723, abs=5e-5) == 23.8891 * (1 - 11.7e-6 * 60)
    assert float(r.P_d) * 1e3 == pytest.approx(4.8, abs=0.05)
    assert math.degrees(float(r.alpha0)) == pytest.approx(8.2, abs=0.05)
    warm = radial_coupling(p, 40.0)
    assert bool(warm.loose) and float(warm.P_d) * 1e3 == pytest.approx(16.2, abs=0.05)


@pytest.mark.parametrize(('delta', 't_loose'), [(0.004, 35.4), (0.006, 43.1), (0.008, 50.8)])
def test_loose_fit_temperatures(delta, t_loose):
    p = P0.replace(interference_mm=delta)
    assert loose_fit_temperature(p) == pytest.approx(t_loose, abs=0.05)
    r = radial_coupling(p, np.array([t_loose - 0.2, t_loose + 0.2]))
    assert r.loose.tolist() == [False, True]
    assert float(r.fit_pressure[0]) > 0.0 and float(r.fit_pressure[1]) == 0.0
    # the literal -2 Delta reading moves the loose fit out of the plotted range (docs/model.md §3 note)
    assert loose_fit_temperature(p.replace(interference_factor=2)) > t_loose + 15


def test_fig5_free_contact_angle():
    """Fig. 5 text: Delta = 0.008 reaches 0 deg before -40 degC (at -34.7), Delta = 0.006 does not (2.5 deg)."""
    r8 = friction_torque(P0.replace(interference_mm=0.008), T_GRID)
    zero = T_GRID[r8.free_contact_angle_deg == 0.0]
    assert zero.max() == pytest.approx(-34.7, abs=0.15)
    r6 = friction_torque(P0, -40.0)
    assert float(r6.free_contact_angle_deg) == pytest.approx(2.5, abs=0.05)
    # 15 deg (14.988) wherever the fit is loose; larger interference -> smaller angle in the cold
    res = [friction_torque(P0.replace(interference_mm=d), T_GRID) for d in (0.0, 0.004, 0.006, 0.008)]
    for lo, hi in zip(res[1:], res[:-1]):
        assert np.all(lo.free_contact_angle_deg <= hi.free_contact_angle_deg + 1e-12)
    assert res[2].free_contact_angle_deg[T_GRID > 44].min() == pytest.approx(14.988, abs=1e-3)
    assert np.all(np.diff(res[3].free_contact_angle_deg) >= -1e-9)


def test_eq19_newton_raphson_matches_bracketing_root():
    """Eq. (19) Harris Newton-Raphson at the coupled solution's F_a gives the brentq contact angle."""
    for t in (-40.0, -10.0, 20.0, 43.1, 60.0):
        r, res = radial_coupling(P0, t), None
        ax = axial_coupling(P0, r)
        A, c0 = float(r.A), float(r.c0)
        D_w = float(r.D_w2)
        K = float(ax.K_n) * A**1.5 / D_w**2
        alpha_nr = contact_angle_Harris_Eq19(float(ax.F_a), P0.ball_count, D_w, K, c0,
                                             max(float(r.alpha0), 1e-3) + math.radians(2.0))
        direct = friction_torque(P0, t, direct=True)
        assert math.degrees(alpha_nr) == pytest.approx(float(direct.contact_angle_deg), abs=1e-8)
        assert float(ax.alpha) == pytest.approx(alpha_nr, abs=1e-10)
        del res


def test_vectorised_solver_equals_direct_solve():
    temps = [-60.0, -40.0, -27.3, 0.0, 20.0, 43.2, 60.0, 120.0]
    vec = friction_torque(P0, temps)
    direct = friction_torque(P0, temps, direct=True)
    for name in ('contact_angle_deg', 'axial_force_n', 'ball_load_n', 'm_total_nmm', 'm_sliding_nmm'):
        np.testing.assert_allclose(getattr(vec, name), getattr(direct, name), rtol=1e-9)


def test_model_md_operating_points():
    """docs/model.md §7 table (Delta = 0.006 mm, P = 0.03 mm)."""
    r = friction_torque(P0, [-40.0, 20.0, 60.0])
    np.testing.assert_allclose(r.contact_angle_deg, [8.90, 14.44, 16.40], atol=0.006)
    np.testing.assert_allclose(r.axial_force_n, [38.5, 30.3, 34.2], atol=0.06)
    np.testing.assert_allclose(r.ball_load_n, [16.6, 8.1, 8.1], atol=0.06)
    np.testing.assert_allclose(r.m_sliding_nmm + r.m_rolling_nmm, [0.841, 0.436, 0.473], atol=6e-4)
    np.testing.assert_allclose(r.m_viscous_nmm, [2.300, 0.609, 0.611], atol=3e-3)
    np.testing.assert_allclose(r.m_total_nmm, [3.141, 1.046, 1.084], atol=3e-3)


def test_paper_headline_numbers():
    """Sec. 5 / Fig. 11: M_L(-40) = 2.30, M_S+M_R(-40) = 0.84, min 0.38 at the loose fit, M(-40) ~ 3.14."""
    r = friction_torque(P0, T_GRID)
    i40 = 0
    assert r.m_viscous_nmm[i40] == pytest.approx(2.30, rel=0.005)
    ms = r.m_sliding_nmm + r.m_rolling_nmm
    assert ms[i40] == pytest.approx(0.84, rel=0.02)
    assert ms.min() == pytest.approx(0.38, rel=0.02)
    assert T_GRID[np.argmin(ms)] == pytest.approx(loose_fit_temperature(P0), abs=0.1)
    assert r.m_total_nmm[i40] == pytest.approx(3.14, rel=0.01)
    warm = r.m_total_nmm[T_GRID >= 0.0]
    assert (warm.max() - warm.min()) / warm.mean() < 0.13
    # the paper's measured CW mean at -40 degC is 3.19 N*mm
    assert r.m_total_nmm[i40] == pytest.approx(3.19, rel=0.03)


def test_palmgren_branch_switch_near_minus27():
    r = friction_torque(P0, T_GRID)
    vn = r.viscosity_cst * P0.speed_rpm
    t_switch = T_GRID[vn >= 2000].max()
    assert t_switch == pytest.approx(-27.0, abs=0.6)
    flat = r.m_viscous_nmm[T_GRID > -26.0]
    assert flat.max() / flat.min() - 1 < 0.005  # only the thermal d_m^3 scaling


def test_fig7_fig9_gasket_trends():
    res = [friction_torque(P0.replace(gasket_thickness_mm=g), T_GRID) for g in (0.0, 0.01, 0.02, 0.03)]
    for lo, hi in zip(res[:-1], res[1:]):
        assert np.all(hi.axial_force_n > lo.axial_force_n - 1e-12)
        assert np.all(hi.m_sliding_nmm + hi.m_rolling_nmm >= lo.m_sliding_nmm + lo.m_rolling_nmm - 1e-12)
    p3 = res[3]
    # U shape: minimum at the loose-fit temperature, sharp rise above it
    assert T_GRID[np.argmin(p3.axial_force_n)] == pytest.approx(43.1, abs=0.15)
    assert p3.axial_force_n[0] > p3.axial_force_n[-1] > p3.axial_force_n.min()
    # P = 0: the pair just touches at 20 degC and has a gap (F_a = 0) until the fit loosens and beyond
    gap = T_GRID[res[0].axial_force_n == 0.0]
    assert gap.min() == pytest.approx(20.0, abs=0.15) and gap.max() > 50.0
    ms3 = p3.m_sliding_nmm + p3.m_rolling_nmm
    assert ms3[0] > 2 * ms3.min()


def test_fig8_fig10_interference_trends():
    res = {d: friction_torque(P0.replace(interference_mm=d), T_GRID) for d in (0.004, 0.006, 0.008)}
    cold = [res[d].axial_force_n[0] for d in (0.004, 0.006, 0.008)]
    hot = [res[d].axial_force_n[-1] for d in (0.004, 0.006, 0.008)]
    assert max(cold) / min(cold) - 1 < 0.03          # little effect in the cold
    assert hot[0] > hot[1] > hot[2]                   # larger interference, lower force when hot
    ms = {d: res[d].m_sliding_nmm + res[d].m_rolling_nmm for d in res}
    assert ms[0.008][0] > ms[0.006][0] > ms[0.004][0]  # cold: larger interference, larger torque
    assert ms[0.008][-1] < ms[0.006][-1] < ms[0.004][-1]  # hot: the opposite


def test_two_bearing_axis_and_speed():
    one = friction_torque(P0.replace(bearings_per_axis=1), 0.0)
    two = friction_torque(P0, 0.0)
    assert float(two.m_total_nmm) == pytest.approx(2 * float(one.m_total_nmm))
    fast = friction_torque(P0, -40.0, speed_rpm=30.0)
    slow = friction_torque(P0, -40.0)
    assert float(fast.m_viscous_nmm) == pytest.approx(float(slow.m_viscous_nmm) * 90 ** (2 / 3), rel=1e-9)
    assert float(fast.m_sliding_nmm) == pytest.approx(float(slow.m_sliding_nmm))


def test_half_ball_radius_option_raises_m_r_5_percent():
    harris = friction_torque(P0, -40.0)
    half = friction_torque(P0.replace(hysteresis_radius='half_ball'), -40.0)
    assert float(half.m_rolling_nmm) / float(harris.m_rolling_nmm) == pytest.approx(1.05, abs=0.01)


def test_paper_literal_width_option_equals_shorter_L():
    lit = friction_torque(P0.replace(scale_bearing_width=False), [-40.0, 60.0])
    short = friction_torque(P0.replace(shaft_length_mm=54.3 - 11.7), [-40.0, 60.0])
    np.testing.assert_allclose(lit.axial_force_n, short.axial_force_n, rtol=5e-3)  # C1 also holds L


def test_negative_clearance_radially_preloaded():
    """Large interference in the cold: clearance < 0, alpha0 = 0, balls still loaded (Eq. 4 0/0 avoided)."""
    p = P0.replace(interference_mm=0.012)
    r = friction_torque(p, -40.0)
    assert float(r.radial_clearance_mm) < 0 and float(r.free_contact_angle_deg) == 0.0
    assert np.isfinite(float(r.m_total_nmm)) and float(r.ball_load_n) > 0


def test_domain_errors_never_nan():
    with pytest.raises(ModelDomainError):
        friction_torque(P0, [np.nan])
    with pytest.raises(ModelDomainError):
        friction_torque(P0, [-400.0])
    # an extreme but valid configuration gives large, finite numbers
    extreme = friction_torque(dataclasses.replace(P0, gasket_thickness_mm=1.0, extra_compliance_mm_per_n=0.0),
                              [-60.0, 20.0, 120.0])
    assert np.all(np.isfinite(extreme.m_total_nmm)) and np.all(extreme.contact_angle_deg < 80.0)
