"""The in-process controller API: built from the nodes' parameter files, the node's very object and rules."""

from __future__ import annotations

import math

import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.config.loader import render_parameter_file
from gimbal_friction.controller import load_feedforward
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams

V = 2 * math.pi / 180


def test_defaults_follow_the_model_and_the_node_rules():
    ff = load_feedforward()
    assert isinstance(ff, Feedforward) and ff.order == ('elevation',)
    assert ff.update_temperature(-40.0, 10.0) is None
    v_th = FeedforwardSettings().velocity_threshold_rad_s
    assert ff.torque_nm('elevation', V, 10.0) == pytest.approx(float(friction_torque(AxisParams(), -40.0).m_total_nmm)
                                                              * 1e-3 * math.tanh(V / v_th), rel=2e-5)
    # the node's stale policy (fallback 20 degC after the 5 s timeout), on the caller's clock
    stale = ff.torque_nm('elevation', V, 16.0)
    assert stale == pytest.approx(float(friction_torque(AxisParams(), 20.0).m_total_nmm) * 1e-3, rel=2e-5)
    assert ff.update_temperature(math.nan, 17.0) == 'non-finite temperature'


def test_layered_files_refit_and_node_section(tmp_path):
    refit = tmp_path / 'refit.yaml'
    refit.write_text(render_parameter_file(axes=['elevation', 'azimuth'],
                                           axes_overrides={'elevation': {'palmgren_factor': 3.0}}))
    node = tmp_path / 'node.yaml'
    node.write_text('friction_feedforward:\n  ros__parameters:\n    max_torque_nm: 0.001\n')
    ff = load_feedforward(refit, node)
    assert ff.order == ('elevation', 'azimuth') and ff.settings.max_torque_nm == 0.001
    assert ff.axes['elevation'].palmgren_factor == 3.0 and ff.axes['azimuth'].palmgren_factor != 3.0
    ff.update_temperature(-40.0, 0.0)
    assert ff.torque_nm('elevation', 1.0, 0.0) == 0.001                       # clamped
    only = load_feedforward(refit, axes=['azimuth'])
    assert only.order == ('azimuth',)
    with pytest.raises(ConfigError, match='not configured'):
        load_feedforward(refit, axes=['roll'])
    with pytest.raises(ConfigError):
        load_feedforward(tmp_path / 'missing.yaml')


@pytest.mark.slow
def test_a_correction_file_is_added_and_a_mismatched_or_corrupt_one_refused(tmp_path):
    from gimbal_friction.feedforward.correction import (
        Correction,
        CorrectionError,
        CorrectionSettings,
        load,
        model_identity,
        save,
    )

    refit = tmp_path / 'refit.yaml'
    refit.write_text(render_parameter_file(axes=['elevation', 'azimuth']))
    plain = load_feedforward(refit)
    c = Correction(CorrectionSettings(prior_samples=1.0), plain.model_identity())
    c.add_residuals('azimuth', [-40.0] * 99, [0.03] * 99, [0.0] * 99, [2e-4] * 99, [3e-3] * 99)
    c.add_residuals('azimuth', [-40.0] * 99, [-0.03] * 99, [0.0] * 99, [-2e-4] * 99, [3e-3] * 99)
    c.settle(guarded=False)   # (every candidate applied: what is tested is how the file is added)
    path = tmp_path / 'unit.correction.yaml'
    save(c, path)
    ff = load_feedforward(refit, correction=path)
    for f in (plain, ff):
        f.update_temperature(-40.0, 0.0)
    assert ff.torque_nm('azimuth', 0.03, 0.0) - plain.torque_nm('azimuth', 0.03, 0.0) == pytest.approx(
        math.tanh(0.03 / FeedforwardSettings().velocity_threshold_rad_s) * 2e-4 * 198 / 199, rel=1e-6)   # n0 = 1
    assert ff.torque_nm('elevation', 0.03, 0.0) == plain.torque_nm('elevation', 0.03, 0.0)
    only = load_feedforward(refit, axes=['azimuth'], correction=path)   # a subset of the configured joints
    only.update_temperature(-40.0, 0.0)
    assert only.torque_nm('azimuth', 0.03, 0.0) == ff.torque_nm('azimuth', 0.03, 0.0)
    other = tmp_path / 'other.yaml'
    other.write_text(render_parameter_file(axes=['elevation', 'azimuth'],
                                           axes_overrides={'elevation': {'palmgren_factor': 3.0}}))
    for params, bad, match in ((other, path, 'learned against model parameters'),
                               (refit, tmp_path / 'missing.yaml', 'missing.yaml')):
        with pytest.raises(CorrectionError, match=match) as e:
            load_feedforward(params, correction=bad)
        assert '\n' not in str(e.value)
    corrupt = tmp_path / 'corrupt.yaml'
    corrupt.write_text('format: [')
    with pytest.raises(CorrectionError):
        load_feedforward(refit, correction=corrupt)
    assert load(path).identity == model_identity(load_feedforward(refit).axes)
