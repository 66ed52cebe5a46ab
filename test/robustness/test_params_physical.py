"""Physically impossible model values are refused by the whole-model check (FrictionTable, hence Feedforward)."""

from __future__ import annotations

import math

import pytest

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError, ModelDomainError
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import FrictionTable


@pytest.mark.parametrize('changes', [
    {'walther_a': 1.0},                      # nu + c1 -> 1: nu = 1 - 1.08 < 0 everywhere
    {'walther_a': 3.0},
    {'walther_b': -1000.0},
    {'viscosity_offset_cst': 50.0},          # negative above ~30 degC
    {'viscosity_model': 'walther'},          # Eq. 20 with the Eq. 21 constants
])
def test_negative_viscosity_is_refused_not_turned_into_a_positive_torque(changes):
    params = AxisParams(**changes)
    with pytest.raises(ModelDomainError, match=r'viscosity .* must be > 0'):
        FrictionTable(params, -60.0, 120.0, 0.1)
    with pytest.raises(ModelDomainError):
        Feedforward({'elevation': params}, FeedforwardSettings())


def test_viscosity_check_uses_the_node_range():
    # c1 = 50 cSt: positive when cold, negative above about 30 degC
    params = AxisParams(viscosity_offset_cst=50.0)
    FrictionTable(params, -60.0, 20.0, 0.1)
    with pytest.raises(ModelDomainError, match=r'30\.6 degC'):
        FrictionTable(params, -60.0, 40.0, 0.1)


@pytest.mark.parametrize(('changes', 'name'), [
    ({'walther_a': 1e3}, 'viscosity'),        # overflows: nu = inf
    ({'walther_b': -1e-9}, 'viscosity'),
])
def test_overflowing_viscosity_is_refused(changes, name):
    with pytest.raises(ModelDomainError, match=name):
        FrictionTable(AxisParams(**changes), -60.0, 120.0, 0.1)


@pytest.mark.parametrize('values', [
    {'max_torque_nm': 1e300}, {'max_torque_nm': math.inf}, {'max_torque_nm': -1.0}, {'max_torque_nm': 0.0},
    {'temperature_min_c': -273.0}, {'temperature_max_c': 999.0}, {'table_step_c': 0.0},
])
def test_absurd_feedforward_settings_are_refused(values):
    from gimbal_friction.common.settings import settings_from
    with pytest.raises(ConfigError) as info:
        settings_from(FeedforwardSettings, values)
    assert info.value.parameter in values


def test_default_model_builds_over_the_widest_allowed_range_or_says_why():
    """The credible range may be widened to [-200, 400] degC; the model either builds or refuses with a reason
    (never a NaN table): below about -170 degC the Walther fit overflows."""
    with pytest.raises(GimbalFrictionError, match='non-finite viscosity'):
        FrictionTable(AxisParams(), -199.0, 120.0, 0.1)
    FrictionTable(AxisParams(), -60.0, 400.0, 0.1)
