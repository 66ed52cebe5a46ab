"""export/table.py: the exported table meets its error bound against the full model, handles the kinks and the
Palmgren branch switch, follows the parameters, refuses impossible bounds; the C header compiles with gcc and
its functions agree with the Python model and the feedforward rule."""

from __future__ import annotations

import csv
import io
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError
from gimbal_friction.common.units import rad_s_from_rpm, rpm_from_rad_s
from gimbal_friction.common.xp import ARRAY, SCALAR
from gimbal_friction.export.formats import CSV_FIELDS, ROS_NODE, render_c_header, render_csv, render_ros_yaml
from gimbal_friction.export.table import (
    PALMGREN_JUMP,
    PALMGREN_SWITCH_CST_RPM,
    ExportOptions,
    Provenance,
    build_table,
    c_identifier,
)
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.direction import direction_factor
from gimbal_friction.physics.friction import viscous_torque_Palmgren_1959
from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import FrictionTable
from gimbal_friction.physics.thermal import loose_fit_temperature

BOUND = 1e-4
PROV = Provenance('gimbal-friction export test', '2025-01-01T00:00:00+00:00',
                  (('packaged defaults', '0' * 64), ('refit.yaml', 'f' * 64)))

V_TH = FeedforwardSettings().velocity_threshold_rad_s


def model_nm(params, t, v):
    """The full model, called here directly (not through the module under test), [N*m]."""
    rpm = rpm_from_rad_s(np.abs(np.asarray(v, dtype=float)))
    return 1e-3 * friction_torque(params, t, rpm).m_total_nmm


def model_upper_branch(params, t, v):
    return viscosity_cst(params, t) * rpm_from_rad_s(np.abs(v)) >= 2000.0


#: the numerics are checked over the node's credible range, past the model's validity range (extrapolate=True: a
#: table for a controller keeps to the validity range, see test_the_table_keeps_to_the_models_validity_range)
WIDE = {'temperature_min_c': -60.0, 'temperature_max_c': 120.0}


@pytest.fixture(scope='module')
def table():
    return build_table('elevation', AxisParams(), FeedforwardSettings(), ExportOptions(relative_error=BOUND, **WIDE),
                       extrapolate=True)


def test_palmgren_switch_constant_is_the_models():
    """The table's coordinate rests on Eq. (9) switching at nu*n = 2000 with a jump of PALMGREN_JUMP."""
    below = viscous_torque_Palmgren_1959(1.917, PALMGREN_SWITCH_CST_RPM * (1 - 1e-12), 1.0, 21.5)
    at = viscous_torque_Palmgren_1959(1.917, PALMGREN_SWITCH_CST_RPM, 1.0, 21.5)
    assert float(below / at) - 1.0 == pytest.approx(PALMGREN_JUMP, rel=1e-9)
    assert abs(PALMGREN_JUMP - 0.0079) < 1e-4


def test_bound_met_at_every_midpoint(table):
    """Independent midpoint check: every temperature interval at speed 0, and where the speed-dependent branch is
    reachable, just above the switch, at the maximum speed and half way between; every upper row half way."""
    p, g, vmax = table.params, table.grid, table.options.max_speed_rad_s
    t = g.t
    tm = 0.5 * (t[:-1] + t[1:])
    err0 = np.abs(table.evaluate_nm(tm, 0.0) - model_nm(p, tm, 0.0)) / model_nm(p, tm, 0.0)
    assert err0.max() <= BOUND
    vs_true = rad_s_from_rpm(2000.0 / viscosity_cst(p, tm))
    vs_table = np.exp(0.5 * (g.ln_vs[:-1] + g.ln_vs[1:]))
    v_lo = np.maximum(vs_true, vs_table) * (1 + 1e-6)
    sel = (v_lo < vmax) & (np.arange(len(tm)) + 1 < g.upper_nm.shape[0])
    assert sel.sum() > 100   # the speed-dependent region is large with the defaults
    for v in (v_lo[sel], np.full(sel.sum(), vmax), np.sqrt(v_lo[sel] * vmax)):
        m = model_nm(p, tm[sel], v)
        assert model_upper_branch(p, tm[sel], v).all()
        assert (np.abs(table.evaluate_nm(tm[sel], v) - m) / m).max() <= BOUND
    r = table.report
    assert r.midpoint_max_relative_error <= BOUND and r.midpoint_checks >= len(tm)
    assert r.temperatures == len(t) and r.upper_rows == g.upper_nm.shape[0]


def test_bound_met_at_random_points_outside_the_switch_band(table):
    p = table.params
    rng = np.random.default_rng(1234)          # not the build's seed
    n = 20000
    t = rng.uniform(-60.0, 120.0, n)
    v = np.concatenate([rng.uniform(-10.0, 10.0, n // 2), 10.0 * 10.0 ** rng.uniform(-6, 0, n // 2)])
    m = model_nm(p, t, v)
    err = np.abs(table.evaluate_nm(t, v) - m) / m
    vs_table = np.exp(np.interp(t, table.grid.t, table.grid.ln_vs))
    table_upper = (np.abs(v) >= vs_table) & (t <= table.grid.t[table.grid.upper_nm.shape[0] - 1])
    other_branch = table_upper != model_upper_branch(p, t, v)
    assert other_branch.sum() <= 5             # the band is about 1e-4 wide
    assert err[~other_branch].max() <= BOUND
    assert table.report.random_max_relative_error <= BOUND
    assert table.report.random_points + table.report.switch_band_points == 20000


def test_switch_band_is_narrow_and_its_error_is_the_models_own_jump(table):
    """Between the interpolated and the exact switch speed the table and the model take different branches of
    Eq. (9): the error there is the model's jump (0.79 % of M_L), and the band is within half the bound."""
    p, g = table.params, table.grid
    assert 0.0 < table.report.switch_band <= 0.5 * BOUND
    k = g.upper_nm.shape[0]
    tm = 0.5 * (g.t[:k - 1] + g.t[1:k])
    vs_true = rad_s_from_rpm(2000.0 / viscosity_cst(p, tm))
    vs_table = np.exp(0.5 * (g.ln_vs[:k - 1] + g.ln_vs[1:k]))
    assert np.all(np.abs(vs_table / vs_true - 1.0) <= table.report.switch_band * (1 + 1e-9))
    v = np.sqrt(vs_true * vs_table)            # strictly between the two switch speeds
    ok = (np.abs(vs_table / vs_true - 1) > 1e-12) & (v < table.options.max_speed_rad_s)
    t, v = tm[ok], v[ok]
    assert len(t) > 50
    res = friction_torque(p, t, rpm_from_rad_s(v))
    err = np.abs(table.evaluate_nm(t, v) - 1e-3 * res.m_total_nmm) / (1e-3 * res.m_total_nmm)
    jump = PALMGREN_JUMP * res.m_viscous_nmm / res.m_total_nmm
    assert err.max() > 10 * BOUND              # really the other branch
    assert np.all(err <= jump + BOUND)


def test_kinks_loose_fit_is_a_breakpoint_and_the_switch_is_sharp(table):
    p = table.params
    kink = loose_fit_temperature(p)
    assert table.report.loose_fit_c == pytest.approx(kink)
    assert np.min(np.abs(table.grid.t - kink)) == 0.0
    # on both sides of the kink, close to it
    t = kink + np.array([-1e-3, -0.05, 0.05, 1e-3])
    assert np.all(np.abs(table.evaluate_nm(t, 0.0) / model_nm(p, t, 0.0) - 1) <= BOUND)
    # just below and above the switch speed (outside the band), at temperatures where it is in range
    rng = np.random.default_rng(7)
    t = rng.uniform(-60.0, 45.0, 2000)
    vs = rad_s_from_rpm(2000.0 / viscosity_cst(p, t))
    for factor in (1 - 3 * BOUND, 1 + 3 * BOUND):
        v = vs * factor
        m = model_nm(p, t, v)
        assert np.all(np.abs(table.evaluate_nm(t, v) / m - 1) <= BOUND)


def test_switch_nodes_sit_on_the_upper_branch_even_when_very_cold():
    """At -100 degC nu is 2e15 cSt and v* = 1e-12 rad/s: the eta = 1 nodes must still be on the upper branch of
    Eq. (9) (exp(ln v*) alone loses |ln v*| ulp and can land below the switch)."""
    t = build_table('elevation', AxisParams(), FeedforwardSettings(),
                    ExportOptions(temperature_min_c=-100.0, temperature_max_c=0.0, random_points=2000),
                    extrapolate=True)
    g = t.grid
    k = g.upper_nm.shape[0]
    assert k == len(g.t)
    ratio = g.upper.m_viscous_nmm[:, 0] / g.lower.m_viscous_nmm[:k]
    assert np.allclose(ratio, 1.0 / (1.0 + PALMGREN_JUMP), rtol=1e-12)
    assert t.report.midpoint_max_relative_error <= BOUND and t.report.random_max_relative_error <= BOUND


def test_speed_matters_only_where_nu_n_reaches_2000(table):
    p, o = table.params, table.options
    t_s = table.report.speed_matters_below_c
    assert t_s == pytest.approx(50.5, abs=0.5)       # nu(t_s) * 95.5 rpm = 2000 with the defaults
    nu = float(viscosity_cst(p, t_s))
    assert nu * rpm_from_rad_s(o.max_speed_rad_s) == pytest.approx(2000.0, rel=1e-9)
    hot = np.linspace(t_s + 0.01, 120.0, 50)
    assert np.array_equal(table.evaluate_nm(hot, 0.0), table.evaluate_nm(hot, o.max_speed_rad_s))
    cold = np.linspace(-60.0, t_s - 1.0, 50)
    assert np.all(table.evaluate_nm(cold, o.max_speed_rad_s) > table.evaluate_nm(cold, 0.0))
    # the speed-dependent table stops at the first breakpoint above t_s
    k = table.grid.upper_nm.shape[0]
    assert table.grid.t[k - 2] < t_s <= table.grid.t[k - 1]


def test_edges_are_clamped(table):
    t0, t1 = table.grid.t[0], table.grid.t[-1]
    vmax = table.options.max_speed_rad_s
    assert table.evaluate_nm(-100.0, 0.0) == table.evaluate_nm(t0, 0.0)
    assert table.evaluate_nm(500.0, 3.0) == table.evaluate_nm(t1, 3.0)
    assert table.evaluate_nm(-20.0, 50.0) == table.evaluate_nm(-20.0, vmax) == table.evaluate_nm(-20.0, -vmax)
    assert table.evaluate_nm(-20.0, -0.5) == table.evaluate_nm(-20.0, 0.5)


def test_a_refit_changes_the_table_and_still_meets_the_bound(table):
    refit = AxisParams().replace(walther_a=8.70, walther_b=-21.40)   # a stiffer cold lubricant, as refit writes
    other = build_table('elevation', refit, FeedforwardSettings(), ExportOptions(relative_error=BOUND,
                                                                                  random_points=2000))
    t = np.array([-40.0, 0.0, 30.0])          # nu * n >= 2000 at 5 rad/s: the viscous torque follows the oil
    assert np.all(other.evaluate_nm(t, 5.0) > 1.05 * table.evaluate_nm(t, 5.0))
    assert not np.array_equal(other.grid.ln_vs[:3], table.grid.ln_vs[:3])
    m = model_nm(refit, t, 5.0)
    assert np.all(np.abs(other.evaluate_nm(t, 5.0) / m - 1) <= BOUND)
    assert other.report.speed_matters_below_c != table.report.speed_matters_below_c


@pytest.mark.parametrize(('change', 'name'), [
    ({'relative_error': 0.0}, 'relative_error'), ({'relative_error': -1e-4}, 'relative_error'),
    ({'relative_error': math.nan}, 'relative_error'), ({'relative_error': 1e-13}, 'relative_error'),
    ({'max_speed_rad_s': 0.0}, 'max_speed_rad_s'), ({'temperature_max_c': -70.0}, 'temperature_max_c'),
    ({'temperature_min_c': -300.0}, 'temperature_min_c'), ({'random_points': 5}, 'random_points'),
])
def test_bad_options_refused_naming_the_option(change, name):
    with pytest.raises(ConfigError) as info:
        build_table('elevation', AxisParams(), FeedforwardSettings(), ExportOptions(**change))
    assert info.value.parameter == name
    assert '\n' not in str(info.value)


def test_a_bound_that_would_explode_the_grid_is_refused():
    with pytest.raises(GimbalFrictionError, match=r'needs more than 400 temperature breakpoints') as info:
        build_table('elevation', AxisParams(), FeedforwardSettings(),
                    ExportOptions(relative_error=1e-8, max_breakpoints=400, random_points=100))
    assert '\n' not in str(info.value)


def test_c_identifier_and_files_for_odd_joint_names():
    assert c_identifier('gimbal/az-1') == 'gimbal_az_1'
    t = build_table('gimbal/az-1', AxisParams(), FeedforwardSettings(), ExportOptions(relative_error=1e-3,
                                                                                      random_points=200))
    header = render_c_header(t, PROV)
    assert 'gf_gimbal_az_1_friction_nm' in header and '#ifndef GIMBAL_FRICTION_GIMBAL_AZ_1_H' in header


# ---------------------------------------------------------------------------------------------- text formats
def test_csv_has_provenance_units_and_the_grid(table):
    text = render_csv(table, PROV)
    comments = [line for line in text.splitlines() if line.startswith('#')]
    joined = '\n'.join(comments)
    for needle in ('gimbal-friction export test', '2025-01-01', 'axis: elevation', 'refit.yaml: ' + 'f' * 64,
                   'packaged defaults: ' + '0' * 64, 'requested 0.0001', 'walther_a = 8.6195',
                   'ball_diameter_mm = 2.381 [mm]', f'velocity_threshold_rad_s = {V_TH} [rad/s]'):
        assert needle in joined
    rows = list(csv.DictReader(io.StringIO('\n'.join(line for line in text.splitlines()
                                                     if not line.startswith('#')))))
    assert list(rows[0]) == list(CSV_FIELDS)
    k = table.grid.upper_nm.shape[0]
    assert len(rows) == len(table.grid.t) + 2 * k
    lower = [r for r in rows if float(r['eta']) == 0.0]
    assert [float(r['temperature_c']) for r in lower] == table.grid.t.tolist()
    assert [float(r['m_total_nm']) for r in lower] == table.grid.lower_nm.tolist()
    for r in rows[:30]:
        assert float(r['m_total_nm']) == pytest.approx(float(r['m_total_nmm']) * 1e-3, rel=1e-15)
        assert float(r['m_total_nmm']) == pytest.approx(float(r['m_rolling_nmm']) + float(r['m_sliding_nmm'])
                                                        + float(r['m_viscous_nmm']), rel=1e-12)
        assert float(r['speed_rad_s']) == pytest.approx(rad_s_from_rpm(float(r['speed_rpm'])), rel=1e-12)


def _lookup_from_ros_parameters(e, t, v):
    """A controller engineer's implementation of the lookup rule, from the YAML arrays alone."""
    T = np.array(e['temperatures_c'])
    L = np.array(e['ln_switch_speed'])
    lower = np.array(e['torque_lower_nm'])
    upper = np.array(e['torque_upper_nm']).reshape(e['torque_upper_shape'])
    eta0, eta1 = e['eta_breakpoints']
    t = min(max(t, T[0]), T[-1])
    s = min(abs(v), e['max_speed_rad_s'])
    i = min(max(int(np.searchsorted(T, t, side='right')) - 1, 0), len(T) - 2)
    w = (t - T[i]) / (T[i + 1] - T[i])
    xi = s * math.exp(-(L[i] + w * (L[i + 1] - L[i])))
    if xi < 1.0 or i + 1 >= upper.shape[0]:
        return lower[i] + w * (lower[i + 1] - lower[i])
    a = upper[i] + w * (upper[i + 1] - upper[i])
    u = (min(xi ** (2.0 / 3.0), eta1) - eta0) / (eta1 - eta0)
    return a[0] + u * (a[1] - a[0])


def test_ros_yaml_loads_and_its_arrays_reproduce_the_table(table, tmp_path):
    text = render_ros_yaml(table, PROV)
    assert 'refit.yaml: ' + 'f' * 64 in text and 'requested 0.0001' in text
    doc = yaml.safe_load(text)
    e = doc[ROS_NODE]['ros__parameters']['elevation']
    assert e['joint'] == 'elevation'
    assert len(e['temperatures_c']) == len(e['ln_switch_speed']) == len(e['torque_lower_nm'])
    assert len(e['torque_upper_nm']) == e['torque_upper_shape'][0] * e['torque_upper_shape'][1]
    assert e['relative_error_bound'] == BOUND and e['max_relative_error'] <= BOUND
    assert e['velocity_threshold_rad_s'] == V_TH and e['max_torque_nm'] == 0.02
    rng = np.random.default_rng(3)
    for t, v in zip(rng.uniform(-70, 130, 300), rng.uniform(-12, 12, 300), strict=True):
        assert _lookup_from_ros_parameters(e, t, v) == pytest.approx(float(table.evaluate_nm(t, v)), rel=1e-13)
    # the suite's loader and ROS's own parameter-file parser accept it
    path = tmp_path / 'params.yaml'
    path.write_text(text)
    from gimbal_friction.config.loader import load_parameters
    loaded = load_parameters([path], node_name=ROS_NODE)
    assert loaded['elevation']['temperatures_c'] == e['temperatures_c']
    rclpy_parameter = pytest.importorskip('rclpy.parameter')
    msgs = rclpy_parameter.parameter_dict_from_yaml_file(str(path), target_nodes=[ROS_NODE])
    values = {name: rclpy_parameter.parameter_value_to_python(m.value) for name, m in msgs.items()}
    assert list(values['elevation.torque_upper_nm']) == e['torque_upper_nm']     # a double array
    assert list(values['elevation.torque_upper_shape']) == e['torque_upper_shape']   # an integer array
    assert values['elevation.joint'] == 'elevation'


# ---------------------------------------------------------------------------------------------- C header
def _gcc() -> str:
    gcc = shutil.which('gcc')
    assert gcc is not None, 'gcc is required to test the exported C header (CI has it): apt-get install gcc'
    return gcc


CFLAGS = ['-std=c99', '-Wall', '-Wextra', '-Werror', '-pedantic']

DRIVER = r"""
#include <stdio.h>
#include "gimbal_friction_%(a)s.h"
int main(void)
{
    double t, v;
    while (scanf("%%lf %%lf", &t, &v) == 2) {
        printf("%%.17g %%.17g\n", gf_%(a)s_friction_nm(t, v), gf_%(a)s_feedforward_nm(t, v));
    }
    return 0;
}
"""


def _run_c(tmp_path: Path, tables, t, v, axis: str):
    for tb in tables:
        (tmp_path / f'gimbal_friction_{c_identifier(tb.axis)}.h').write_text(render_c_header(tb, PROV))
    src = tmp_path / 'driver.c'
    src.write_text(DRIVER % {'a': c_identifier(axis)})
    exe = tmp_path / 'driver'
    subprocess.run([_gcc(), *CFLAGS, '-O2', str(src), '-o', str(exe), '-lm'], check=True, capture_output=True,
                   text=True, cwd=tmp_path)
    text = ''.join(f'{float(a)!r} {float(b)!r}\n' for a, b in zip(t, v, strict=True))
    out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True, timeout=60)
    res = np.array(out.stdout.split(), dtype=float).reshape(-1, 2)
    return res[:, 0], res[:, 1]


def test_c_header_compiles_on_its_own_and_with_another_axis(table, tmp_path):
    header = tmp_path / 'gimbal_friction_elevation.h'
    header.write_text(render_c_header(table, PROV))
    for args in (['-x', 'c', '-c', str(header)], ['-x', 'c', '-O2', '-c', str(header)]):
        done = subprocess.run([_gcc(), *CFLAGS, *args, '-o', str(tmp_path / 'x.o')], capture_output=True, text=True,
                              check=False)
        assert done.returncode == 0, done.stderr
    other = build_table('azimuth', AxisParams().replace(interference_mm=0.004), FeedforwardSettings(),
                        ExportOptions(relative_error=1e-3, random_points=200))
    (tmp_path / 'gimbal_friction_azimuth.h').write_text(render_c_header(other, PROV))
    src = tmp_path / 'both.c'
    src.write_text('#include "gimbal_friction_elevation.h"\n#include "gimbal_friction_elevation.h"\n'
                   '#include "gimbal_friction_azimuth.h"\n'
                   'double both(double t, double v);\n'
                   'double both(double t, double v)\n'
                   '{\n    return gf_elevation_feedforward_nm(t, v) + gf_azimuth_feedforward_nm(t, v);\n}\n')
    done = subprocess.run([_gcc(), *CFLAGS, '-c', str(src), '-o', str(tmp_path / 'both.o')], capture_output=True,
                          text=True, cwd=tmp_path, check=False)
    assert done.returncode == 0, done.stderr


def test_c_function_agrees_with_the_python_model_at_random_points(table, tmp_path):
    rng = np.random.default_rng(99)
    n = 5000
    t = rng.uniform(-60.0, 120.0, n)
    v = np.concatenate([rng.uniform(-10.0, 10.0, n // 2),
                        np.where(rng.uniform(size=n // 2) < 0.5, -1, 1) * 10.0 ** rng.uniform(-5, 1, n // 2)])
    c_friction, _ = _run_c(tmp_path, [table], t, v, 'elevation')
    # the same arithmetic as the Python evaluator of the table ...
    assert np.max(np.abs(c_friction / table.evaluate_nm(t, v) - 1)) < 1e-12
    # ... and within the bound of the full model (outside the switch band)
    m = model_nm(table.params, t, v)
    err = np.abs(c_friction - m) / m
    vs_table = np.exp(np.interp(t, table.grid.t, table.grid.ln_vs))
    table_upper = (np.abs(v) >= vs_table) & (t <= table.grid.t[table.grid.upper_nm.shape[0] - 1])
    outside = table_upper == model_upper_branch(table.params, t, v)
    assert outside.sum() >= n - 3
    assert err[outside].max() <= BOUND


@pytest.mark.slow
def test_c_feedforward_is_the_nodes_rule(tmp_path):
    """gf_<axis>_feedforward_nm against Feedforward.torque_at (the node's rule) with direction factors
    and a clamp that bites; tolerance: the bound plus the node table's own (0.1 degC grid) error."""
    params = AxisParams().replace(scale_positive=1.1, scale_negative=0.8, direction_asymmetry_cold=0.13,
                                  direction_asymmetry_warm=-0.12)   # the per-direction term, as refitted on the paper
    settings = FeedforwardSettings(velocity_threshold_rad_s=0.01, max_torque_nm=0.0016)
    tb = build_table('elevation', params, settings, ExportOptions(relative_error=BOUND, random_points=2000))
    rng = np.random.default_rng(5)
    n = 3000
    t = rng.uniform(-60.0, 120.0, n)
    v = np.concatenate([rng.uniform(-10.0, 10.0, n // 2), rng.uniform(-0.05, 0.05, n // 2)])
    _, c_ff = _run_c(tmp_path, [tb], t, v, 'elevation')
    logic = Feedforward({'elevation': params}, settings)
    node = np.array([logic.torque_at('elevation', float(b), float(a)) for a, b in zip(t, v, strict=True)])
    node_table = FrictionTable(params)
    node_m = np.array([node_table.torque_nm(float(a), float(b)) for a, b in zip(t, v, strict=True)])
    m = model_nm(params, t, v)
    tol = (BOUND + np.abs(node_m / m - 1)) * np.abs(node) + 1e-18
    assert np.all(np.abs(c_ff - node) <= tol)
    assert np.sum(np.abs(c_ff) == 0.0016) > 100 and np.max(np.abs(c_ff)) == 0.0016   # the clamp bites
    assert np.all(np.sign(c_ff[v != 0]) == np.sign(v[v != 0]))
    # direction factors: same |v| both ways differs by k_+(T) / k_-(T) where the clamp does not bite, and the
    # asymmetry changes with temperature as the core's rule says
    for temp in (-50.0, 20.0, 70.0):
        probe_t, probe_v = np.array([temp, temp]), np.array([0.002, -0.002])
        _, ff = _run_c(tmp_path, [tb], probe_t, probe_v, 'elevation')
        expected = direction_factor(params, temp, 1.0, SCALAR) / direction_factor(params, temp, -1.0, SCALAR)
        assert -ff[0] / ff[1] == pytest.approx(expected, rel=1e-12)


def test_c_edges_and_non_finite_inputs(table, tmp_path):
    t = np.array([-100.0, -60.0, 200.0, 120.0, -20.0, -20.0, 20.0, math.nan, 20.0, math.inf])
    v = np.array([0.5, 0.5, 0.5, 0.5, 50.0, 10.0, math.nan, 0.5, math.inf, 0.5])
    friction, ff = _run_c(tmp_path, [table], t, v, 'elevation')
    assert friction[0] == friction[1] and friction[2] == friction[3]   # temperature clamped
    assert friction[4] == friction[5]                                 # speed clamped at max_speed_rad_s
    assert math.isnan(friction[6]) and math.isnan(friction[7])         # NaN in, NaN out
    assert ff[6] == ff[7] == ff[8] == ff[9] == 0.0                     # feedforward: 0 on non-finite input
    assert friction[9] == friction[3]                                 # +inf temperature clamps to the top


# ---------------------------------------------------------------------------------------------- learned correction
POSITION = math.nan   # the export is the correction's lookup without a joint position


def _learned_correction(settings=None):
    """A correction of 'elevation' learned against the default parameters with every term the fit knows: a level
    falling with temperature, a CW/CCW asymmetry, a speed profile over the octaves, a torque independent of the
    direction (an unbalance) and a position ripple; plus one cell with a single sample (its error is unknown)."""
    from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity
    s = settings or CorrectionSettings(prior_samples=20.0, max_relative=0.2, guard_min_samples=0, guard_z=0.0)
    rng = np.random.default_rng(5)
    n = 30_000
    t = rng.uniform(-55.0, 70.0, n)
    v = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-2.2, 0.3, n)
    p = rng.uniform(0.0, 0.5, n)
    m = np.full(n, 2e-3)
    along = 4e-4 * (-t / 50.0 + 0.5 * (v > 0) + 0.8 * np.abs(v) ** (2 / 3)) \
        + 0.1 * m * np.sin(2 * np.pi * p / 0.05)        # a ripple, relative to the model friction
    r = np.sign(v) * along + 3e-4 + rng.normal(0.0, 1e-4, n)   # + an unbalance the motor must supply both ways
    one = (100.0, 0.05, 0.0, 1e-4, 2e-3)     # a cell with one sample
    cols = [np.append(a, x) for a, x in zip((t, v, p, r, np.sign(v) * m), one, strict=True)]
    c, refused = Correction.from_residuals(s, model_identity({'elevation': AxisParams()}), {'elevation': tuple(cols)})
    assert refused == {'elevation': {}}
    return c


@pytest.fixture(scope='module')
def learned():
    return _learned_correction()


CORRECTION_DRIVER = r"""
#include <stdio.h>
#include "gimbal_friction_elevation.h"
int main(void)
{
    double t, v, m, odd, even;
    while (scanf("%lf %lf %lf", &t, &v, &m) == 3) {
        gf_elevation_correction_split_nm(t, v, m, &odd, &even);
        printf("%.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", odd, even, gf_elevation_correction_nm(t, v, m),
               gf_elevation_correction_error_nm(t, v), gf_elevation_feedforward_nm(t, v),
               gf_elevation_friction_nm(t, v), gf_elevation_correction_samples(t, v));
    }
    return 0;
}
"""


def _run_correction_c(tmp_path, header, t, v, m):
    (tmp_path / 'gimbal_friction_elevation.h').write_text(header)
    for args in (['-x', 'c', '-c'], ['-x', 'c', '-O2', '-c']):
        done = subprocess.run([_gcc(), *CFLAGS, *args, 'gimbal_friction_elevation.h', '-o', 'x.o'], cwd=tmp_path,
                              capture_output=True, text=True, check=False)
        assert done.returncode == 0, done.stderr        # standalone, -pedantic -Werror
    (tmp_path / 'driver.c').write_text(CORRECTION_DRIVER)
    done = subprocess.run([_gcc(), *CFLAGS, '-O2', 'driver.c', '-o', 'driver', '-lm'], capture_output=True,
                          text=True, cwd=tmp_path, check=False)
    assert done.returncode == 0, done.stderr
    text = ''.join(f'{float(a)!r} {float(b)!r} {float(x)!r}\n' for a, b, x in zip(t, v, m, strict=True))
    out = subprocess.run([str(tmp_path / 'driver')], input=text, capture_output=True, text=True, check=True,
                         timeout=60)
    return np.array(out.stdout.split(), dtype=float).reshape(-1, 7)


def _correction_points(n, seed=9):
    """Temperatures beyond the bins and at their centres and edges, speeds over and beyond the octaves (both
    signs, zero), model frictions from 0 up (the bound bites)."""
    rng = np.random.default_rng(seed)
    t = np.concatenate([rng.uniform(-80.0, 140.0, n - 8), [-62.5, 122.5, -60.0, 100.0, -40.0, 20.0, 20.0, 20.0]])
    v = np.concatenate([rng.choice([-1.0, 1.0], n // 2) * 10.0 ** rng.uniform(-4.0, 2.0, n // 2),
                        rng.uniform(-0.2, 0.2, n - 8 - n // 2), [0.03, -0.03, -0.03, 0.05, 0.03, 0.0, -0.0, 1e3]])
    m = rng.uniform(0.0, 4e-3, n)
    return t, v, m


@pytest.mark.slow
def test_a_correction_is_exported_as_its_lookup_without_a_position(learned):
    """table_correction holds the tables the lookup reads (after the hold rule), its constants, and per cell the
    samples and the error bound; correction_nm gives the numbers of Correction.split_nm_array at NaN positions."""
    from gimbal_friction.export.table import correction_along_nm, correction_nm, table_correction

    c = learned
    lut = c.lookups['elevation']
    tc = table_correction(c, 'elevation', 'unit')
    assert np.array_equal(tc.odd_nm, lut.odd) and np.array_equal(tc.even_nm, lut.even)
    assert tc.odd_nm.shape == (37, 12) and tc.octaves == 12 and np.abs(tc.even_nm).max() > 2e-4
    assert tc.centres_c[0] == lut.t0 and tc.inv_bin_per_c == lut.inv_bin and tc.min_speed_rad_s == lut.vmin
    assert (tc.max_relative, tc.floor_nm, tc.max_independent_nm) == (lut.rel, lut.floor, lut.independent)
    assert tc.octave_speeds_rad_s[0] == pytest.approx(0.005 * math.sqrt(2.0), rel=1e-15)
    assert len(tc.ripple_periods_rad) >= 1 and tc.ripple_periods_rad[0] == pytest.approx(0.05, rel=0.01)
    assert tc.ripple_max_relative == pytest.approx(0.1, rel=0.2)      # the 10 % ripple learned
    assert tc.position_terms
    t, v, m = _correction_points(20_000)
    odd, even, error = correction_nm(tc, t, v, m)
    want_odd, want_even = c.split_nm_array('elevation', t, v, np.full(t.size, POSITION), m)
    np.testing.assert_allclose(odd, want_odd, rtol=1e-12, atol=1e-19)
    np.testing.assert_allclose(even, want_even, rtol=1e-12, atol=1e-19)
    bound = 0.2 * m + c.settings.floor_nm
    assert np.count_nonzero(np.abs(odd) == bound) > 100                        # the bound bites, as in the node
    assert np.count_nonzero(np.abs(even) == np.maximum(bound, c.settings.max_independent_nm)) == 0
    along, error2 = correction_along_nm(tc, t, v, m)
    np.testing.assert_allclose(along, c.along_nm_array('elevation', t, v, np.full(t.size, POSITION), m),
                               rtol=1e-12, atol=1e-19)
    assert np.array_equal(error, error2, equal_nan=True)
    # the scalar lookup too (the node's hot path)
    for k in range(0, t.size, 97):
        o, e = c.split_nm('elevation', float(t[k]), float(v[k]), POSITION, float(m[k]))
        assert (odd[k], even[k]) == pytest.approx((o, e), rel=1e-12, abs=1e-19)
    # the error bound of a cell: its standard error of the mean, shrunk like its value; unknown with one sample
    cell = next(r for r in c.cells('elevation') if r['direction'] == 'cw' and r['centre_c'] == -40.0)
    k = int(round((-40.0 - tc.centres_c[0]) * tc.inv_bin_per_c))
    assert tc.error_nm[0, k] == pytest.approx(cell['std_error_nm'] * cell['samples'] / (cell['samples'] + 20.0))
    assert tc.samples[0, k] == cell['samples'] and tc.applied[0, k]
    hot = int(round((100.0 - tc.centres_c[0]) * tc.inv_bin_per_c))
    assert tc.samples[0, hot] == 1 and math.isnan(tc.error_nm[0, hot])
    assert tc.samples[1, hot] == 0 and tc.error_nm[1, hot] == 0.0
    # a bin measured in one direction only cannot tell an unbalance from friction: nothing is applied there, nor in the
    # neighbours that would hold its profile (the lookup's tables); the neighbours hold its error
    assert not tc.applied[0, hot] and not np.any(tc.odd_nm[hot]) and not np.any(tc.odd_nm[hot + 1])
    assert math.isnan(tc.error_nm[0, hot + 1]) and math.isnan(tc.error_nm[0, hot - 1])
    assert tc.error_nm[0, hot + 2] == 0.0 and not np.any(tc.odd_nm[hot + 2])


@pytest.mark.slow
def test_a_correction_is_carried_in_every_format_and_the_c_feedforward_adds_it(table, learned, tmp_path):
    """The C header (compiled standalone, -pedantic -Werror) looks the correction up as the feedforward does at a
    NaN position and adds it, tanh(v/v_th) (k_dir M + odd) + even, clamped; the CSV columns and the ROS arrays hold
    the same numbers; the files say the position terms are left out."""
    from gimbal_friction.export.formats import CSV_CORRECTION_FIELDS
    from gimbal_friction.export.table import correction_nm, table_correction

    c = learned
    tc = table_correction(c, 'elevation', 'unit.correction.yaml (SHA-256 ' + 'a' * 64 + ')')
    ct = table._replace(correction=tc)
    assert render_c_header(table, PROV) == render_c_header(table._replace(correction=None), PROV)   # unchanged
    t, v, m = _correction_points(3000)
    res = _run_correction_c(tmp_path, render_c_header(ct, PROV), t, v, m)
    nan = np.full(t.size, POSITION)
    want_odd, want_even = c.split_nm_array('elevation', t, v, nan, m)
    np.testing.assert_allclose(res[:, 0], want_odd, rtol=1e-12, atol=1e-19)
    np.testing.assert_allclose(res[:, 1], want_even, rtol=1e-12, atol=1e-19)
    np.testing.assert_allclose(res[:, 2], c.along_nm_array('elevation', t, v, nan, m), rtol=1e-12, atol=1e-19)
    assert np.count_nonzero(want_odd) > t.size // 2 and np.count_nonzero(want_even) > t.size // 2
    _, _, error = correction_nm(tc, t, v, m)
    np.testing.assert_allclose(res[:, 3], np.where(np.isnan(error), -1.0, error), rtol=1e-12, atol=1e-19)
    assert res[-5, 3] == -1.0 and res[-5, 6] == 1.0   # 100 degC cw: the one-sample cell, its error unknown
    assert res[-4, 6] == tc.samples[0, int(round((-40.0 - tc.centres_c[0]) * tc.inv_bin_per_c))] > 100
    # the C feedforward: clamp(tanh(v/v_th) (k_dir M + odd) + even, +-tau_max), M from the table
    model = direction_factor(AxisParams(), t, v, ARRAY) * res[:, 5]
    odd, even = c.split_nm_array('elevation', t, v, nan, model)
    tau = np.clip(np.tanh(v / V_TH) * (model + odd) + even, -0.02, 0.02)
    ff = res[:, 4]
    finite = np.isfinite(v)
    np.testing.assert_allclose(ff[finite], tau[finite], rtol=1e-12, atol=1e-18)
    assert ff[-3] == ff[-2] == pytest.approx(even[-3], rel=1e-12) and ff[-3] != 0.0   # at v = 0: the even part
    # ... which is the node's rule (Feedforward with the correction, no position) up to the tables' error, inside the
    # model's validity range (where the node's table clamps; this table is the wide one)
    node = Feedforward({'elevation': AxisParams()}, FeedforwardSettings(), correction=c)
    sel = np.flatnonzero((t > -40.0) & (t < 60.0) & (np.abs(v) < 10.0))[:400]
    want = np.array([node.torque_at('elevation', float(v[k]), float(t[k])) for k in sel])
    np.testing.assert_allclose(ff[sel], want, rtol=2e-3, atol=1e-8)
    # the CSV columns: what the feedforward adds along the motion at the row's temperature and speed
    csv_text = render_csv(ct, PROV)
    rows = list(csv.DictReader(io.StringIO('\n'.join(line for line in csv_text.splitlines()
                                                     if not line.startswith('#')))))
    assert list(rows[0]) == [*CSV_FIELDS, *CSV_CORRECTION_FIELDS]
    for r in rows[::7]:
        tt, mm, speed = float(r['temperature_c']), float(r['m_total_nm']), float(r['speed_rad_s'])
        for sign, name in ((1.0, 'cw'), (-1.0, 'ccw')):   # at the row's speed (0: held below min_speed_rad_s)
            kd = float(direction_factor(AxisParams(), tt, sign, SCALAR))
            want = c.along_nm('elevation', tt, sign * max(speed, c.settings.min_speed_rad_s), POSITION, kd * mm)
            assert float(r[f'correction_{name}_nm']) == pytest.approx(want, rel=1e-12, abs=1e-19)
    assert any(float(r['correction_cw_nm']) != float(r['correction_ccw_nm']) for r in rows)
    # the ROS arrays, and a controller engineer's lookup from them alone
    yaml_text = render_ros_yaml(ct, PROV)
    e = yaml.safe_load(yaml_text)[ROS_NODE]['ros__parameters']['elevation']
    assert e['correction_shape'] == [37, 12] and e['correction_odd_nm'] == tc.odd_nm.ravel().tolist()
    assert e['correction_even_nm'] == tc.even_nm.ravel().tolist()
    assert e['correction_max_relative'] == 0.2 and len(e['correction_temperatures_c']) == 37
    assert e['correction_min_speed_rad_s'] == 0.005 and e['correction_max_independent_nm'] == 0.005
    assert e['correction_ccw_samples'] == tc.samples[1].tolist() and -1.0 in e['correction_cw_error_nm']
    assert e['correction_cw_applied'] == tc.applied[0].tolist()
    for k in range(0, t.size, 37):
        o, ev = _correction_from_ros_parameters(e, float(t[k]), float(v[k]), float(m[k]))
        assert (o, ev) == pytest.approx((float(want_odd[k]), float(want_even[k])), rel=1e-12, abs=1e-19)
    # every file names the source and says the position terms are left out
    header = render_c_header(ct, PROV)
    for text in (csv_text, header, yaml_text):
        assert 'Learned correction: unit.correction.yaml' in text
        assert "Not exported: the correction's position terms (a ripple at periods 0.05" in text
        assert ('and a trend with the joint angle (coefficients up to' in text) == (tc.trend_max_nm > 0.0)


def _correction_from_ros_parameters(e, t, v, m):
    """The correction lookup rule written in the files, implemented from the ROS arrays alone: (odd, even)."""
    nb, no = e['correction_shape']
    odd = np.array(e['correction_odd_nm']).reshape(nb, no)
    even = np.array(e['correction_even_nm']).reshape(nb, no)
    x = (t - e['correction_temperatures_c'][0]) * e['correction_inv_bin_per_c']
    if 0.0 < x < nb - 1:
        i = int(x)
        w = x - i
    elif x > 0.0:
        i, w = nb - 2, 1.0
    else:
        i, w = 0, 0.0
    s = abs(v)
    vmin = e['correction_min_speed_rad_s']
    y = math.log2(s / vmin) - 0.5 if s > vmin else -1.0
    out = []
    for table in (odd, even):
        row = (1.0 - w) * table[i] + w * table[i + 1]
        if y <= 0.0:
            out.append(row[0])
        elif y >= no - 1:
            out.append(row[no - 1])
        else:
            k = int(y)
            out.append(row[k] + (y - k) * (row[k + 1] - row[k]))
    if s < vmin:   # the part along the motion fades to 0 at zero speed
        out[0] *= s / vmin
    b = e['correction_max_relative'] * abs(m) + e['correction_floor_nm']
    o = min(max(out[0], -b), b)
    b = max(b, e['correction_max_independent_nm'])
    return o, min(max(out[1], -b), b)


@pytest.mark.slow
def test_a_correction_without_speed_or_position_terms_and_an_axis_without_one(table, tmp_path):
    """One value per cell (speed_term false: one octave) and no position terms: exported and added the same way, and
    the files say nothing is left out; an axis the correction applies nothing to exports zeros (the model)."""
    from gimbal_friction.export.table import correction_nm, table_correction
    from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity

    s = CorrectionSettings(speed_term=False, trend=False, ripple_periods_max=0, guard_min_samples=0, guard_z=0.0)
    c = Correction(s, model_identity({'elevation': AxisParams()}))
    n = 400
    for sign in (1.0, -1.0):
        c.learn_residuals('elevation', [-40.0] * n, [sign * 0.03] * n, [0.0] * n, [sign * 2e-4 + 5e-5] * n,
                          [sign * 3e-3] * n)
    c.settle()
    tc = table_correction(c, 'elevation', 'flat')
    assert tc.octaves == 1 and not tc.position_terms and np.abs(tc.odd_nm).max() > 1e-4
    t, v, m = _correction_points(1000, seed=4)
    res = _run_correction_c(tmp_path, render_c_header(table._replace(correction=tc), PROV), t, v, m)
    want_odd, want_even = c.split_nm_array('elevation', t, v, np.full(t.size, POSITION), m)
    np.testing.assert_allclose(res[:, 0], want_odd, rtol=1e-12, atol=1e-19)
    np.testing.assert_allclose(res[:, 1], want_even, rtol=1e-12, atol=1e-19)
    assert np.count_nonzero(want_even) > 50       # (the bins around -40 degC)
    assert 'Not exported' not in render_csv(table._replace(correction=tc), PROV)
    # nothing applied: zeros, and the C feedforward is the model's to the bit
    empty = table_correction(Correction(s, c.identity), 'elevation', 'empty')
    assert not np.any(empty.odd_nm) and not np.any(empty.even_nm) and empty.samples.sum() == 0
    odd, even, error = correction_nm(empty, t, v, m)
    assert not np.any(odd) and not np.any(even) and not np.any(error)
    with_empty = _run_correction_c(tmp_path, render_c_header(table._replace(correction=empty), PROV), t, v, m)
    _, plain = _run_c(tmp_path, [table], t, v, 'elevation')
    finite = np.isfinite(v)
    assert np.array_equal(with_empty[finite, 4], plain[finite])


def test_the_table_keeps_to_the_models_validity_range():
    """Issue 31 item 3: a table spans the model's validity range by default, refuses a range past it (naming the
    option), narrows with the parameters, and every file says so in its header."""
    default = build_table('elevation', AxisParams(), FeedforwardSettings(), ExportOptions(random_points=200))
    assert (default.temperatures_c[0], default.temperatures_c[-1]) == (-40.0, 60.0)
    for change, name in (({'temperature_min_c': -60.0}, 'temperature_min_c'),
                         ({'temperature_max_c': 120.0}, 'temperature_max_c')):
        with pytest.raises(ConfigError) as info:
            build_table('elevation', AxisParams(), FeedforwardSettings(), ExportOptions(random_points=200, **change))
        assert info.value.parameter == name and 'validity range is -40..60 degC' in str(info.value)
    loose = AxisParams(gasket_thickness_mm=0.0)   # no preload above 20 degC: the range ends there
    with pytest.raises(ConfigError, match='no axial preload'):
        build_table('elevation', loose, FeedforwardSettings(), ExportOptions(random_points=200))
    narrow = build_table('elevation', loose, FeedforwardSettings(),
                         ExportOptions(random_points=200, temperature_max_c=20.0))
    assert narrow.temperatures_c[-1] == 20.0
    for text in (render_csv(default, PROV), render_c_header(default, PROV), render_ros_yaml(default, PROV)):
        assert "The model's validity range is -40 .. 60 degC" in text
    assert 'validity range is -40 .. 20 degC (the bearing pair has no axial preload' in render_csv(narrow, PROV)


def test_c_header_says_it_carries_no_presliding_term(table):
    text = render_c_header(table, PROV)
    assert 'No pre-sliding (dynamic) term' in text and 'tanh(v/v_th)' in text
