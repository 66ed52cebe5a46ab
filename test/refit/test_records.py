"""One JSON form of a refit result (gimbal_friction.refit.records): refit's per-axis record and fleet's are the same
record; fleet's adds its population fields and keeps its historical short names as aliases."""

import json

import numpy as np
import pytest

from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import refit_model
from gimbal_friction.refit.records import fleet_record, refit_record


@pytest.fixture(scope='module')
def result():
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.01)
    t = np.repeat([-40.0, 0.0, 40.0], 20).repeat(2)
    d = np.tile([1.0, -1.0], 60)
    tau = friction_torque(truth, t, 1 / 3).m_total_nmm * 1e-3
    return refit_model(base, t, np.full(t.shape, 1 / 3), tau, d)


def test_the_fleet_record_is_the_refit_record_plus_its_own_fields(result):
    one = refit_record(result)
    fleet = fleet_record(result, 123.0, {'-40': 3.0})
    def same(a, b):   # NaN (no calibration given) equals NaN here
        return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)

    for key, value in one.items():
        if key == 'offset':
            assert same({k: fleet['offset'][k] for k in value}, value)
        else:
            assert same(fleet[key], value)
    assert fleet['ci95'] == one['confidence_intervals_95']
    assert fleet['identifiable'] == {k: v['identifiable'] for k, v in one['identifiability'].items()}
    assert fleet['offset']['se_nmm'] == one['offset']['standard_error_nmm']
    assert fleet['viscosity_m40_cst'] == 123.0 and fleet['friction_nmm'] == {'-40': 3.0}
    assert one['fitted']['walther_a'] == pytest.approx(AxisParams().walther_a + 0.01, abs=1e-6)


def test_the_offset_travels_in_the_file_as_data_the_loader_ignores(result, tmp_path):
    """refit writes its calibration offset into a section of its parameter file: read back exactly, ignored by the
    parameter loader (the file stays layerable, the model unchanged), refused with one line in another version."""
    from gimbal_friction.common.errors import ConfigFileError
    from gimbal_friction.config.loader import check_config_files, load_parameters, render_parameter_file
    from gimbal_friction.refit.records import offset_values, read_refit_offsets, refit_section_text

    assert result.offset.estimated
    params = render_parameter_file(axes_overrides={'elevation': result.refitted})
    path, bare = tmp_path / 'refit.yaml', tmp_path / 'bare.yaml'
    path.write_text(params + refit_section_text({'elevation': offset_values(result)}))
    bare.write_text(params)
    assert read_refit_offsets(path) == {'elevation': result.offset.value_nm} and read_refit_offsets(bare) == {}
    check_config_files([path])
    assert load_parameters([path]) == load_parameters([bare])
    not_fitted = tmp_path / 'off.yaml'
    not_fitted.write_text(refit_section_text({'elevation': (0.0, float('nan'), False)}))
    assert read_refit_offsets(not_fitted) == {'elevation': 0.0}
    later = tmp_path / 'later.yaml'
    later.write_text(path.read_text().replace('format_version: 1', 'format_version: 2'))
    with pytest.raises(ConfigFileError, match='gimbal_friction_refit format_version 2 is not supported'):
        read_refit_offsets(later)
