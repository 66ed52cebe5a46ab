"""The scalar feedforward call keeps what depends on temperature only (the table's terms, both direction factors,
the stale policy's choice) between calls: it must follow every change of temperature, of joint and of the latest
valid temperature, and give what the array rule gives on the same inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.xp import ARRAY
from gimbal_friction.feedforward.rule import SOURCE_FALLBACK, SOURCE_MEASURED, Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams

AXES = {'elevation': AxisParams(direction_asymmetry_cold=0.131, direction_asymmetry_warm=-0.121),
        'azimuth': AxisParams(interference_mm=0.004, scale_negative=0.8, walther_a=8.65)}


def test_scalar_calls_follow_temperature_and_joint_changes_as_the_array_rule():
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=0.05))
    rng = np.random.default_rng(5)
    temps = rng.choice([-45.0, -40.0, 3.25, 60.0], 400)       # repeats and changes, as a sensor's rate gives
    vels = rng.normal(0.0, 0.2, 400)                           # both directions, both Palmgren branches
    joints = rng.choice(list(AXES), 400)
    got = [ff.torque_at(str(j), float(v), float(t)) for j, v, t in zip(joints, vels, temps, strict=True)]
    for joint in AXES:
        mine = joints == joint
        want = Feedforward(AXES, FeedforwardSettings(max_torque_nm=0.05)).rule(joint, vels[mine], temps[mine], ARRAY)
        np.testing.assert_allclose(np.array(got)[mine], want, rtol=1e-12, atol=0.0)


def test_the_latest_valid_temperature_is_used_however_it_is_set():
    s = FeedforwardSettings(temperature_timeout_s=1.0)
    ff = Feedforward(AXES, s)
    assert ff.temperature(0.0) == (20.0, SOURCE_FALLBACK)
    ff.update_temperature(-30.0, 0.0)
    assert ff.temperature(0.5) == (-30.0, SOURCE_MEASURED)
    cold = ff.torque_nm('elevation', 0.03, 0.5)
    ff.last_temperature_c = 50.0                                # set directly (the attribute is public)
    assert ff.temperature(0.5) == (50.0, SOURCE_MEASURED)
    warm = ff.torque_nm('elevation', 0.03, 0.5)
    assert warm == pytest.approx(ff.torque_at('elevation', 0.03, 50.0), rel=0.0) and warm < cold
    other = Feedforward(AXES, s)
    other.take_state(ff)
    assert other.temperature(0.9) == (50.0, SOURCE_MEASURED)
    assert other.temperature(2.0) == (20.0, SOURCE_FALLBACK)
    assert math.isnan(Feedforward(AXES, FeedforwardSettings(stale_policy='zero')).temperature(0.0)[0])
