"""Feedforward (pure) under hostile inputs: never an exception, never NaN/Inf or beyond the clamp, the documented
fallback applied, every rejection counted under its cause.

Complements test/feedforward/test_feedforward_logic.py (the rule itself, arrays == floats) with generated input streams:
any float (NaN, +-Inf, 1e308, subnormals), any names (unknown, duplicated, empty), arrays of the wrong length,
stamps anywhere (0 = unstamped, far future, backwards), temperatures anywhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_friction.feedforward.rule import (
    SOURCE_FALLBACK,
    SOURCE_MEASURED,
    SOURCE_ZERO,
    Feedforward,
    FeedforwardSettings,
)
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.arrays import chamber_arrays
from gimbal_friction.streams.inputs import J_DUPLICATE, J_MISMATCH, J_NONE, J_UNKNOWN, T_NON_FINITE, T_RANGE

AXES = {'elevation': AxisParams(), 'azimuth': AxisParams(scale_negative=0.7, direction_asymmetry_cold=0.1)}
CLAMP = 0.003
COARSE = 5.0  # table step [degC]: the properties do not depend on it, and a coarse table builds in milliseconds
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
SPEED = st.one_of(st.floats(-0.2, 0.2), ANY_FLOAT, st.sampled_from([0.0, -0.0, 5e-324, 1e154, -1e308]))
TEMPERATURE = st.one_of(st.floats(-70.0, 130.0), ANY_FLOAT, st.sampled_from([-273.0, 999.0, -60.0, 120.0]))
TIME = st.one_of(st.floats(-1e6, 1e6), st.sampled_from([0.0, 1e12, -1e12, math.nan, math.inf]))
NAME = st.sampled_from(['elevation', 'azimuth', 'bogus', '', 'elevation ', 'ELEVATION'])


@st.composite
def joint_message(draw: st.DrawFn) -> tuple[list[str], list[float]]:
    names = draw(st.lists(NAME, max_size=5))
    n = len(names) if draw(st.booleans()) or not names else draw(st.integers(0, 6))
    return names, draw(st.lists(SPEED, min_size=n, max_size=n))


EVENT = st.one_of(st.tuples(st.just('t'), TEMPERATURE, TIME), st.tuples(st.just('j'), joint_message(), TIME))


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(events=st.lists(EVENT, max_size=40), policy=st.sampled_from(['hold_last', 'fallback_temperature', 'zero']))
def test_message_never_raises_and_stays_finite_within_the_clamp(events, policy):
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=CLAMP, stale_policy=policy, temperature_timeout_s=2.0,
                                                 table_step_c=COARSE))
    expected_rejections: dict[str, int] = {}
    for kind, payload, time_s in events:
        if kind == 't':
            reason = ff.update_temperature(payload, time_s)
            if not math.isfinite(payload):
                assert reason == T_NON_FINITE
            elif not -60.0 <= payload <= 120.0:
                assert reason == T_RANGE
            else:
                assert reason is None and ff.last_temperature_c == payload
            continue
        names, velocities = payload
        out = ff.message(names, velocities, time_s)
        if len(velocities) != len(names):
            assert out is None
            expected_rejections[J_MISMATCH] = expected_rejections.get(J_MISMATCH, 0) + 1
            continue
        first = {}
        for i, name in enumerate(names):
            first.setdefault(name, i)
        usable = [j for j in ff.order if j in first and math.isfinite(velocities[first[j]])]
        if not usable:
            assert out is None
            continue
        assert out is not None
        assert out.names == usable                      # configured order, first entry of each joint
        assert len(out.commands_nm) == len(ff.order)
        assert all(math.isfinite(x) and abs(x) <= CLAMP for x in out.torques_nm + out.commands_nm)
        for joint, torque in zip(out.names, out.torques_nm, strict=True):
            v = velocities[first[joint]]
            if out.source == SOURCE_ZERO:
                assert torque == 0.0
            elif v != 0.0 and torque != 0.0:
                assert math.copysign(1.0, torque) == math.copysign(1.0, v)   # sign of the motion, always
            # duplicates: the value used is the first entry's (same result as a message without the repeats)
            assert torque == ff.torque_at(joint, v, out.temperature_c)
        if out.source == SOURCE_MEASURED:
            assert -60.0 <= out.temperature_c <= 120.0
    c = ff.counters
    assert c.joint_state_rejected.get(J_MISMATCH, 0) == expected_rejections.get(J_MISMATCH, 0)
    assert set(c.joint_state_rejected) <= {J_MISMATCH, J_UNKNOWN, J_DUPLICATE, J_NONE, 'non-finite velocity'}
    assert set(c.temperature_rejected) <= {T_NON_FINITE, T_RANGE}


@pytest.mark.slow
@settings(max_examples=120, deadline=None)
@given(v=SPEED, t_c=TEMPERATURE, time_s=TIME, temperature_time=TIME)
def test_controller_call_is_total(v, t_c, time_s, temperature_time):
    """``torque_nm`` (the in-process controller call) for any float: finite, clamped, 0 for a non-finite
    velocity, and the fallback temperature when the measured one is unusable or stale."""
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=CLAMP, stale_policy='fallback_temperature',
                                                 table_step_c=COARSE))
    ff.update_temperature(t_c, temperature_time)
    torque = ff.torque_nm('elevation', v, time_s)
    assert math.isfinite(torque) and abs(torque) <= CLAMP
    if not math.isfinite(v):
        assert torque == 0.0
    t_used, source = ff.temperature(time_s)
    if source == SOURCE_FALLBACK:
        assert t_used == 20.0
    else:
        assert source == SOURCE_MEASURED and t_used == t_c and abs(time_s - temperature_time) <= 5.0


def test_absurd_speed_saturates_instead_of_overflowing():
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=CLAMP))
    ff.update_temperature(-40.0, 0.0)
    for v in (1e154, 1e308, -1e308, 1e30):
        assert abs(ff.torque_nm('elevation', v, 0.0)) == CLAMP
    assert ff.counters.saturated['elevation'] == 4


def test_duplicate_joint_uses_the_first_entry_and_counts_the_rest():
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=CLAMP))
    ff.update_temperature(0.0, 0.0)
    out = ff.message(['elevation', 'elevation', 'bogus'], [0.03, -0.03, 1.0], 0.0)
    assert out is not None and out.names == ['elevation'] and out.torques_nm[0] > 0.0
    assert ff.counters.joint_state_rejected == {J_UNKNOWN: 1, J_DUPLICATE: 1}


@settings(max_examples=25, deadline=None)
@given(temps=st.lists(st.tuples(TEMPERATURE, st.integers(0, 10**12)), max_size=10),
       js=st.lists(st.tuples(st.lists(SPEED, min_size=2, max_size=2), st.integers(0, 10**12),
                             st.sampled_from([0, 1, 2])), min_size=1, max_size=20))
@pytest.mark.slow
def test_bag_torques_never_raise_and_stay_within_the_clamp(temps, js):
    """The replay path (arrays) under the same hostile values: every output finite and clamped."""
    t_msgs = [(k + 1, stamp, t) for k, (t, stamp) in enumerate(temps)]
    j_msgs = []
    for k, (v, stamp, which) in enumerate(js):
        names = [['elevation'], ['azimuth', 'elevation'], ['bogus', 'azimuth']][which]
        j_msgs.append((len(temps) + k + 1, stamp, names, [0.0] * len(names), v[:len(names)], []))
    arrays, _, _ = chamber_arrays(t_msgs, j_msgs)
    bag = Feedforward(AXES, FeedforwardSettings(max_torque_nm=CLAMP, table_step_c=COARSE)).bag_torques(arrays)
    assert np.all(np.isfinite(bag.commands_nm)) and np.all(np.abs(bag.commands_nm) <= CLAMP)
