"""Feedforward (pure): one rule on floats and on arrays, stale policies by stamps, bad inputs, counters."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_friction.common.errors import ConfigError, ModelDomainError
from gimbal_friction.feedforward.rule import (
    SOURCE_FALLBACK,
    SOURCE_HOLD_LAST,
    SOURCE_MEASURED,
    SOURCE_ZERO,
    Feedforward,
    FeedforwardSettings,
)
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.arrays import chamber_arrays, joint_state_arrays

AXES = {'elevation': AxisParams(), 'azimuth': AxisParams(interference_mm=0.004, scale_negative=0.8)}
S = 1_000_000_000
V_TH = FeedforwardSettings().velocity_threshold_rad_s
ODD = [math.nan, math.inf, -math.inf, 1e308, -1e-300]


def test_torque_follows_the_model_sign_and_direction_factor():
    ff = Feedforward(AXES, FeedforwardSettings())
    ff.update_temperature(-40.0, 100.0)
    v = 1 / 3 * 2 * math.pi / 60
    for joint, k_neg in (('elevation', 1.0), ('azimuth', 0.8)):
        m = float(friction_torque(AXES[joint], -40.0, 1 / 3).m_total_nmm) * 1e-3
        assert ff.torque_nm(joint, v, 100.0) == pytest.approx(math.tanh(v / V_TH) * m, rel=2e-5)
        assert ff.torque_nm(joint, -v, 100.0) == pytest.approx(-k_neg * math.tanh(v / V_TH) * m, rel=2e-5)
    assert ff.torque_nm('elevation', 0.0, 100.0) == 0.0
    assert ff.torque_nm('elevation', math.nan, 100.0) == 0.0


def test_clamp_and_saturation_count():
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=0.001))
    ff.update_temperature(-40.0, 0.0)
    assert ff.torque_nm('elevation', 1.0, 0.0) == 0.001
    assert ff.torque_nm('elevation', -1.0, 0.0) == -0.001
    assert ff.counters.saturated == {'elevation': 2}


@pytest.mark.slow
def test_stale_policies_judge_freshness_on_stamps():
    for policy, source, t_expected in (('hold_last', SOURCE_HOLD_LAST, -40.0),
                                       ('fallback_temperature', SOURCE_FALLBACK, 20.0),
                                       ('zero', SOURCE_ZERO, math.nan)):
        ff = Feedforward(AXES, FeedforwardSettings(stale_policy=policy, temperature_timeout_s=1.0))
        assert ff.update_temperature(-40.0, 10.0) is None
        assert ff.temperature(10.5) == (-40.0, SOURCE_MEASURED)
        assert ff.temperature(9.2) == (-40.0, SOURCE_MEASURED)          # either way within the timeout
        t, src = ff.temperature(12.0)
        assert src == source and (t == t_expected or (math.isnan(t) and math.isnan(t_expected)))
    ff = Feedforward(AXES, FeedforwardSettings(stale_policy='hold_last'))
    assert ff.temperature(0.0) == (20.0, SOURCE_FALLBACK)                 # nothing to hold yet
    ff = Feedforward(AXES, FeedforwardSettings(stale_policy='zero'))
    assert ff.torque_nm('elevation', 0.1, 0.0) == 0.0


def test_bad_temperatures_are_refused_and_the_last_valid_one_stays():
    ff = Feedforward(AXES, FeedforwardSettings())
    ff.update_temperature(-10.0, 1.0)
    for bad in (math.nan, math.inf, -273.0, 999.0, -60.5, 120.5):
        assert ff.update_temperature(bad, 2.0) is not None
    assert ff.last_temperature_c == -10.0
    assert ff.counters.temperature_rejected == {'non-finite temperature': 2, 'temperature out of range': 4}


def test_message_rules_unknown_duplicate_mismatch_nonfinite():
    ff = Feedforward(AXES, FeedforwardSettings())
    ff.update_temperature(0.0, 1.0)
    out = ff.message(['bogus', 'azimuth', 'elevation', 'azimuth'], [9.0, 0.1, -0.1, 0.5], 1.0)
    assert out.names == ['elevation', 'azimuth']                          # configured order, first entry wins
    assert out.torques_nm[1] == ff.torque_nm('azimuth', 0.1, 1.0)
    assert out.commands_nm == out.torques_nm
    out = ff.message(['azimuth'], [math.nan], 1.0)
    assert out is None
    assert ff.message(['elevation'], [], 1.0) is None
    out = ff.message(['elevation', 'azimuth'], [0.1, math.inf], 1.0)
    assert out.names == ['elevation'] and out.commands_nm[1] == 0.0
    assert ff.counters.joint_state_rejected == {'unknown joint name': 1, 'duplicate joint name': 1,
                                                'non-finite velocity': 2, 'no configured joint': 1,
                                                'value/name length mismatch': 1}


def test_whole_model_is_checked_when_built():
    with pytest.raises(ModelDomainError):
        Feedforward({'elevation': AxisParams(walther_a=3.0, walther_b=-0.01)}, FeedforwardSettings())
    with pytest.raises(ConfigError):
        Feedforward(AXES, FeedforwardSettings(fallback_temperature_c=200.0))
    with pytest.raises(ConfigError):
        Feedforward({}, FeedforwardSettings())


def test_take_state_keeps_counters_and_a_temperature_still_in_range():
    old = Feedforward(AXES, FeedforwardSettings())
    old.update_temperature(-50.0, 3.0)
    old.update_temperature(math.nan, 3.0)
    new = Feedforward(AXES, FeedforwardSettings(temperature_min_c=-40.0))
    new.take_state(old)
    assert math.isnan(new.last_temperature_c) and new.counters is old.counters
    new = Feedforward(AXES, FeedforwardSettings(temperature_min_c=-55.0))
    new.take_state(old)
    assert new.last_temperature_c == -50.0


def assert_same_commands(expected: list[list[float] | None], bag, n_messages: int) -> list[list[float]]:
    """The per-message commands (None: nothing published) equal the bag's rows; returns the published ones."""
    got: list[list[float] | None] = [None] * n_messages
    for i, row in zip(bag.msg_index.tolist(), bag.commands_nm.tolist()):
        got[i] = row
    for e, g in zip(expected, got):
        assert (e is None) == (g is None)
        if e is not None:
            np.testing.assert_allclose(g, e, rtol=1e-12, atol=1e-18)
    return [g for g in got if g is not None]


@settings(max_examples=40, deadline=None)
@given(temps=st.lists(st.tuples(st.one_of(st.floats(-1e3, 1e3), st.sampled_from(ODD)), st.integers(-3, 3)),
                      max_size=8),
       vels=st.lists(st.tuples(st.one_of(st.floats(-50, 50), st.sampled_from(ODD)), st.floats(-50, 50),
                               st.sampled_from([0, 1, 2])), min_size=1, max_size=30),
       policy=st.sampled_from(['hold_last', 'fallback_temperature', 'zero']))
@pytest.mark.slow
def test_bag_arrays_equal_the_per_message_rule(temps, vels, policy):
    """The replay's array path gives what the node's per-message path gives, message for message; the output
    is never NaN, Inf or beyond the clamp."""
    s = FeedforwardSettings(stale_policy=policy, temperature_timeout_s=1.5, max_torque_nm=0.002)
    one = Feedforward(AXES, s)
    t_msgs, js_msgs, events = [], [], []
    clock = 10 * S
    for (t_c, dt), (v1, v2, which) in zip(temps + [(None, 0)] * (len(vels) - len(temps)), vels):
        clock += S // 2
        if t_c is not None:
            t_msgs.append((clock, clock + dt * S // 2, t_c))
            events.append(('t', clock, clock + dt * S // 2, t_c))
        clock += S // 2
        names = [['elevation'], ['azimuth', 'elevation'], ['azimuth'], ['elevation', 'elevation']][which]
        vel = [v1, v2][:len(names)]
        js_msgs.append((clock, clock, names, [0.0] * len(names), vel, []))
        events.append(('j', clock, clock, names, vel))
    expected = []
    for e in events:
        if e[0] == 't':
            one.update_temperature(e[3], e[2] / S)
        else:
            out = one.message(e[3], e[4], e[2] / S)
            expected.append(None if out is None else out.commands_nm)
    arrays, _, _ = chamber_arrays(t_msgs, js_msgs)
    bag = Feedforward(AXES, s).bag_torques(arrays)
    for g in assert_same_commands(expected, bag, len(js_msgs)):
        assert all(math.isfinite(x) and abs(x) <= 0.002 for x in g)


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.tuples(st.sampled_from(['ref', 'js', 'both']),
                                st.one_of(st.floats(-5, 5), st.sampled_from(ODD)),   # reference velocity
                                st.one_of(st.floats(-5, 5), st.sampled_from(ODD)),   # measured velocity
                                st.integers(-3, 3),                                  # reference stamp offset
                                st.sampled_from([0, 1, 2, 3])),                      # which joints
                      min_size=1, max_size=30),
       source=st.sampled_from(['measured', 'reference', 'auto']))
@pytest.mark.slow
def test_bag_reference_velocity_equals_the_per_message_rule(steps, source):
    """velocity_source on arrays (replay of a bag holding /gimbal/reference_velocity) equals the node's path:
    Feedforward.update_reference per reference message, Feedforward.message per joint state."""
    s = FeedforwardSettings(velocity_source=source, reference_timeout_s=0.6, temperature_timeout_s=1e4)
    one = Feedforward(AXES, s)
    clock = 10 * S
    one.update_temperature(-20.0, clock / S)
    t_msgs = [(clock, clock, -20.0)]
    js_msgs, ref_msgs, events = [], [], []
    for kind, v_ref, v_meas, dt, which in steps:
        names = [['elevation'], ['azimuth', 'elevation'], ['azimuth'], ['elevation', 'elevation']][which]
        clock += S // 4
        if kind in ('ref', 'both'):
            vel = [v_ref, -v_ref][:len(names)]
            stamp = clock + dt * S // 4
            ref_msgs.append((clock, stamp, names, [], vel, []))
            events.append(('r', stamp, names, vel))
        if kind in ('js', 'both'):
            names = names if which != 3 else ['elevation']   # a repeated name only in the reference
            vel = [v_meas, v_meas / 2][:len(names)]
            js_msgs.append((clock, clock, names, [0.0] * len(names), vel, []))
            events.append(('j', clock, names, vel))
    expected = []
    for e in events:
        if e[0] == 'r':
            one.update_reference(e[2], e[3], e[1] / S)
        else:
            out = one.message(e[2], e[3], e[1] / S)
            expected.append(None if out is None else out.commands_nm)
    arrays, _, _ = chamber_arrays(t_msgs, js_msgs)
    reference, _ = joint_state_arrays(ref_msgs, fields=(False, True, False))
    arrays = arrays._replace(reference_velocity=reference)
    ff = Feedforward(AXES, s)
    assert_same_commands(expected, ff.bag_torques(arrays), len(js_msgs))
    assert ff.counters.joint_state_rejected == one.counters.joint_state_rejected


def test_a_fresh_reference_drives_the_torque_and_a_stale_one_falls_back():
    ff = Feedforward({'elevation': AxisParams()}, FeedforwardSettings(reference_timeout_s=0.5))
    ff.update_temperature(20.0, 100.0)
    assert ff.update_reference(['elevation'], [-0.1], 100.0) is None
    assert ff.velocity('elevation', 0.2, 100.3) == -0.1          # auto: the fresh reference
    assert ff.velocity('elevation', 0.2, 100.7) == 0.2           # stale: the measured velocity
    assert ff.message(['elevation'], [0.2], 100.3).torques_nm[0] < 0.0
    assert ff.update_reference(['elevation', 'x'], [0.1], 100.4) == 'value/name length mismatch'
    ff.update_reference(['elevation'], [math.nan], 100.4)
    assert ff.counters.reference_rejected == {'value/name length mismatch': 1, 'non-finite velocity': 1}
    strict = Feedforward({'elevation': AxisParams()}, FeedforwardSettings(velocity_source='reference'))
    assert strict.velocity('elevation', 0.2, 100.0) == 0.0       # reference only: no reference, no torque
