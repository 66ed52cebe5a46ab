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


@pytest.fixture(scope='module')
def table():
    return build_table('elevation', AxisParams(), FeedforwardSettings(), ExportOptions(relative_error=BOUND))


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
                    ExportOptions(temperature_min_c=-100.0, temperature_max_c=0.0, random_points=2000))
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
def _learned_correction(bins: int = 16):
    from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity
    rng = np.random.default_rng(5)
    n = 30_000
    t = rng.uniform(-55.0, 70.0, n)
    v = rng.choice([-1.0, 1.0], n) * rng.uniform(0.01, 0.1, n)
    p = rng.uniform(0.0, 6.3, n)
    along = 4e-4 * (-t / 50.0 + 0.5 * (v > 0) + 0.3 * np.sin(2 * p) + 0.5 * np.abs(v / 0.0349066) ** (2 / 3)) \
        + rng.normal(0.0, 1e-4, n)   # with a speed term
    c, _ = Correction.from_residuals(CorrectionSettings(prior_samples=20.0, position_bins=bins, harmonics=3,
                                                        max_relative=0.2),
                                     model_identity({'elevation': AxisParams()}),
                                     {'elevation': (t, v, p, np.where(v > 0, along, -along), np.full(n, 2e-3))})
    one = Correction(c.settings, c.identity)   # a cell with one sample: its error is unknown
    one.add_residuals('elevation', [100.0] * 1, [0.05], [0.0], [1e-4], [2e-3])
    for name in Correction.STATE[:7]:   # the sums
        getattr(c, name)['elevation'] += getattr(one, name)['elevation']
    c.settle()
    return c


CORRECTION_DRIVER = r"""
#include <stdio.h>
#include "gimbal_friction_elevation.h"
int main(void)
{
    double t, v, m;
    while (scanf("%lf %lf %lf", &t, &v, &m) == 3) {
        printf("%.17g %.17g %.17g %.17g\n", gf_elevation_correction_nm(t, v, m),
               gf_elevation_correction_error_nm(t, v), gf_elevation_feedforward_nm(t, v),
               gf_elevation_friction_nm(t, v));
    }
    return 0;
}
"""


def test_a_correction_is_carried_in_every_format_and_the_c_feedforward_adds_it(table, tmp_path):
    """export with a learned correction: the C header (compiled standalone, -pedantic -Werror) looks it up as the
    feedforward does (the correction's own lookup at a NaN position: the cells' means) and adds it; its error bound
    is the cells' (shrunk) standard errors; the CSV columns and the ROS arrays hold the same numbers."""
    from gimbal_friction.export.formats import CSV_CORRECTION_FIELDS
    from gimbal_friction.export.table import correction_nm, table_correction

    c = _learned_correction()
    tc = table_correction(c, 'elevation', 'unit.correction.yaml (SHA-256 ' + 'a' * 64 + ')')
    ct = table._replace(correction=tc)
    assert render_c_header(table, PROV) == render_c_header(table._replace(correction=None), PROV)   # unchanged
    (tmp_path / 'gimbal_friction_elevation.h').write_text(render_c_header(ct, PROV))
    src = tmp_path / 'driver.c'
    src.write_text(CORRECTION_DRIVER)
    exe = tmp_path / 'driver'
    subprocess.run([_gcc(), *CFLAGS, '-O2', str(src), '-o', str(exe), '-lm'], check=True, capture_output=True,
                   text=True, cwd=tmp_path)
    rng = np.random.default_rng(9)
    n = 3000
    t = np.concatenate([rng.uniform(-80.0, 140.0, n - 4), [-62.5, 122.5, -60.0, 100.0]])
    v = np.concatenate([rng.uniform(-0.2, 0.2, n - 4), [0.03, -0.03, -0.03, 0.05]])
    m = rng.uniform(0.0, 4e-3, n)
    text = ''.join(f'{float(a)!r} {float(b)!r} {float(x)!r}\n' for a, b, x in zip(t, v, m, strict=True))
    out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True, timeout=60)
    res = np.array(out.stdout.split(), dtype=float).reshape(-1, 4)
    want = c.along_nm_array('elevation', t, v, np.full(n, np.nan), m)
    np.testing.assert_allclose(res[:, 0], want, rtol=1e-14, atol=1e-19)
    assert np.count_nonzero(want) > n // 2 and np.count_nonzero(np.abs(want) == 0.2 * m + c.settings.floor_nm) > 10
    value, error = correction_nm(tc, t, v, m)
    np.testing.assert_allclose(value, want, rtol=1e-14, atol=1e-19)
    np.testing.assert_allclose(res[:, 1], np.where(np.isnan(error), -1.0, error), rtol=1e-12, atol=1e-19)
    assert res[-1, 1] == -1.0   # next to the one-sample cell: unknown
    # the error bound of a cell: its standard error of the mean, shrunk like its value
    cell = next(r for r in c.cells('elevation') if r['direction'] == 'cw' and r['centre_c'] == -40.0)
    k = int((-40.0 - tc.centres_c[0]) * tc.inv_bin_per_c + 0.5)
    assert tc.error_nm[0, k] == pytest.approx(cell['std_error_nm'] * cell['samples'] / (cell['samples'] + 20.0))
    assert tc.samples[0, k] == cell['samples']
    # the C feedforward: clamp(tanh(v/v_th) (k_dir M + c), +-tau_max) with M from the table
    k_dir = direction_factor(AxisParams(), t, v, ARRAY)
    model = k_dir * res[:, 3]
    tau = np.clip(np.tanh(v / V_TH) * (model + c.along_nm_array('elevation', t, v, np.full(n, np.nan), model)),
                  -0.02, 0.02)
    np.testing.assert_allclose(res[:, 2], tau, rtol=1e-12, atol=1e-18)
    # CSV columns and ROS arrays
    csv_text = render_csv(ct, PROV)
    assert 'Learned correction: unit.correction.yaml' in csv_text and \
        'position map (16 bins, a relative ripple) is not exported' in csv_text
    assert np.abs(c.speed_nm['elevation']).max() > 1e-4   # the speed term is carried
    rows = list(csv.DictReader(io.StringIO('\n'.join(line for line in csv_text.splitlines()
                                                     if not line.startswith('#')))))
    assert list(rows[0]) == [*CSV_FIELDS, *CSV_CORRECTION_FIELDS]
    for r in rows[::7]:
        tt, mm, speed = float(r['temperature_c']), float(r['m_total_nm']), float(r['speed_rad_s'])
        for sign, name in ((1.0, 'cw'), (-1.0, 'ccw')):   # at the row's speed (0: held at the gate's speed)
            kd = float(direction_factor(AxisParams(), tt, sign, SCALAR))
            want = c.along_nm('elevation', tt, sign * max(speed, c.settings.min_speed_rad_s), math.nan, kd * mm)
            assert float(r[f'correction_{name}_nm']) == pytest.approx(want, rel=1e-14, abs=1e-19)
    e = yaml.safe_load(render_ros_yaml(ct, PROV))[ROS_NODE]['ros__parameters']['elevation']
    assert e['correction_cw_nm'] == tc.values_nm[0].tolist() and e['correction_ccw_samples'] == tc.samples[1].tolist()
    assert e['correction_max_relative'] == 0.2 and len(e['correction_temperatures_c']) == 37
    assert e['correction_cw_speed_nm'] == tc.speed_nm[0].tolist() and e['correction_min_speed_rad_s'] == 0.005
    assert -1.0 in e['correction_cw_error_nm']
