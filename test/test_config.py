"""Parameter files: packaged defaults, key-by-key layering, per-axis overrides, named errors."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.config.loader import (
    all_axis_params,
    axis_names,
    axis_params,
    load_parameters,
    packaged_defaults_text,
    render_parameter_file,
)
from gimbal_friction.physics.params import AxisParams

ROOT = Path(__file__).resolve().parents[1]


def test_packaged_defaults_are_the_config_file_and_reproduce_the_paper():
    assert packaged_defaults_text() == (ROOT / 'config' / 'gimbal_friction.yaml').read_text(encoding='utf-8')
    cfg = load_parameters()
    assert axis_names(cfg) == ['elevation']
    assert axis_params(cfg, 'elevation') == AxisParams()


def test_layering_key_by_key(tmp_path):
    f1 = tmp_path / 'a.yaml'
    f1.write_text(render_parameter_file({'interference_mm': 0.004}))
    f2 = tmp_path / 'b.yaml'
    f2.write_text(render_parameter_file({'gasket_thickness_mm': 0.02}, axes=['elevation', 'azimuth'],
                                        axes_overrides={'azimuth': {'interference_mm': 0.008}}))
    cfg = load_parameters([f1, f2])
    params = all_axis_params(cfg)
    assert list(params) == ['elevation', 'azimuth']
    assert params['elevation'].interference_mm == 0.004 and params['elevation'].gasket_thickness_mm == 0.02
    assert params['azimuth'].interference_mm == 0.008 and params['azimuth'].gasket_thickness_mm == 0.02
    assert params['elevation'].ball_count == 15  # untouched defaults survive


def test_node_section_applies_after_wildcard(tmp_path):
    f = tmp_path / 'n.yaml'
    f.write_text(yaml.safe_dump({'friction_feedforward': {'ros__parameters': {'model': {'speed_rpm': 2.0}}}}))
    assert axis_params(load_parameters([f]), 'elevation').speed_rpm == pytest.approx(1 / 3)
    cfg = load_parameters([f], node_name='friction_feedforward')
    assert axis_params(cfg, 'elevation').speed_rpm == 2.0


@pytest.mark.parametrize(('text', 'needle'), [
    ('/**: {ros__parameters: {model: {ball_diameter_mm: -2.0}}}', 'model.ball_diameter_mm'),
    ('/**: {ros__parameters: {axes: [elevation], axis: {elevation: {palmgren_factor: 0.0}}}}',
     'axis.elevation.palmgren_factor'),
    ('/**: {ros__parameters: {axes: []}}', "'axes'"),
    ('/**: [1, 2', 'not valid YAML'),
    ('/**: {model: {}}', 'ros__parameters'),
])
def test_bad_files_are_refused_with_a_named_reason(tmp_path, text, needle):
    f = tmp_path / 'bad.yaml'
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        cfg = load_parameters([f])
        all_axis_params(cfg)
    assert needle in str(info.value)


def test_missing_file_and_unknown_axis(tmp_path):
    with pytest.raises(ConfigError, match='cannot read'):
        load_parameters([tmp_path / 'nope.yaml'])
    with pytest.raises(ConfigError, match="'pan' is not configured"):
        axis_params(load_parameters(), 'pan')


# ---------------------------------------------------------------------------------------------------- parameter rules
def _rule_classes() -> dict[str, type]:
    from gimbal_friction.config.parameter_rules import _settings_classes
    return _settings_classes()


def _build(owner: str, values: dict) -> object:
    """The settings of ``owner`` from ``values`` over its defaults, validated (its own validate())."""
    from gimbal_friction.common.settings import settings_from
    cls = _rule_classes()[owner]
    from_mapping = getattr(cls, 'from_mapping', None)
    return from_mapping(values) if from_mapping is not None else settings_from(cls, values)


#: values of other fields a bound can only be reached with (a rule between two parameters), per (owner, field)
_FAST = {'rate_loop_hz': 1e5, 'rate_bandwidth_hz': 25000.0, 'track_loop_hz': 25000.0}
_COMPANIONS = {
    ('SimConfig', 'rate_bandwidth_hz'): {'rate_loop_hz': 1e5},
    ('SimConfig', 'rate_integral_hz'): {'rate_loop_hz': 1e5, 'rate_bandwidth_hz': 25000.0},
    ('SimConfig', 'track_loop_hz'): {'rate_loop_hz': 1e5},
    ('SimConfig', 'track_bandwidth_hz'): _FAST,
    ('SimConfig', 'temperature_rate_hz'): {'rate_loop_hz': 1e5},
    ('SimConfig', 'scan_frequency_hz'): _FAST,
    ('CorrectionSettings', 'ripple_period_max_rad'): {'position_resolution_rad': 1e-5},
    ('JudgeSettings', 'block_s'): {'settle_s': 0.0},
    ('JudgeSettings', 'settle_s'): {'block_s': 3600.0},
    ('JudgeSettings', 'min_blocks'): {'max_blocks': 10**9},
    ('JudgeSettings', 'max_blocks'): {'min_blocks': 2},
    ('FeedforwardSettings', 'temperature_max_c'): {'temperature_min_c': -200.0},
    ('EstimatorSettings', 'temperature_max_c'): {'temperature_min_c': -200.0},
    ('SimConfig', 'rate_loop_hz'): {'rate_bandwidth_hz': 2.0, 'rate_integral_hz': 0.5, 'track_loop_hz': 10.0,
                                    'track_bandwidth_hz': 0.4, 'temperature_rate_hz': 10.0, 'scan_frequency_hz': 0.5,
                                    'base_motion_frequencies_hz': (0.5, 2.0, 4.0)},
    ('SimConfig', 'tracking_speed_rpm'): {'tracking_reversal_s': 0.01},
    ('FeedforwardSettings', 'fallback_temperature_c'): {'temperature_min_c': -200.0, 'temperature_max_c': 400.0},
    ('CorrectionSettings', 'position_resolution_rad'): {'ripple_period_max_rad': 3.0},
    ('CorrectionSettings', 'max_speed_rad_s'): {'min_speed_rad_s': 1e-4},
    ('CorrectionSettings', 'min_speed_rad_s'): {'max_speed_rad_s': 1000.0},
}


def _probes(owner: str, name: str, default: object) -> list[tuple[float, bool]]:
    """(value, allowed by the table) at and just beyond each bound of the table's rule."""
    from gimbal_friction.config.parameter_rules import SETTINGS_RULES
    rule = SETTINGS_RULES[owner][name]
    whole = isinstance(default, int)
    out = []
    for bound, is_low, is_open in ((rule.low, True, rule.low_open), (rule.high, False, rule.high_open)):
        if bound is None:
            continue
        step = 1 if whole else max(abs(bound), 1e-3) * 1e-6
        beyond = bound - step if is_low else bound + step
        out.append((int(bound) if whole else float(bound), not is_open))
        out.append((int(beyond) if whole else float(beyond), False))
    return out


def test_the_rules_table_names_only_fields_and_agrees_with_every_validate():
    """config/parameter_rules.py against the validate() of each settings class: a value the table allows at a bound
    is accepted, one at an excluded bound or just beyond a bound is refused naming the field; every allowed name is
    accepted and another refused. So the descriptors' ranges (from the table) never refuse what the validation
    accepts, nor allow what it refuses."""
    import dataclasses

    from gimbal_friction.config.parameter_rules import SETTINGS_RULES
    problems = []
    for owner, rules in SETTINGS_RULES.items():
        if owner == 'chamber_replay':
            continue   # validated by the node (test/robustness/test_bags_chamber_replay.py)
        fields = {f.name: f.default for f in dataclasses.fields(_rule_classes()[owner])}
        problems += [f'{owner}.{name}: not a field' for name in rules if name not in fields]
        for name, rule in rules.items():
            if name not in fields:
                continue
            base = _COMPANIONS.get((owner, name), {})
            cases = [(c, True) for c in rule.choices] + [('no_such_choice', False)] if rule.choices \
                else _probes(owner, name, fields[name])
            for value, allowed in cases:
                try:
                    _build(owner, {**base, name: value})
                    accepted = True
                except ConfigError as err:
                    accepted = False
                    if allowed or err.parameter != name:
                        problems.append(f'{owner}.{name} = {value!r}: {err}')
                if accepted != allowed:
                    problems.append(f'{owner}.{name} = {value!r}: table says {allowed}, validate {accepted}')
    assert problems == [], '\n'.join(problems)


def test_every_bounded_numeric_setting_has_its_range_in_the_table():
    """A numeric field whose validate() refuses a huge or a hugely negative value has a bound in the table on that
    side (so its descriptor shows the range), or a rule between parameters in words (its note)."""
    import dataclasses

    from gimbal_friction.config.parameter_rules import SETTINGS_RULES
    missing = []
    for owner, cls in _rule_classes().items():
        rules = SETTINGS_RULES.get(owner, {})
        for f in dataclasses.fields(cls):
            if isinstance(f.default, bool) or not isinstance(f.default, (int, float)):
                continue
            rule = rules.get(f.name)
            for huge, side in ((10**12, 'high'), (-10**12, 'low')):
                value = huge if isinstance(f.default, int) else float(huge)
                try:
                    _build(owner, {f.name: value})
                except ConfigError as err:
                    if err.parameter == f.name and (rule is None or (getattr(rule, side) is None
                                                                    and not rule.note)):
                        missing.append(f'{owner}.{f.name}: no {side} bound in the table ({err.rule})')
    assert missing == [], '\n'.join(missing)


def test_model_rules_are_the_model_bounds():
    """The model parameters' rules are AxisParams' own bounds and choices (one table)."""
    from gimbal_friction.config.parameter_rules import from_bound, parameter_rule
    from gimbal_friction.physics.params import parameter_specs
    for spec in parameter_specs():
        expected = from_bound(spec['bound'], spec['choices'])
        for node in ('friction_feedforward', 'friction_estimator', 'gimbal_sim'):
            assert parameter_rule(node, f'model.{spec["name"]}') == expected
            assert parameter_rule(node, f'axis.elevation.{spec["name"]}') == expected
    assert parameter_rule('residual_logger', 'model.ball_count') is None
