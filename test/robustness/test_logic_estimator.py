"""EstimatorLogic (pure) under hostile streams: never an exception; every sample it accepts is finite, signed like
the motion, paired with a credible temperature (or none), and built from inputs that pass the input rules; bad
inputs are counted under their cause; the estimator recovers once the cause goes away (a far-future or restarting
stamp does not lock it up).

The stream is a plausible chamber run (joint states at 100 Hz at the commanded speed, currents paired with them,
temperatures) with hostile messages injected at random places, fed one message at a time (the node feeds batches;
batch invariance is tested in test/estimation/test_estimator.py).
"""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_friction.estimation.estimator import (
    INPUT_REASONS,
    OBSERVER_REASONS,
    R_OPPOSES,
    R_RESET,
    STEADY_STATE_REASONS,
    UNKNOWN_JOINT,
    EstimatorLogic,
    EstimatorSettings,
)
from gimbal_friction.physics.params import AxisParams

EL = 'elevation'
KT, I0 = 0.05, 0.01
V = 2.0 * math.pi / 180.0 / 3.0 * 3.0     # the commanded speed (1/3 rpm) [rad/s]
NS, MS = 1_000_000_000, 1_000_000
T0 = 1_000 * NS
AXES = {EL: AxisParams(torque_constant_nm_per_a=KT, no_load_current_a=I0),
        'azimuth': AxisParams(torque_constant_nm_per_a=0.08)}
ANY = st.floats(allow_nan=True, allow_infinity=True)
HOSTILE = st.one_of(
    st.tuples(st.just('js_values'), st.sampled_from([math.nan, math.inf, -math.inf, 1e154, 1e308, -1e308]),
              st.booleans()),
    st.tuples(st.just('current'), st.sampled_from([math.nan, math.inf, -math.inf, 1e154, 3.0, -1e308]),
              st.just(0)),
    st.tuples(st.just('wrong_sign'), st.floats(0.02, 1.5), st.just(0)),
    st.tuples(st.just('stamp'), st.sampled_from([10**6 * NS, 10**9 * NS, -5 * NS, -T0 + 1, 0]), st.booleans()),
    st.tuples(st.just('names'), st.sampled_from(['duplicate', 'unknown', 'mismatch', 'empty']), st.booleans()),
    st.tuples(st.just('temperature'), st.one_of(ANY, st.sampled_from([-273.0, 999.0, -60.0, 120.0])), st.just(0)),
)


def run(logic: EstimatorLogic, t_ns: int, sign: float, current_a: float) -> list:
    """One clean step: a joint state at ``t_ns`` moving with ``sign`` and its current."""
    out = logic.on_joint_state(t_ns, [EL], [0.01], [sign * V], arrival_ns=t_ns)
    out += logic.on_current(t_ns, [EL], [current_a], arrival_ns=t_ns + 1)
    return out


def check(samples: list, logic: EstimatorLogic) -> None:
    s = logic.settings
    for m in samples:
        assert m.joint in AXES
        for x in (m.friction_nm, m.position_rad, m.velocity_rad_s, m.current_a, m.acceleration_rad_s2):
            assert math.isfinite(x)
        # signed like the motion, or opposing it by at most the allowance (an unbalance)
        assert m.friction_nm * math.copysign(1.0, m.velocity_rad_s) >= -s.max_opposing_torque_nm
        assert abs(m.current_a) <= s.max_current_a
        assert math.isnan(m.temperature_c) or s.temperature_min_c <= m.temperature_c <= s.temperature_max_c


@settings(max_examples=60, deadline=None)
@given(plan=st.lists(st.tuples(st.integers(0, 60), HOSTILE), max_size=12),
       method=st.sampled_from(['steady_state', 'observer', 'both']))
@pytest.mark.slow
def test_hostile_streams_never_break_the_estimator(plan, method):
    logic = EstimatorLogic(AXES, EstimatorSettings(method=method, min_dwell_s=0.05, observer_min_speed_rad_s=0.01))
    logic.on_temperature(-20.0, T0, arrival_ns=T0)
    inject: dict[int, list] = {}
    for step, event in plan:
        inject.setdefault(step, []).append(event)
    accepted = []
    t = T0
    sign = 1.0
    for step in range(60):
        t += 10 * MS
        if step == 30:
            sign = -sign
        for kind, value, flag in inject.get(step, []):
            if kind == 'js_values':
                pos, vel = (value, sign * V) if flag else (0.0, value)
                accepted += logic.on_joint_state(t, [EL], [pos], [vel], arrival_ns=t)
            elif kind == 'current':
                accepted += logic.on_current(t, [EL], [value], arrival_ns=t)
            elif kind == 'wrong_sign':   # a current that would give friction against the motion
                accepted += logic.on_current(t, [EL], [-sign * value], arrival_ns=t)
            elif kind == 'stamp':
                stamp = t + value if value else 0
                accepted += logic.on_joint_state(stamp, [EL], [0.0], [sign * V], arrival_ns=t)
                if flag:
                    accepted += logic.on_current(stamp, [EL], [sign * 0.06], arrival_ns=t)
            elif kind == 'names':
                names = {'duplicate': [EL, EL], 'unknown': ['bogus'], 'mismatch': [EL, 'azimuth'],
                         'empty': []}[value]
                values = [sign * V] * (1 if value == 'mismatch' else len(names))
                accepted += logic.on_joint_state(t, names, [0.0] * len(values), values, arrival_ns=t)
                if flag:
                    accepted += logic.on_current(t, names, [0.06] * len(names), arrival_ns=t)
            else:
                accepted += logic.on_temperature(value, t, arrival_ns=t)
        accepted += run(logic, t, sign, sign * 0.06 + (0.002 if step % 2 else -0.002))
    check(accepted, logic)
    # the cause has gone: a clean tail is accepted again (steady state and observer alike)
    tail = []
    for _ in range(120):
        t += 10 * MS
        tail += run(logic, t, sign, sign * 0.06)
    tail += logic.on_temperature(-20.0, t + MS, arrival_ns=t + MS)   # stamped after: the samples' one is known
    check(tail, logic)
    assert tail, logic.counters.as_dict()
    for m in accepted + tail:   # Eq. 23 with the joint's K_T and I_0 (minus J alpha for observer samples)
        d = math.copysign(1.0, m.velocity_rad_s)
        j_alpha = AXES[EL].inertia_kg_m2 * m.acceleration_rad_s2 if m.method == 1 else 0.0
        assert math.isclose(m.friction_nm, KT * (m.current_a - d * I0) - j_alpha, rel_tol=1e-9, abs_tol=1e-15)
    known = set(INPUT_REASONS) | set(STEADY_STATE_REASONS) | set(OBSERVER_REASONS)
    for joint, reasons in logic.counters.rejected.items():
        assert joint in (*AXES, UNKNOWN_JOINT)
        assert set(reasons) <= known, reasons


def test_one_far_future_stamp_restarts_the_stream_instead_of_locking_it():
    logic = EstimatorLogic(AXES, EstimatorSettings(min_dwell_s=0.05, temperature_wait_s=0.0))
    t = T0
    for _ in range(30):
        t += 10 * MS
        run(logic, t, 1.0, 0.06)
    before = logic.counters.accepted[EL]
    assert before > 0
    logic.on_joint_state(t + 10**7 * NS, [EL], [0.0], [V])          # one sample stamped 116 days ahead
    after = []
    for _ in range(30):
        t += 10 * MS
        after += run(logic, t, 1.0, 0.06)
    assert after, logic.counters.as_dict()
    assert logic.counters.rejected[EL][R_RESET] == 1


def test_a_replayed_loop_restarts_each_time():
    """chamber_replay loop:=true (or sim time restarting): the stamps jump back by the bag length (2 s here, more
    than stamp_reset_s) every lap."""
    logic = EstimatorLogic(AXES, EstimatorSettings(min_dwell_s=0.05, temperature_wait_s=0.0))
    per_lap = []
    for _lap in range(3):
        t = T0
        got = []
        for _ in range(200):
            t += 10 * MS
            got += run(logic, t, 1.0, 0.06)
        per_lap.append(len(got))
    assert per_lap[0] > 0 and per_lap[1] == per_lap[2] and per_lap[1] > 0
    assert logic.counters.rejected[EL][R_RESET] == 2


@pytest.mark.parametrize(('opposing_a', 'allowed_nm'), [(-0.06, 0.0), (-0.4, None)])
def test_current_against_the_motion_is_refused_not_published_with_the_wrong_sign(opposing_a, allowed_nm):
    """Every third current says friction pulls the other way: by 3.5 mN*m with no opposing torque allowed, by
    20 mN*m with the default allowance (``max_opposing_torque_nm``, 10 mN*m, kept for an unbalance)."""
    settings = EstimatorSettings(min_dwell_s=0.05, temperature_wait_s=0.0)
    if allowed_nm is not None:
        settings = dataclasses.replace(settings, max_opposing_torque_nm=allowed_nm)
    logic = EstimatorLogic(AXES, settings)
    t = T0
    good = 0
    for k in range(60):
        t += 10 * MS
        current = opposing_a if k % 3 == 0 else 0.06
        out = run(logic, t, 1.0, current)
        for m in out:
            assert m.friction_nm > 0.0
        good += len(out)
    assert good > 0
    assert logic.counters.rejected[EL][R_OPPOSES] > 0


def test_a_joint_named_twice_uses_the_first_entry_like_the_feedforward():
    """The two nodes once disagreed on ``name=[elevation, elevation]`` (last vs first entry)."""
    from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
    logic = EstimatorLogic(AXES, EstimatorSettings(min_dwell_s=0.05, temperature_wait_s=0.0))
    t = T0
    out = []
    for _ in range(40):
        t += 10 * MS
        out += logic.on_joint_state(t, [EL, EL], [0.01, 0.05], [V, -V], arrival_ns=t)
        out += logic.on_current(t, [EL, EL], [0.06, -0.06], arrival_ns=t + 1)
    assert out and all(m.velocity_rad_s == V and m.position_rad == 0.01 and m.current_a == 0.06 for m in out)
    assert logic.counters.rejected[EL]['duplicate joint name'] == 80
    ff = Feedforward({EL: AXES[EL]}, FeedforwardSettings(table_step_c=5.0))
    ff.update_temperature(20.0, 0.0)
    msg = ff.message([EL, EL], [V, -V], 0.0)
    assert msg is not None and msg.torques_nm[0] > 0.0        # the first entry (+V) here too
