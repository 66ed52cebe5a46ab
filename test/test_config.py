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
