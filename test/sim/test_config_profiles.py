"""SimConfig: parameter file section, validation with ConfigError; profiles and base motion."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import RAD_S_PER_RPM
from gimbal_friction.sim.config import RealtimeSettings, SimConfig, parameter_file_text, parameter_specs
from gimbal_friction.sim.profiles import base_motion, make_profile, zero_crossings

YAML = Path(__file__).resolve().parents[2] / 'config' / 'gimbal_sim.yaml'


def test_parameter_file_holds_every_parameter_with_its_default_and_unit():
    text = YAML.read_text(encoding='utf-8')
    assert text == parameter_file_text()       # regenerate with parameter_file_text() after changing a parameter
    section = yaml.safe_load(text)['gimbal_sim']['ros__parameters']
    defaults = {**SimConfig().to_mapping(), **dataclasses.asdict(RealtimeSettings())}
    assert section == defaults
    assert SimConfig.from_mapping(yaml.safe_load(text)) == SimConfig()
    assert RealtimeSettings.from_mapping(yaml.safe_load(text)) == RealtimeSettings()
    for spec in parameter_specs(node=True):
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(spec['name'] + ':'))
        assert f'# [{spec["unit"]}]' in line, spec['name']


def test_from_mapping_accepts_the_flat_parameters_the_section_or_a_whole_file():
    flat = {'rate_bandwidth_hz': 30, 'base_motion_amplitudes_rad_s': [0.1], 'base_motion_frequencies_hz': [1],
            'base_motion_phases_rad': [0.0], 'asymmetry_enabled': False}
    a = SimConfig.from_mapping(flat)
    b = SimConfig.from_mapping({'ros__parameters': flat})
    c = SimConfig.from_mapping({'/**': {'ros__parameters': {}}, 'gimbal_sim': {'ros__parameters': flat}})
    assert a == b == c
    assert a.rate_bandwidth_hz == 30.0 and a.base_motion_frequencies_hz == (1.0,) and not a.asymmetry_enabled
    assert SimConfig().replace(seed=3).seed == 3


@pytest.mark.parametrize(('values', 'parameter', 'rule'), [
    ({'inertia_truth_ratio': 0.0}, 'inertia_truth_ratio', 'must lie in (0, 100] [-]'),
    ({'inertia_kg_m2': 1e-4}, 'inertia_kg_m2', "unknown simulator parameter (did you mean 'inertia_truth_ratio'?)"),
    ({'asymmetry_temperatures_c': [-40.0, 0.0, 60.0]}, 'asymmetry_temperatures_c',
     'must be [cold, warm] with cold < warm [degC]'),
    ({'rate_bandwidth_hz': 'fast'}, 'rate_bandwidth_hz', 'must be a number, not str'),
    ({'plant_substeps': 2.5}, 'plant_substeps', 'must be a whole number'),
    ({'asymmetry_enabled': 1}, 'asymmetry_enabled', 'must be true or false'),
    ({'ripple_amplitudes': [0.1]}, 'ripple_periods_deg',
     'ripple_amplitudes, ripple_periods_deg and ripple_phases_rad must have the same length'),
    ({'ripple_amplitudes': [0.4, 0.2]}, 'ripple_amplitudes',
     'must be >= 0 with sum x (1 + ripple_cold_gain) < 1 (friction keeps its sign)'),
    ({'rate_bandwidth_hz': 400.0}, 'rate_bandwidth_hz', 'must lie in (0, rate_loop_hz / 4] [Hz]'),
    ({'rate_integral_hz': 50.0}, 'rate_integral_hz', 'must lie in [0, rate_bandwidth_hz) [Hz]'),
    ({'gyro_noise_rad_s': math.nan}, 'gyro_noise_rad_s', 'must be a finite number'),
    ({'breakaway_ratio': 0.5}, 'breakaway_ratio', 'must lie in [1, 10] [-]'),
    ({'base_motion_profiles': ['spin']}, 'base_motion_profiles',
     'must name profiles among tracking, scan, pointing, weave'),
    ({'tracking_travel_deg': [3.0, 1.0]}, 'tracking_travel_deg', 'must be [low, high] with low < high [deg]'),
    ({'asymmetry_cw_nmm': [3.19]}, 'asymmetry_cw_nmm', 'must give one value > 0 per asymmetry temperature [N*mm]'),
    ({'seed': -1}, 'seed', 'must be an integer >= 0'),
])
def test_bad_values_are_refused_naming_the_parameter_and_the_rule(values, parameter, rule):
    with pytest.raises(ConfigError) as info:
        SimConfig.from_mapping(values)
    assert info.value.parameter == parameter
    assert info.value.rule == rule


def test_every_parameter_is_documented_with_unit_and_group():
    for spec in parameter_specs():
        assert spec['unit'] and spec['description'] and spec['group'], spec['name']
    names = {f.name for f in dataclasses.fields(SimConfig)}
    assert {'inertia_truth_ratio', 'current_limit_a', 'current_loop_time_constant_s', 'rate_loop_hz',
            'gyro_noise_rad_s',
            'gyro_bias_rad_s', 'base_motion_amplitudes_rad_s', 'base_motion_frequencies_hz',
            'thermal_time_constant_s', 'temperature_noise_c', 'lubricant_walther_a_shift', 'sigma0_nm_per_rad',
            'sigma1_nm_s_per_rad', 'stribeck_velocity_rad_s', 'breakaway_ratio'} <= names


@pytest.mark.parametrize(('values', 'parameter', 'rule'), [
    ({'profile': 'spiral'}, 'profile', 'must be one of tracking, scan, pointing, weave'),
    ({'environment_temperature_c': -80.0}, 'environment_temperature_c', 'must lie in [-60, 120] [degC]'),
    ({'publish_every_ticks': 0}, 'publish_every_ticks', 'must be an integer in [1, 10000]'),
    ({'use_feedforward': 'yes'}, 'use_feedforward', 'must be true or false'),
])
def test_bad_node_settings_are_refused_naming_the_parameter_and_the_rule(values, parameter, rule):
    with pytest.raises(ConfigError) as info:
        RealtimeSettings.from_mapping({'gimbal_sim': {'ros__parameters': {'rate_loop_hz': 500.0, **values}}})
    assert info.value.parameter == parameter
    assert info.value.rule == rule


def test_tracking_profile_is_the_papers_sweep():
    cfg = SimConfig()
    p = make_profile(cfg, 'tracking', 20.0)
    speed = cfg.tracking_speed_rpm * RAD_S_PER_RPM
    assert float(np.max(np.abs(p.target_rate_rad_s))) == pytest.approx(speed, rel=1e-12)
    assert float(p.target_angle_rad.max()) == pytest.approx(math.radians(11.0), abs=1e-9)
    assert float(p.target_angle_rad.min()) == pytest.approx(math.radians(-6.0), abs=1e-9)
    # the angle is the integral of the rate (piecewise-parabolic, exact)
    np.testing.assert_allclose(np.diff(p.target_angle_rad) / cfg.controller_period_s,
                               0.5 * (p.target_rate_rad_s[1:] + p.target_rate_rad_s[:-1]), atol=2e-4)
    span_s = math.radians(17.0) / speed
    # reversals: at the top after half the travel, then every span/speed + reversal_s/2
    assert p.reversal_times_s.tolist() == pytest.approx([0.5 * span_s + 0.1, 1.5 * span_s + 0.2], abs=2e-3)
    assert not p.base_motion and np.all(p.base_rate_rad_s == 0.0)


def test_base_motion_is_a_sum_of_sines_and_its_integral():
    cfg = SimConfig()
    t = np.linspace(0.0, 2.0, 20001)
    angle, rate = base_motion(cfg, t)
    np.testing.assert_allclose(np.gradient(angle, t), rate, atol=2e-5)
    assert angle[0] == 0.0
    p = make_profile(cfg, 'pointing', 2.5)
    assert p.base_motion and p.base_rate_rad_s.shape == (2500, cfg.plant_substeps)
    _, sub_rate = base_motion(cfg, p.time_s[5] + cfg.plant_step_s * 2)
    assert float(p.base_rate_rad_s[5, 2]) == pytest.approx(float(sub_rate))
    assert len(p.reversal_times_s) >= 2         # every sign change of the relative motion


def test_scan_and_zero_crossings():
    cfg = SimConfig()
    p = make_profile(cfg, 'scan', 3.0)
    assert p.target_rate_rad_s[0] == 0.0 and p.target_angle_rad[0] == pytest.approx(-math.radians(3.0))
    assert p.reversal_times_s.tolist() == pytest.approx([1.0, 2.0], abs=1e-9)
    assert zero_crossings(np.arange(4.0), np.array([1.0, 0.0, -1.0, -2.0])).tolist() == [1.0]
    with pytest.raises(ConfigError):
        make_profile(cfg, 'spiral')
