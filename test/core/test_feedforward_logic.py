"""FeedforwardLogic: the node's fast path equals the full path; fallbacks and counters."""

from __future__ import annotations

import math

import pytest

from gimbal_friction.core.feedforward import FeedforwardLogic, FeedforwardSettings
from gimbal_friction.core.params import AxisParams

AXES = {'elevation': AxisParams(), 'azimuth': AxisParams(interference_mm=0.004, scale_negative=0.8)}


@pytest.mark.parametrize('temperature', [None, -40.0, 20.0, 60.0])
def test_fast_path_equals_compute(temperature):
    fast = FeedforwardLogic(AXES, FeedforwardSettings(max_torque_nm=0.003))
    full = FeedforwardLogic(AXES, FeedforwardSettings(max_torque_nm=0.003))
    for logic in (fast, full):
        if temperature is not None:
            logic.update_temperature(temperature, 0.0)
    for k, v in enumerate([-0.05, -0.0349, -0.001, 0.0, 0.002, 0.0349, 0.3]):
        vel = [v, -v / 2]
        a = fast.torques_in_order(['elevation', 'azimuth'], vel, 1.0 + k)
        out = full.compute(['elevation', 'azimuth'], vel, 1.0 + k)
        assert a == [j.torque_nm for j in out.joints] == full.command_vector(out)
    assert fast.counters.saturated == full.counters.saturated
    assert fast.counters.published == full.counters.published


def test_fast_path_declines_unusual_messages():
    logic = FeedforwardLogic(AXES, FeedforwardSettings())
    assert logic.torques_in_order(['azimuth', 'elevation'], [0.1, 0.1], 0.0) is None  # other order
    assert logic.torques_in_order(['elevation'], [0.1], 0.0) is None                   # a joint missing
    assert logic.torques_in_order(['elevation', 'azimuth'], [0.1], 0.0) is None       # length mismatch
    assert logic.torques_in_order(['elevation', 'azimuth'], [math.nan, 0.1], 0.0) is None
    assert logic.counters.published == 0


def test_stale_policies():
    for policy, expected_source in (('hold_last', 'hold_last'), ('fallback_temperature', 'fallback_temperature'),
                                    ('zero', 'zero')):
        logic = FeedforwardLogic(AXES, FeedforwardSettings(stale_policy=policy, temperature_timeout_s=1.0))
        logic.update_temperature(-40.0, 0.0)
        assert logic.effective_temperature(0.5) == (-40.0, 'measured')
        t, source = logic.effective_temperature(2.0)
        assert source == expected_source
        assert t == {'hold_last': -40.0, 'fallback_temperature': 20.0, 'zero': None}[policy]
    logic = FeedforwardLogic(AXES, FeedforwardSettings())
    assert logic.update_temperature(math.nan, 0.0) == 'non-finite temperature'
    assert logic.update_temperature(200.0, 0.0) == 'temperature out of range'
    assert logic.last_temperature_c is None
