"""Feedforward with a learned correction: tau = clip(tanh(v/v_th) (k_dir M + c_odd) + c_even, +-tau_max); an empty
or absent correction is exactly the model; the per-message and array paths agree; the reference position is used."""

from __future__ import annotations

import copy
import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionError,
    CorrectionSettings,
    Learner,
    LearningSettings,
    model_identity,
)
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.arrays import chamber_arrays, joint_state_arrays

AXES = {'elevation': AxisParams(), 'azimuth': AxisParams(interference_mm=0.004, scale_negative=0.8)}
IDENT = model_identity(AXES)
S = 1_000_000_000
ODD = [math.nan, math.inf, -math.inf, 1e308, -1e-300]


#: the guard off: every candidate applied (what is tested here is how the feedforward adds a correction)
OPEN = CorrectionSettings(prior_samples=1.0, guard_min_samples=0, guard_z=0.0)


def learned(positions: bool = True, seed: int = 0, joints: tuple[str, ...] = ('elevation', 'azimuth'),
            scale_nm: float = 3e-4) -> Correction:
    """A correction learned from random residuals (a temperature trend, a direction asymmetry, a speed dependence
    and, with ``positions``, a position ripple and a torque independent of the direction) over -60..120 degC, both
    directions, speeds 0.01..0.1 rad/s. (A copy of the one learned once per set of arguments: the fit takes
    about 10 s.)"""
    return copy.deepcopy(_learned_once(positions, seed, joints, scale_nm))


@functools.cache
def _learned_once(positions: bool, seed: int, joints: tuple[str, ...], scale_nm: float) -> Correction:
    rng = np.random.default_rng(seed)
    samples = {}
    for k, joint in enumerate(joints):
        n = 20_000
        t = rng.uniform(-60.0, 120.0, n)
        v = rng.choice([-1.0, 1.0], n) * rng.uniform(0.01, 0.1, n)
        p = rng.uniform(-0.3, 0.3, n)
        along = scale_nm * (-t / 60.0 + 0.5 * (v > 0) + 3.0 * np.abs(v) + 0.1 * k
                            + positions * 0.4 * np.sin(2 * np.pi * p / np.radians(2.0)))
        absolute = np.where(v > 0, along, -along) + positions * scale_nm * 0.5 * np.sin(p)
        samples[joint] = (t, v, p, absolute, np.full(n, 2e-3))
    c, _ = Correction.from_residuals(OPEN, IDENT, samples)
    return c


def empty() -> Correction:
    return Correction(CorrectionSettings(), IDENT)


def bits(x: float) -> bytes:
    return np.float64(x).tobytes()


# ---------------------------------------------------------------------------------------------------- exactness
@pytest.mark.slow
@pytest.mark.parametrize('policy', ['hold_last', 'fallback_temperature', 'zero'])
def test_an_empty_or_absent_correction_is_bit_identical_to_the_model(policy):
    s = FeedforwardSettings(stale_policy=policy, temperature_timeout_s=1.0, max_torque_nm=0.003)
    plain, with_empty = Feedforward(AXES, s), Feedforward(AXES, s, correction=empty())
    reset = Feedforward(AXES, s, correction=learned())
    Learner(reset.correction, LearningSettings()).reset()   # back to the pure model
    speeds = [0.0, -0.0, 1e-5, -1e-3, 0.0349, -0.2, 5.0, -1e3, math.nan, math.inf]
    for ff in (plain, with_empty, reset):
        ff.update_temperature(-35.0, 0.0)
    for k, t in enumerate([-59.0, -40.0, -12.3, 0.0, 20.0, 61.7, 119.0]):
        for ff in (plain, with_empty, reset):
            ff.update_temperature(t, 10.0 * k)
        for joint in AXES:
            for v in speeds:
                for time_s, position in ((10.0 * k + 0.1, 0.3), (10.0 * k + 5.0, math.nan)):   # fresh, stale
                    want = plain.torque_nm(joint, v, time_s)
                    assert bits(with_empty.torque_nm(joint, v, time_s, position)) == bits(want)
                    assert bits(reset.torque_nm(joint, v, time_s, position)) == bits(want)
        for v in speeds:
            want_msg = plain.message(['azimuth', 'elevation'], [v, -v], 10.0 * k + 0.2)
            for ff in (with_empty, reset):
                got = ff.message(['azimuth', 'elevation'], [v, -v], 10.0 * k + 0.2, [1.0, 2.0])
                assert (got is None) == (want_msg is None) == (v != v or abs(v) == math.inf)
                if got is not None:
                    assert [bits(x) for x in got.commands_nm] == [bits(x) for x in want_msg.commands_nm]
    # arrays: a whole bag
    rng = np.random.default_rng(1)
    t_msgs = [(k * S, k * S, float(t)) for k, t in enumerate(rng.uniform(-60.0, 120.0, 50))]
    js_msgs = [(k * S // 3, k * S // 3, ['elevation', 'azimuth'], [float(p), -float(p)], [float(v), -float(v) / 3], [])
               for k, (v, p) in enumerate(zip(rng.normal(0.0, 0.1, 150), rng.uniform(-7.0, 7.0, 150), strict=True))]
    arrays, _, _ = chamber_arrays(t_msgs, js_msgs)
    want_bag = Feedforward(AXES, s).bag_torques(arrays).commands_nm
    assert np.array_equal(Feedforward(AXES, s, correction=empty()).bag_torques(arrays).commands_nm, want_bag)
    assert np.array_equal(reset.bag_torques(arrays).commands_nm, want_bag)


def test_a_learned_correction_is_added_along_the_motion_and_beside_it():
    """A cell learned in one direction: half of it is along the motion (before the smooth sign), half independent of
    the direction, so the learned direction gets all of it and the other none (away from zero speed)."""
    ff_plain = Feedforward(AXES, FeedforwardSettings())
    c = Correction(OPEN, IDENT)
    n = 1000   # +2e-4 N*m along the motion at -40 degC, cw only
    c.add_residuals('elevation', [-40.0] * n, [0.03] * n, [0.0] * n, [2e-4] * n, [3e-3] * n)
    c.settle(guarded=False)
    ff = Feedforward(AXES, FeedforwardSettings(), correction=c)
    for f in (ff, ff_plain):
        f.update_temperature(-40.0, 0.0)
    v_th = FeedforwardSettings().velocity_threshold_rad_s
    value = 2e-4 * n / (n + 0.5)   # (along and independent each shrunk like n0 = 1 sample: n + n0 / 2 in all)
    delta = ff.torque_nm('elevation', 0.03, 0.1) - ff_plain.torque_nm('elevation', 0.03, 0.1)
    assert delta == pytest.approx(math.tanh(0.03 / v_th) * value / 2 + value / 2, rel=1e-6)
    # at a speed two octaves below any sample, the part along the motion is 0 (not carried where no data showed
    # it): only the part independent of the direction is added
    delta = ff.torque_nm('elevation', 0.001, 0.1) - ff_plain.torque_nm('elevation', 0.001, 0.1)
    assert delta == pytest.approx(value / 2, rel=1e-4)
    ccw = ff.torque_nm('elevation', -0.03, 0.1) - ff_plain.torque_nm('elevation', -0.03, 0.1)
    assert abs(ccw) < 1e-6 * value   # ccw: no data (tanh(-0.03/v_th) = -1 to 1e-13)
    assert ff.torque_nm('azimuth', 0.03, 0.1) == ff_plain.torque_nm('azimuth', 0.03, 0.1)         # no data
    ff.set_correction(None)   # back to the model at run time
    assert ff.correction is None and ff.torque_nm('elevation', 0.03, 0.1) == ff_plain.torque_nm('elevation', 0.03, 0.1)


@pytest.mark.slow
def test_the_clamp_applies_to_the_corrected_torque_and_saturation_is_counted():
    c = learned(positions=False, scale_nm=5e-3)
    ff = Feedforward(AXES, FeedforwardSettings(max_torque_nm=0.0031), correction=c)
    ff.update_temperature(-55.0, 0.0)
    tau = ff.torque_nm('elevation', 0.05, 0.1)
    assert tau == 0.0031 and ff.counters.saturated == {'elevation': 1}


def test_a_learner_updating_the_correction_in_place_is_followed_at_once():
    c = Correction(OPEN, IDENT)
    ff = Feedforward(AXES, FeedforwardSettings(), correction=c)
    ff.update_temperature(20.0, 0.0)
    before = ff.torque_nm('elevation', 0.03, 0.1)
    learner = Learner(c, LearningSettings(max_rate_nm_per_min=1.0, step_period_s=1.0))
    for k in range(100):   # both directions (a cell moves once its temperature bin has both)
        learner.update('elevation', 20.0, 0.03, 0.0, 1e-4, 1e-3, now_s=k * 0.1)
        learner.update('elevation', 20.0, -0.03, 0.0, -1e-4, -1e-3, now_s=k * 0.1)
    learner.step(100.0)
    assert ff.torque_nm('elevation', 0.03, 0.1) > before
    learner.reset()
    assert ff.torque_nm('elevation', 0.03, 0.1) == before


@pytest.mark.slow
def test_a_correction_of_another_model_is_refused_with_one_line():
    other = Correction(CorrectionSettings(), model_identity({'elevation': AxisParams(walther_a=9.0),
                                                            'azimuth': AXES['azimuth']}))
    with pytest.raises(CorrectionError, match='learned against model parameters') as e:
        Feedforward(AXES, FeedforwardSettings(), correction=other)
    assert '\n' not in str(e.value)
    ff = Feedforward(AXES, FeedforwardSettings())
    with pytest.raises(CorrectionError, match='joints'):
        ff.set_correction(Correction(CorrectionSettings(), model_identity({'elevation': AxisParams()})))
    assert ff.correction is None
    # a subset of the configured joints with the identity of the whole configuration
    sub = Feedforward({'azimuth': AXES['azimuth']}, FeedforwardSettings())
    c = learned(positions=False)
    with pytest.raises(CorrectionError):
        sub.set_correction(c)
    sub.set_correction(c, expected=IDENT)
    assert sub.correction is not None


# ---------------------------------------------------------------------------------------------------- position
@pytest.mark.slow
def test_the_reference_position_is_used_when_the_velocity_is_the_references():
    c = learned(positions=True)
    s = FeedforwardSettings(velocity_source='auto', reference_timeout_s=0.5, temperature_timeout_s=1e4)
    ff = Feedforward(AXES, s, correction=c)
    ff.update_temperature(-40.0, 0.0)

    def at(position: float) -> float:
        return Feedforward(AXES, FeedforwardSettings(velocity_source='measured'), correction=c).torque_at(
            'elevation', 0.05, -40.0, position)

    assert at(0.0) != at(0.1)                                           # the position terms matter
    ff.update_reference(['elevation'], [0.05], 10.0, positions=[0.1])
    assert ff.message(['elevation'], [0.05], 10.1, [0.0]).torques_nm == [at(0.1)]        # fresh: reference's
    assert ff.message(['elevation'], [0.05], 11.0, [0.0]).torques_nm == [at(0.0)]        # stale: measured
    ff.update_reference(['elevation'], [0.05], 12.0)                                      # no reference position
    assert ff.message(['elevation'], [0.05], 12.1, [0.0]).torques_nm == [at(0.0)]
    assert ff.message(['elevation'], [0.05], 12.1).torques_nm == [at(math.nan)]           # no position at all
    assert ff.message(['elevation'], [0.05], 12.1, [0.0, 1.0]).torques_nm == [at(math.nan)]   # wrong length
    measured = Feedforward(AXES, FeedforwardSettings(velocity_source='measured', temperature_timeout_s=1e4),
                           correction=c)
    measured.update_temperature(-40.0, 0.0)
    measured.update_reference(['elevation'], [0.05], 10.0, positions=[0.1])
    assert measured.message(['elevation'], [0.05], 10.1, [0.0]).torques_nm == [at(0.0)]


class _Learned(dict):
    """``LEARNED[positions]``: ``learned(positions)``, learned when a test first asks (not when the module is
    collected: a fast-lane run, and each xdist worker, would pay for it)."""

    def __missing__(self, positions: bool) -> Correction:
        self[positions] = value = learned(positions)
        return value


LEARNED = _Learned()


@pytest.mark.slow
@settings(max_examples=40, deadline=None)
@given(steps=st.lists(st.tuples(st.sampled_from(['ref', 'js', 'both', 'temp']),
                                st.one_of(st.floats(-0.2, 0.2), st.sampled_from(ODD)),   # reference velocity
                                st.one_of(st.floats(-0.2, 0.2), st.sampled_from(ODD)),   # measured velocity
                                st.one_of(st.floats(-20, 20), st.sampled_from(ODD)),     # position
                                st.floats(-70.0, 130.0),                                 # temperature
                                st.integers(-3, 3),                                      # stamp offset
                                st.sampled_from([0, 1, 2])),                             # which joints
                      min_size=1, max_size=30),
       source=st.sampled_from(['measured', 'reference', 'auto']),
       policy=st.sampled_from(['hold_last', 'fallback_temperature', 'zero']),
       positions=st.sampled_from([False, True]))
@pytest.mark.slow
def test_with_a_correction_the_bag_arrays_equal_the_per_message_rule(steps, source, policy, positions):
    """The replay's array path with a learned correction (position terms or not) gives what the node's per-message
    path gives, message for message, with measured and reference positions."""
    s = FeedforwardSettings(velocity_source=source, stale_policy=policy, reference_timeout_s=0.6,
                            temperature_timeout_s=1.2, max_torque_nm=0.01)
    c_one, c_bag = copy.deepcopy(LEARNED[positions]), copy.deepcopy(LEARNED[positions])
    one = Feedforward(AXES, s, correction=c_one)
    clock = 10 * S
    t_msgs, js_msgs, ref_msgs, events = [], [], [], []
    for kind, v_ref, v_meas, pos, temp, dt, which in steps:
        # (a NaN velocity with a NaN position is what the arrays call absent: keep those apart)
        ref_pos = 0.0 if math.isnan(pos) and math.isnan(v_ref) else pos
        pos = 0.0 if math.isnan(pos) and math.isnan(v_meas) else pos
        names = [['elevation'], ['azimuth', 'elevation'], ['azimuth']][which]
        clock += S // 4
        if kind == 'temp':
            t_msgs.append((clock, clock + dt * S // 4, temp))
            events.append(('t', clock + dt * S // 4, temp))
        if kind in ('ref', 'both'):
            vel, ps = [v_ref, -v_ref][:len(names)], [ref_pos + 1.0, -ref_pos][:len(names)]
            stamp = clock + dt * S // 4
            ref_msgs.append((clock, stamp, names, ps, vel, []))
            events.append(('r', stamp, names, vel, ps))
        if kind in ('js', 'both'):
            vel, ps = [v_meas, v_meas / 2][:len(names)], [pos, 2.0 * pos][:len(names)]
            js_msgs.append((clock, clock, names, ps, vel, []))
            events.append(('j', clock, names, vel, ps))
    expected = []
    for e in events:
        if e[0] == 't':
            one.update_temperature(e[2], e[1] / S)
        elif e[0] == 'r':
            one.update_reference(e[2], e[3], e[1] / S, e[4])
        else:
            out = one.message(e[2], e[3], e[1] / S, e[4])
            expected.append(None if out is None else out.commands_nm)
    arrays, _, _ = chamber_arrays(t_msgs, js_msgs)
    reference, _ = joint_state_arrays(ref_msgs, fields=(True, True, False))   # with the positions
    arrays = arrays._replace(reference_velocity=reference)
    ff = Feedforward(AXES, s, correction=c_bag)
    bag = ff.bag_torques(arrays)
    got: list[list[float] | None] = [None] * len(js_msgs)
    for i, row in zip(bag.msg_index.tolist(), bag.commands_nm.tolist(), strict=True):
        got[i] = row
    for e, g in zip(expected, got, strict=True):
        assert (e is None) == (g is None)
        if e is not None:
            np.testing.assert_allclose(g, e, rtol=1e-12, atol=1e-18)
            assert all(math.isfinite(x) and abs(x) <= 0.01 for x in g)
    assert ff.counters == one.counters
    assert c_bag.lookup_saturations == c_one.lookup_saturations
