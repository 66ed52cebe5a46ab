"""The temperature-dependent direction term (physics/direction.py): one rule on floats and arrays, defaults neutral."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.physics.direction import ARRAY, SCALAR, asymmetry_weight, direction_asymmetry, direction_factor
from gimbal_friction.physics.params import AxisParams

PAPER = AxisParams(direction_asymmetry_cold=0.131, direction_asymmetry_warm=-0.121)


def test_defaults_are_the_constant_factors():
    p = AxisParams()
    for t in (-60.0, -40.0, 20.0, 60.0, 100.0):
        assert direction_factor(p, t, 1.0, SCALAR) == 1.0
        assert direction_factor(p, t, -1.0, SCALAR) == 1.0
    q = AxisParams(scale_positive=1.2, scale_negative=0.7)
    assert direction_factor(q, -40.0, 0.3, SCALAR) == 1.2
    assert direction_factor(q, -40.0, -0.3, SCALAR) == 0.7
    assert direction_factor(q, 5.0, 0.0, SCALAR) == 1.2   # zero velocity counts as positive, as the feedforward


def test_linear_between_anchors_and_held_outside():
    t = np.array([-60.0, -40.0, -15.0, 10.0, 60.0, 90.0])
    a = direction_asymmetry(PAPER, t, ARRAY)
    np.testing.assert_allclose(a, [0.131, 0.131, 0.131 - 0.252 * 0.25, 0.131 - 0.252 * 0.5, -0.121, -0.121])
    np.testing.assert_allclose(asymmetry_weight(PAPER, t, ARRAY), [0.0, 0.0, 0.25, 0.5, 1.0, 1.0])
    # the factor raises one direction and lowers the other by the same fraction: the mean stays the model's
    kp = direction_factor(PAPER, t, np.ones_like(t), ARRAY)
    kn = direction_factor(PAPER, t, -np.ones_like(t), ARRAY)
    np.testing.assert_allclose(0.5 * (kp + kn), 1.0)
    np.testing.assert_allclose(kp - kn, 2.0 * a)


def test_reproduces_the_paper_ratios():
    # (CW - |CCW|)/(CW + |CCW|) at -40 and +60 degC: 3.19/2.45 and 1.05/1.34
    kp, kn = direction_factor(PAPER, -40.0, 1.0, SCALAR), direction_factor(PAPER, -40.0, -1.0, SCALAR)
    assert kp / kn == pytest.approx(3.19 / 2.45, rel=2e-3)
    kp, kn = direction_factor(PAPER, 60.0, 1.0, SCALAR), direction_factor(PAPER, 60.0, -1.0, SCALAR)
    assert kp / kn == pytest.approx(1.05 / 1.34, rel=2e-3)


def test_scalar_and_array_agree():
    rng = np.random.default_rng(3)
    t = rng.uniform(-70.0, 90.0, 200)
    v = rng.normal(0.0, 1.0, 200)
    p = PAPER.replace(scale_positive=1.05, scale_negative=0.93, direction_asymmetry_cold_c=-30.0,
                      direction_asymmetry_warm_c=40.0)
    arr = direction_factor(p, t, v, ARRAY)
    one = [direction_factor(p, float(ti), float(vi), SCALAR) for ti, vi in zip(t, v, strict=True)]
    np.testing.assert_allclose(arr, one, rtol=1e-15)
    assert isinstance(one[0], float)


def test_nan_temperature_gives_nan():
    assert math.isnan(direction_factor(PAPER, math.nan, 1.0, SCALAR))


def test_parameters_are_validated():
    with pytest.raises(ConfigError, match=r'direction_asymmetry_warm_c.*must exceed direction_asymmetry_cold_c'):
        AxisParams().replace(direction_asymmetry_warm_c=-50.0)
    with pytest.raises(ConfigError, match='direction_asymmetry_cold'):
        AxisParams().replace(direction_asymmetry_cold=0.95)
