"""Parameter validation (named errors, never NaN) and the tabulated fast path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.xp import ARRAY, SCALAR
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams, parameter_specs
from gimbal_friction.physics.table import FrictionTable

P0 = AxisParams()


@pytest.mark.parametrize(('changes', 'name', 'rule'), [
    ({'ball_diameter_mm': -1.0}, 'ball_diameter_mm', 'must be > 0'),
    ({'ball_diameter_mm': 2.5}, 'ball_diameter_mm', 'balls do not fit'),
    ({'inner_groove_curvature': 0.5}, 'inner_groove_curvature', 'must lie in (0.5, 1)'),
    ({'steel_poisson_ratio': 0.6}, 'steel_poisson_ratio', 'must lie in [0, 0.5)'),
    ({'bore_diameter_mm': 30.0}, 'bore_diameter_mm', 'smaller than outside_diameter_mm'),
    ({'ball_count': 40}, 'ball_count', 'pitch circle'),
    ({'ball_count': 14.5}, 'ball_count', 'whole number'),
    ({'housing_outside_diameter_mm': 25.0}, 'housing_outside_diameter_mm', 'must exceed'),
    ({'walther_b': 2.0}, 'walther_b', 'must lie in'),
    ({'viscosity_model': 'vogel'}, 'viscosity_model', 'must be one of'),
    ({'palmgren_factor': math.nan}, 'palmgren_factor', 'finite'),
    ({'gasket_thickness_mm': 'thick'}, 'gasket_thickness_mm', 'must be a number'),
    ({'scale_bearing_width': 1}, 'scale_bearing_width', 'true or false'),
    ({'ball_diamter_mm': 2.0}, 'ball_diamter_mm', 'unknown model parameter'),
    ({'outer_groove_diameter_mm': 27.0}, 'inner_groove_diameter_mm', 'bore < inner groove'),
])
def test_bad_values_are_refused_with_the_parameter_named(changes, name, rule):
    with pytest.raises(ConfigError) as info:
        AxisParams.from_mapping(changes)
    assert info.value.parameter == name
    assert rule in info.value.rule
    assert name in str(info.value)


def test_specs_document_every_parameter():
    specs = parameter_specs()
    assert {s['name'] for s in specs} == set(P0.to_mapping())
    assert all(s['unit'] and s['description'] for s in specs)
    assert AxisParams.from_mapping(P0.to_mapping()) == P0


def test_int_accepted_for_float_parameter():
    assert AxisParams.from_mapping({'width_mm': 5}).width_mm == 5.0


@pytest.mark.slow
def test_table_interpolation_error_is_small():
    table = FrictionTable(P0, -60.0, 120.0, 0.1)
    assert len(table.grid) == 1802 and table.grid[0] < -60.0 < table.grid[1]  # a node on the loose-fit kink
    rng = np.random.default_rng(1)
    temps = rng.uniform(-60.0, 120.0, 400)
    speeds = rng.uniform(0.0, 5.0, 400)
    exact = friction_torque(P0, temps, speeds).m_total_nmm
    fast = np.array([table.torque_nmm(t, n) for t, n in zip(temps, speeds)])
    rel = np.abs(fast / exact - 1)
    assert rel.max() < 1e-6, rel.max()
    # against the scalar reference solve too
    some = temps[:15]
    direct = friction_torque(P0, some, speeds[:15], direct=True).m_total_nmm
    np.testing.assert_allclose([table.torque_nmm(t, n) for t, n in zip(some, speeds[:15])], direct, rtol=2e-5)
    # vectorised evaluate gives the scalar numbers
    _, _, m = table.evaluate(temps, speeds)
    np.testing.assert_allclose(m, fast, rtol=1e-12)


def test_table_clamps_outside_and_scalar_equals_array():
    table = FrictionTable(P0)
    assert not table.in_range(-80.0) and table.torque_nmm(-80.0, 1 / 3) == table.torque_nmm(-60.0, 1 / 3)
    assert table.in_range(20.0)
    t = np.linspace(-80.0, 130.0, 97)
    w = np.linspace(-0.5, 0.5, 97)
    arr = table.magnitude_nm(t, w, ARRAY)
    one = [table.magnitude_nm(float(a), float(b), SCALAR) for a, b in zip(t, w, strict=True)]
    np.testing.assert_allclose(arr, one, rtol=1e-13)   # one rule, floats or arrays
    assert table.torque_nm(-40.0, 2 * math.pi / 180) == pytest.approx(1e-3 * table.torque_nmm(-40.0, 1 / 3),
                                                                       rel=1e-12)


def test_table_is_exact_to_the_grid_at_the_loose_fit_kink():
    """A grid node sits on the loose-fit temperature (the contact torques' kink): no interpolation across it."""
    from gimbal_friction.physics.thermal import loose_fit_temperature
    table = FrictionTable(P0)
    kink = loose_fit_temperature(P0)
    assert table.t0 <= -60.0 and table.t0 > -60.0 - table.step and table.t_min == -60.0
    assert abs((kink - table.t0) / table.step - round((kink - table.t0) / table.step)) < 1e-9
    t = np.linspace(kink - 0.3, kink + 0.3, 601)
    exact = friction_torque(P0, t, 1 / 3).m_total_nmm * 1e-3
    got = table.magnitude_nm(t, np.full(t.size, 2 * math.pi / 180), ARRAY)
    assert np.max(np.abs(got / exact - 1)) < 1e-6


@pytest.mark.parametrize('t_c', [-40.0, 20.0, 60.0, 117.3])
def test_table_terms_give_eq9_on_both_palmgren_branches_as_floats_and_arrays(t_c):
    """The per-temperature products of the table's terms (N*m, nu x rpm per rad/s) give the tabulated M_R + M_S
    plus Palmgren's Eq. (9) of every bearing on both sides of its switch nu n = 2000, floats and arrays alike."""
    from gimbal_friction.common.units import RPM_PER_RAD_S
    from gimbal_friction.physics.friction import viscous_torque_Palmgren_1959
    table = FrictionTable(P0)
    terms = table.temperature_terms(t_c, SCALAR)
    switch_rad_s = 2000.0 / (terms.viscosity_cst * RPM_PER_RAD_S)
    w = switch_rad_s * np.array([0.0, 0.3, 0.999, 1.001, 4.0, -0.999, -1.001, -4.0])
    low = np.abs(w) < switch_rad_s
    assert low.sum() == 4 and (~low).sum() == 4   # both branches, both directions
    m_l = P0.bearings_per_axis * viscous_torque_Palmgren_1959(P0.palmgren_factor, terms.viscosity_cst,
                                                               np.abs(w) * RPM_PER_RAD_S, terms.pitch_mm)
    want = (terms.m_contact_nmm + m_l) * 1e-3
    np.testing.assert_allclose(m_l[low], P0.bearings_per_axis * 1e-7 * P0.palmgren_factor * terms.pitch_mm ** 3
                               * 160.0, rtol=1e-12)   # the low branch is the constant one
    arr = table.magnitude_nm(np.full(w.shape, t_c), w, ARRAY)
    one = [table.magnitude_nm(t_c, float(x), SCALAR) for x in w]
    np.testing.assert_allclose(arr, want, rtol=1e-13)
    np.testing.assert_allclose(one, want, rtol=1e-13)
