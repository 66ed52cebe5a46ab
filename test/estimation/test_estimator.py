"""Estimator logic (pure): pairing, rejection reasons, Eq. 23 signs, time jumps, observer, statistics, and the one
property that makes live = offline: the result does not depend on how the messages are batched."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_friction.chamber import synth
from gimbal_friction.common.errors import ConfigError
from gimbal_friction.estimation import estimator as est
from gimbal_friction.estimation.estimator import EstimatorLogic, EstimatorSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.bag import open_chamber_bag
from gimbal_friction.streams.arrays import ChamberArrays, JointStateArrays, TemperatureArrays
from gimbal_friction.streams.measurement import METHOD_OBSERVER, METHOD_STEADY_STATE, MeasurementArrays

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / 'bags' / 'chamber_sample'
V = 2 * math.pi / 180          # 1/3 rpm [rad/s]
KT, I0 = 0.05, 0.01
MS = 1_000_000                 # 1 ms [ns]
S = 1_000_000_000              # 1 s [ns]
DT = 20 * MS                   # 50 Hz
EL = 'elevation'


def make(**settings) -> EstimatorLogic:
    """An estimator of one joint; by default samples do not wait for a later temperature (the tests of pairing and
    verdicts feed none), the wait has tests of its own."""
    settings.setdefault('temperature_wait_s', 0.0)
    return EstimatorLogic({EL: AxisParams(torque_constant_nm_per_a=KT, no_load_current_a=I0)},
                          EstimatorSettings(**settings))


def warm(logic: EstimatorLogic, v: float = V, n: int = 40, t0: int = S, pos0: float = 0.0) -> int:
    """Constant-speed joint states from pos0 for n samples at 50 Hz (beyond the default 0.5 s dwell); last stamp."""
    for k in range(n):
        t = t0 + k * DT
        logic.on_joint_state(t, [EL], [pos0 + v * k * DT * 1e-9], [v])
    return t0 + (n - 1) * DT


def rejected(logic: EstimatorLogic, reason: str, joint: str = EL) -> int:
    return logic.counters.rejected_count(joint, reason)


# ------------------------------------------------------------------------------------------------ settings
def test_defaults_follow_the_paper():
    s = EstimatorSettings()
    s.validate()
    assert s.commanded_speed_rad_s == pytest.approx(1 / 3 * 2 * math.pi / 60)
    assert math.degrees(s.position_min_rad) == pytest.approx(-5.0)
    assert math.degrees(s.position_max_rad) == pytest.approx(10.0)
    assert s.method == 'steady_state'


@pytest.mark.parametrize(('name', 'value', 'rule'), [
    ('commanded_speed_rad_s', 0.0, '(0, 100]'),
    ('speed_tolerance', 1.0, '(0, 1)'),
    ('min_dwell_s', -0.1, '[0, 3600]'),
    ('position_max_rad', -0.2, 'exceed position_min_rad'),
    ('max_accel_rad_s2', 0.0, '(0, 1e6]'),
    ('pairing_tolerance_s', -0.001, '[0, 10]'),
    ('max_current_a', -1.0, '(0, 1e4]'),
    ('temperature_bin_c', 0.0, '[0.001, 1000]'),
    ('temperature_timeout_s', 0.0, '(0, 86400]'),
    ('temperature_min_c', -300.0, '>= -200'),
    ('temperature_max_c', -70.0, 'exceed temperature_min_c'),
    ('ripple_bins', 0, 'integer'),
    ('ripple_bins', 2.5, 'integer'),
    ('speed_tolerance', math.nan, 'finite'),
    ('method', 'guess', 'one of'),
    ('stamp_reset_s', 0.0, '(0, 1e6]'),
    ('acceleration_window_s', 0.0, '[1e-4, 10]'),
])
def test_settings_refuse_bad_values(name, value, rule):
    with pytest.raises(ConfigError) as err:
        EstimatorSettings(**{name: value}).validate()
    assert err.value.parameter == name and rule in err.value.rule


# ------------------------------------------------------------------------------------------------ Eq. 23
@pytest.mark.parametrize('direction', [1, -1])
def test_eq23_sign_both_directions(direction):
    logic = make()
    t = warm(logic, v=direction * V)
    current = direction * 0.06   # motor pushes along the motion
    assert logic.on_current(t, [EL], [current]) == []              # decided once a later joint state arrives
    (m,) = logic.on_joint_state(t + DT, [EL], [0.1], [direction * V])
    assert m.direction == direction and m.method == METHOD_STEADY_STATE
    assert m.friction_nm == pytest.approx(KT * (current - direction * I0), rel=1e-15)
    assert m.friction_nm == pytest.approx(direction * 0.0025)   # 0.05 * (0.06 - 0.01), signed like the motion
    assert m.stamp_ns == t and m.velocity_rad_s == direction * V and m.current_a == current
    assert (m.torque_constant_nm_per_a, m.no_load_current_a) == (KT, I0)
    assert math.isnan(m.temperature_c) and not m.temperature_fresh
    assert logic.counters.accepted[EL] == 1


def test_friction_against_the_motion_is_refused_beyond_max_opposing_torque():
    logic = make(max_opposing_torque_nm=0.0)      # none kept: friction alone
    t = warm(logic)
    logic.on_current(t, [EL], [-0.05])            # pushes against the motion: not friction
    assert logic.on_joint_state(t + DT, [EL], [0.1], [V]) == []
    assert rejected(logic, 'friction opposes motion') == 1
    logic.on_current(t + DT, [EL], [0.005])       # below I_0: K_T (I - I_0) < 0
    assert logic.on_joint_state(t + 2 * DT, [EL], [0.1], [V]) == []
    assert rejected(logic, 'friction opposes motion') == 2
    # the default keeps a torque against the motion up to 10 mN*m (an unbalance outweighing the friction): the motor
    # must supply it, and learning needs both directions to tell it from friction
    logic = make()
    t = warm(logic)
    logic.on_current(t, [EL], [-0.05])            # 0.05 * (-0.05 - 0.01) = -3 mN*m
    (m,) = logic.on_joint_state(t + DT, [EL], [0.1], [V])
    assert m.friction_nm == pytest.approx(-0.003)
    logic.on_current(t + DT, [EL], [-1.0])        # -50 mN*m: beyond any unbalance, refused
    assert logic.on_joint_state(t + 2 * DT, [EL], [0.1], [V]) == []
    assert rejected(logic, 'friction opposes motion') == 1


# ------------------------------------------------------------------------------------------------ pairing
def test_current_pairs_with_the_nearest_joint_state_within_tolerance():
    logic = make()
    t = warm(logic)
    logic.on_joint_state(t + 4 * MS, [EL], [0.15], [V])      # both within 5 ms of the current below
    assert logic.on_current(t + 1 * MS, [EL], [0.05]) == []   # not decided: a nearer one could still come
    (m,) = logic.on_joint_state(t + DT, [EL], [0.2], [V])
    assert m.stamp_ns == t                                   # 1 ms away beats 3 ms away


def test_arrival_order_does_not_matter():
    a, b = make(), make()
    ta, tb = warm(a), warm(b)
    a.on_current(ta + DT, [EL], [0.05])                      # current before its joint state
    out_a = a.on_joint_state(ta + DT, [EL], [0.1], [V]) + a.on_joint_state(ta + 2 * DT, [EL], [0.1], [V])
    out_b = b.on_joint_state(tb + DT, [EL], [0.1], [V])      # joint state before its current
    out_b += b.on_current(tb + DT, [EL], [0.05]) + b.on_joint_state(tb + 2 * DT, [EL], [0.1], [V])
    assert len(out_a) == 1 and out_a[0].stamp_ns == ta + DT
    assert [m._replace(temperature_c=0.0) for m in out_a] == [m._replace(temperature_c=0.0) for m in out_b]


def test_late_current_pairs_with_its_own_older_joint_state():
    logic = make()
    t = warm(logic)
    logic.on_joint_state(t + DT, [EL], [0.11], [V])
    logic.on_joint_state(t + 2 * DT, [EL], [0.12], [V])
    (m,) = logic.on_current(t + DT - 3 * MS, [EL], [0.05])   # late current of the sample before last: decided now
    assert m.stamp_ns == t + DT and m.position_rad == 0.11


def test_tolerance_boundary_is_inclusive_and_outside_is_unpaired():
    logic = make(pairing_tolerance_s=0.005)
    t = warm(logic)
    logic.on_current(t + 5 * MS, [EL], [0.05])               # exactly 5 ms after a joint state
    logic.on_current(t + 10 * MS, [EL], [0.05])              # 10 ms from both neighbours
    out = logic.on_joint_state(t + DT, [EL], [0.1], [V])
    assert [m.stamp_ns for m in out] == [t]
    assert rejected(logic, 'unpaired') == 1 and logic.pending(EL) == 0


def test_waiting_buffer_is_bounded():
    logic = make()
    for k in range(est.WAIT_LENGTH + 5):
        logic.on_current(S + k * DT, [EL], [0.05])   # no joint state ever
    assert logic.pending(EL) == est.WAIT_LENGTH
    assert rejected(logic, 'unpaired') == 5


def test_history_bounds_how_late_a_current_may_arrive():
    logic = make(min_dwell_s=0.0)
    t = warm(logic, n=est.HISTORY_LENGTH + 10, pos0=-0.08)
    logic.on_current(S, [EL], [0.05])                         # its joint state is HISTORY_LENGTH + 9 back
    assert rejected(logic, 'unpaired') == 1
    (m,) = logic.on_current(t - 5 * DT, [EL], [0.05])         # 5 back: still in the history
    assert m.stamp_ns == t - 5 * DT


# ------------------------------------------------------------------------------------------------ rejections
def test_bad_inputs_are_rejected_and_counted_never_returned():
    logic = make()
    t = warm(logic)
    for bad in ([math.nan], [math.inf], [2.5], [-2.01]):
        assert logic.on_current(t, [EL], bad) == []
    assert logic.on_current(t, ['bogus'], [0.05]) == []
    assert logic.on_current(t, [EL, 'x'], [0.05]) == []           # length mismatch
    assert logic.on_joint_state(t + DT, [EL], [math.nan], [V]) == []
    assert logic.on_joint_state(t + DT, [EL], [0.1], [math.inf]) == []
    assert logic.on_joint_state(t + DT, [EL], [0.1], []) == []    # length mismatch
    assert logic.on_joint_state(t, [EL], [0.1], [V]) == []        # same stamp as the last one
    assert logic.on_joint_state(t - DT, [EL], [0.1], [V]) == []   # older
    c = logic.counters
    assert c.rejected[EL] == {'non-finite': 2, 'over current rating': 2, 'length mismatch': 2,
                              'non-finite joint state': 2, 'stamp not increasing': 2}
    assert c.rejected['*'] == {'unknown joint': 1}   # the mismatch names a configured joint: counted there
    assert c.accepted[EL] == 0
    # a message naming an unknown and a configured joint, and the configured one twice: the first entry counts
    logic.on_joint_state(t + DT, [EL], [0.1], [V])
    logic.on_current(t + DT, ['bogus', EL, EL], [9.0, 0.05, 0.07])
    (m,) = logic.on_joint_state(t + 2 * DT, [EL], [0.1], [V])
    assert m.current_a == 0.05 and c.rejected['*']['unknown joint'] == 2
    assert c.rejected[EL]['duplicate joint name'] == 1


def test_nan_current_is_counted_and_never_paired():
    logic = make()
    t = warm(logic)
    assert logic.on_current(t, [EL], [math.nan]) == []
    assert logic.pending(EL) == 0 and rejected(logic, 'non-finite') == 1


def test_temperature_rejections_and_credible_range():
    logic = make()
    for t in (math.nan, -300.0, -61.0, 999.0, 25.0):
        logic.on_temperature(t, stamp_ns=S)
    assert logic.counters.temperature_rejected == {'non-finite temperature': 1, 'temperature out of range': 3}
    assert logic.last_temperature_c == 25.0


def test_a_future_stamp_does_not_stop_the_estimator_for_good():
    logic = make(min_dwell_s=0.0)
    t = warm(logic, t0=10 * S)
    logic.on_joint_state(t + 10**6 * S, [EL], [0.1], [V])      # one sample stamped 11 days ahead
    t2 = warm(logic, t0=t + DT, n=5)                            # the time source goes on as before
    assert rejected(logic, 'stream restarted (stamp jumped back)') == 1
    logic.on_current(t2, [EL], [0.05])
    assert len(logic.on_joint_state(t2 + DT, [EL], [0.1], [V])) == 1
    # a bag played in a loop / simulated time restarting: the stream restarts again
    t3 = warm(logic, t0=S, n=5)
    logic.on_current(t3, [EL], [0.05])
    assert len(logic.on_joint_state(t3 + DT, [EL], [0.1], [V])) == 1
    assert rejected(logic, 'stream restarted (stamp jumped back)') == 2
    assert rejected(logic, 'stamp not increasing') == 0


def test_zero_stamps_fall_back_to_the_arrival_time():
    logic = make(min_dwell_s=0.0)
    for k in range(5):
        logic.on_joint_state(0, [EL], [0.0], [V], arrival_ns=S + k * DT)
    logic.on_current(0, [EL], [0.05], arrival_ns=S + 4 * DT + MS)
    (m,) = logic.on_joint_state(0, [EL], [0.0], [V], arrival_ns=S + 5 * DT)
    assert m.stamp_ns == S + 4 * DT


def test_steady_state_reasons_in_order():
    logic = make(min_dwell_s=0.5)
    # each probe's current is decided by the next joint state: feed a sequence and read the verdicts in order
    seq = [(-S, 0.0, 0.5 * V)] + [(k * DT, 0.0, V) for k in range(26)]
    seq += [(27 * DT, math.radians(10.5), V), (28 * DT, math.radians(-5.5), 0.5 * V), (29 * DT + S, 0.0, V),
            (30 * DT + S, 0.0, V)]
    emitted = []
    for t, pos, v in seq:
        emitted += logic.on_joint_state(2 * S + t, [EL], [pos], [v])
        emitted += logic.on_current(2 * S + t, [EL], [0.05 * (1 if v > 0 else -1)])
    # the window is checked first: the slow sample below -5 deg counts as outside the window; the acceleration
    # is unknown until three joint states within ten windows (the 1 s gaps): the first two at speed and the one
    # after the gap; then 0.5 s of dwell from the start of the run (2*DT .. 24*DT)
    assert logic.counters.rejected[EL] == {'speed off command': 1, 'outside position window': 2, 'acceleration': 3,
                                           'dwell': 23}
    assert [m.stamp_ns - 2 * S for m in emitted] == [25 * DT] and logic.pending(EL) == 1   # the last: undecided
    logic = make(min_dwell_s=0.0)
    out = []
    for k, v in enumerate([V, 1.05 * V, 0.91 * V, -V, -V, -V]):
        out += logic.on_joint_state(S + k * DT, [EL], [0.0], [v])
        out += logic.on_current(S + k * DT, [EL], [0.05 * (1 if v > 0 else -1)])
    # least-squares slopes over three joint states: V, 1.05 V, 0.91 V -> -0.079 rad/s^2 is steady; the windows
    # holding the reversal accelerate; the first two are not known yet; the last current is undecided
    assert logic.counters.rejected[EL] == {'acceleration': 4}
    assert [round((m.stamp_ns - S) / DT) for m in out] == [2]


def test_dwell_counts_stamps_from_the_first_sample_of_the_run():
    logic = make(min_dwell_s=0.1, max_accel_rad_s2=100.0, acceleration_window_s=0.05)
    out = []
    for t, v in ((0, V), (50, 0.5 * V), (100, V), (199, V), (200, V), (300, V)):
        out += logic.on_joint_state(S + t * MS, [EL], [0.0], [v])
        if v == V and t >= 100:
            out += logic.on_current(S + t * MS, [EL], [0.05])
    assert rejected(logic, 'dwell') == 2 and [m.stamp_ns for m in out] == [S + 200 * MS]


# ------------------------------------------------------------------------------------------------ temperature
def test_temperature_of_a_sample_freshness_by_stamps_and_plateau():
    logic = make(temperature_timeout_s=1.0, temperature_bin_c=5.0)
    logic.on_temperature(-41.3, stamp_ns=S)
    t = warm(logic)                              # 1 .. 1.78 s
    logic.on_current(t, [EL], [0.06])
    logic.on_temperature(22.4, stamp_ns=t + DT)
    t2 = warm(logic, t0=t + DT, n=3)             # same run continues
    (m,) = logic.on_current(t2 - DT, [EL], [0.06])  # decided at once (later joint states are there)
    assert m.temperature_c == 22.4 and m.temperature_fresh
    t3 = warm(logic, t0=t2 + 2 * S, n=40)        # 2 s later: 22.4 degC is stale
    logic.on_current(t3 - DT, [EL], [0.06])
    keys = [(r['plateau_c'], r['count']) for r in logic.statistics()]
    assert keys == [(-40.0, 1), (20.0, 1), (None, 1)]


def test_temperature_stamped_in_the_future_is_not_fresh():
    logic = make(temperature_timeout_s=1.0)
    t = warm(logic)
    logic.on_temperature(-40.0, stamp_ns=t + 100 * S)
    logic.on_current(t, [EL], [0.06])
    (m,) = logic.on_joint_state(t + DT, [EL], [0.1], [V])
    assert math.isnan(m.temperature_c) and not m.temperature_fresh   # not in force at the sample's stamp


def _one_sample(logic: EstimatorLogic, order: list[str], t: int) -> list:
    """A sample at stamp t between temperatures stamped t - 50 ms (-40 degC) and t + 30 ms (-39 degC), its
    messages arriving in ``order``; returns what each message completed."""
    out: list = []
    for what in order:
        if what == 'T1':
            out += logic.on_temperature(-40.0, stamp_ns=t - 50 * MS, arrival_ns=t)
        elif what == 'T2':
            out += logic.on_temperature(-39.0, stamp_ns=t + 30 * MS, arrival_ns=t)
        elif what == 'I':
            out += logic.on_current(t, [EL], [0.06], arrival_ns=t)
        else:
            out += logic.on_joint_state(t + DT, [EL], [0.1], [V], arrival_ns=t)
    return out


@pytest.mark.parametrize('order', [['T1', 'I', 'J', 'T2'], ['T1', 'T2', 'I', 'J'], ['T2', 'T1', 'I', 'J'],
                                   ['I', 'J', 'T1', 'T2'], ['I', 'T1', 'J', 'T2']])
def test_a_sample_takes_the_temperature_at_its_stamp_whatever_the_arrival_order(order):
    """Under load a later temperature can arrive before a sample's messages, an earlier one after them (issue:
    live and replay paired the same sample with different temperatures). One publisher sends its temperatures in
    stamp order."""
    for wait in (1.0, 0.0):
        logic = make(temperature_wait_s=wait)
        t = warm(logic)
        out = _one_sample(logic, order, t)
        if wait == 0.0 and order.index('J') < order.index('T1'):
            assert math.isnan(out[0].temperature_c)
            continue     # no wait: decided before the temperature in force arrived
        (m,) = out
        assert m.stamp_ns == t and m.temperature_c == -40.0 and m.temperature_fresh


def test_a_sample_waits_for_its_temperature_bounded_in_time_and_count_and_is_flushed_at_the_end():
    logic = make(temperature_wait_s=1.0)
    logic.on_temperature(-40.0, stamp_ns=S)
    t = warm(logic)
    assert logic.on_current(t, [EL], [0.06]) == []
    assert logic.on_joint_state(t + DT, [EL], [0.1], [V]) == []   # paired, waiting for a later temperature
    assert logic.held(EL) == 1
    released = []
    for k in range(2, 60):                           # no temperature comes: 1 s of stamps later it goes anyway
        released += logic.on_joint_state(t + k * DT, [EL], [0.1], [V])
        if released:
            break
    assert t + k * DT > t + S and t + (k - 1) * DT <= t + S
    (m,) = released
    assert m.temperature_c == -40.0 and m.temperature_fresh     # the one in force, 0.78 s old
    # at the end of the input the held samples are released with what is known
    logic.on_current(t + k * DT, [EL], [0.06])
    logic.on_joint_state(t + (k + 1) * DT, [EL], [0.1], [V])
    assert logic.held(EL) == 1
    (m,) = logic.flush().records()
    assert m.stamp_ns == t + k * DT and m.temperature_c == -40.0 and logic.held(EL) == 0
    # the count bound: at 10 kHz, 1 s of stamps is more than TEMPERATURE_WAIT_STATES joint states
    fast = make(temperature_wait_s=60.0, min_dwell_s=0.0)
    fast.on_temperature(-40.0, stamp_ns=S)
    dt = 100_000
    for k in range(3):
        fast.on_joint_state(2 * S + k * dt, [EL], [0.1], [V])
    fast.on_current(2 * S + 2 * dt, [EL], [0.06])
    got, k = [], 3
    while not got and k < 3 * est.TEMPERATURE_WAIT_STATES:
        got = fast.on_joint_state(2 * S + k * dt, [EL], [0.1], [V])
        k += 1
    (m,) = got
    own = (m.stamp_ns - 2 * S) // dt                 # the index of the sample's joint state
    assert k - 1 - own == est.TEMPERATURE_WAIT_STATES and m.temperature_c == -40.0


def test_final_batch_releases_the_held_samples():
    arrays = arrays_of(_TWO_JOINT_DATA)
    s = EstimatorSettings(pairing_tolerance_s=0.003)
    open_end = EstimatorLogic(TWO_AXES, s)
    closed = EstimatorLogic(TWO_AXES, s)
    a = open_end.feed(arrays)
    b = closed.feed(arrays, final=True)
    assert sum(open_end.held(j) for j in TWO_AXES) > 0
    assert len(b) == len(a) + sum(open_end.held(j) for j in TWO_AXES)
    assert sum(closed.held(j) for j in TWO_AXES) == 0
    rest = open_end.flush()
    assert len(rest) + len(a) == len(b)


# ------------------------------------------------------------------------------------------------ statistics
def _sweep(logic, direction, tau, n=400, t0=S):
    """Constant-speed pass over -6..11 deg; current from the torque tau(pos) by Eq. 23; returns the torques of the
    samples inside the window."""
    lo, hi = math.radians(-6.0), math.radians(11.0)
    dt = (hi - lo) / V / n
    kept = []
    for k in range(n):
        t = t0 + int(round(k * dt * 1e9))
        pos = lo + V * k * dt if direction > 0 else hi - V * k * dt
        out = logic.on_joint_state(t, [EL], [pos], [direction * V])
        torque = direction * tau(pos)
        out += logic.on_current(t, [EL], [torque / KT + direction * I0])
        kept.extend((m.position_rad, m.friction_nm) for m in out)
    return t0 + int(round(n * dt * 1e9)), kept


@pytest.mark.slow
def test_statistics_mean_std_and_position_ripple():
    period = math.radians(15.0)
    lo = math.radians(-5.0)

    def tau(pos):
        return 2e-3 * (1.0 + 0.1 * math.sin(2 * math.pi * (pos - lo) / period))

    logic = make(min_dwell_s=0.0, ripple_bins=15, temperature_timeout_s=60.0)
    logic.on_temperature(-39.0, stamp_ns=S)
    t, up = _sweep(logic, +1, tau)
    logic.on_temperature(-38.0, stamp_ns=t)
    _, down = _sweep(logic, -1, tau, t0=t + S)
    records = logic.statistics()
    assert [(r['direction'], r['plateau_c']) for r in records] == [(-1, -40.0), (1, -40.0)]
    for rec, kept in zip(records, (down, up)):
        pos = np.array([p for p, _ in kept])
        f = np.array([x for _, x in kept])
        assert rec['count'] == f.size > 300
        assert rec['mean_nm'] == pytest.approx(f.mean(), rel=1e-12)
        assert rec['std_nm'] == pytest.approx(f.std(ddof=1), rel=1e-9)
        assert rec['min_position'] == pos.min() >= lo and rec['max_position'] == pos.max() <= math.radians(10)
        assert np.allclose(np.abs(f), [tau(p) for p in pos], rtol=1e-12)
        assert rec['ripple_nm'] == pytest.approx(2 * 0.1 * 2e-3, rel=0.03)
        assert rec['mean_nm'] == pytest.approx(rec['direction'] * 2e-3, rel=0.01)


def test_settings_update_and_axis_params():
    logic = make(min_dwell_s=0.0)
    _sweep(logic, +1, lambda pos: 1e-3)
    assert logic.statistics()
    logic.set_axis_params(EL, AxisParams(torque_constant_nm_per_a=0.1, no_load_current_a=I0))
    assert logic.statistics() == []                      # K_T changed: statistics restart
    t = warm(logic, t0=100 * S)
    logic.on_current(t, [EL], [0.05])
    (m,) = logic.on_joint_state(t + DT, [EL], [0.0], [V])
    assert m.friction_nm == pytest.approx(0.1 * (0.05 - I0))
    logic.update_settings(EstimatorSettings(min_dwell_s=1.0))
    t = warm(logic, t0=200 * S)                          # only 0.78 s of dwell after the restart
    logic.on_current(t, [EL], [0.05])
    assert logic.on_joint_state(t + DT, [EL], [0.0], [V]) == []
    with pytest.raises(ConfigError):
        logic.update_settings(EstimatorSettings(speed_tolerance=-1.0))


# ------------------------------------------------------------------------------------------------ observer
def _working_motion(logic: EstimatorLogic, inertia: float, friction, n: int = 2000, rate: float = 1000.0,
                    noise: float = 0.0, seed: int = 0) -> list:
    """A sine scan at 1 kHz: current = (friction(v) + J a) / K_T + sign(v) I_0; returns the accepted samples."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        t = k / rate
        v = 0.2 * math.sin(2 * math.pi * 0.5 * t)
        a = 0.2 * 2 * math.pi * 0.5 * math.cos(2 * math.pi * 0.5 * t)
        d = 1.0 if v > 0 else -1.0
        current = (d * friction(abs(v)) + inertia * a) / KT + d * I0 + noise * rng.standard_normal()
        stamp = S + int(round(t * 1e9))
        out += logic.on_joint_state(stamp, [EL], [0.0], [v + noise * 0.0])
        out += logic.on_current(stamp, [EL], [current])
    return out + logic.flush().records()     # the input ends: the samples waiting for a temperature


@pytest.mark.slow
def test_observer_removes_the_inertia_term_while_the_gimbal_works():
    J = 2e-4
    logic = EstimatorLogic({EL: AxisParams(torque_constant_nm_per_a=KT, no_load_current_a=I0, inertia_kg_m2=J)},
                           EstimatorSettings(method='observer', observer_max_accel_rad_s2=1.0))
    out = _working_motion(logic, J, lambda v: 1.5e-3 + 1e-3 * v)
    assert len(out) > 1000 and all(m.method == METHOD_OBSERVER for m in out)
    for m in out:  # the window's slope lags by half a window: 1e-2 rad/s^2 * J at most here
        assert abs(m.friction_nm) == pytest.approx(1.5e-3 + 1e-3 * abs(m.velocity_rad_s), abs=3e-6)
        assert m.inertia_kg_m2 == J and abs(m.acceleration_rad_s2) <= 1.0
    r = logic.counters.rejected[EL]
    assert r['observer: speed near zero'] > 0 and 'outside position window' not in r
    # the steady-state method accepts none of this motion
    steady = make()
    assert _working_motion(steady, J, lambda v: 1.5e-3) == []


@pytest.mark.slow
def test_observer_rejects_large_and_noisy_accelerations():
    logic = EstimatorLogic({EL: AxisParams(torque_constant_nm_per_a=KT, no_load_current_a=I0)},
                           EstimatorSettings(method='observer', observer_max_accel_rad_s2=0.2))
    _working_motion(logic, 1e-4, lambda v: 1e-3)
    assert rejected(logic, 'observer: acceleration') > 0
    # velocity noise: the standard error of the slope over 10 ms grows above the limit
    noisy = EstimatorLogic({EL: AxisParams(torque_constant_nm_per_a=KT)},
                           EstimatorSettings(method='observer', observer_max_accel_noise_rad_s2=0.5))
    rng = np.random.default_rng(1)
    for k in range(200):
        v = 0.1 + 0.01 * rng.standard_normal()
        noisy.on_joint_state(S + k * MS, [EL], [0.0], [v])
        noisy.on_current(S + k * MS, [EL], [0.06])
    assert rejected(noisy, 'observer: acceleration noise', EL) > 100


def test_both_methods_prefer_steady_state():
    logic = EstimatorLogic({EL: AxisParams(torque_constant_nm_per_a=KT, no_load_current_a=I0)},
                           EstimatorSettings(method='both', min_dwell_s=0.0, observer_min_speed_rad_s=0.01))
    out = []
    for k in range(100):
        out += logic.on_joint_state(S + k * DT, [EL], [0.0], [V])
        out += logic.on_current(S + k * DT, [EL], [0.05])
    out += logic.flush().records()       # no temperature comes: the input ends
    assert out and {m.method for m in out} == {METHOD_STEADY_STATE}


# ------------------------------------------------------------------------------------------------ batching
def arrays_of(data: synth.SynthData) -> ChamberArrays:
    """ChamberArrays of a synthetic test, as read_arrays() gives them."""
    names = data.joints
    nj, nc = data.joint_stamp_ns.size, data.current_stamp_ns.size

    def nan(n):
        return {j: np.full(n, np.nan) for j in names}

    return ChamberArrays(
        TemperatureArrays(data.temperature_log_ns, data.temperature_stamp_ns, data.temperature_c),
        JointStateArrays(data.joint_log_ns, data.joint_stamp_ns, names,
                         {j: data.position_rad[:, i].copy() for i, j in enumerate(names)},
                         {j: data.velocity_rad_s[:, i].copy() for i, j in enumerate(names)}, nan(nj)),
        JointStateArrays(data.current_log_ns, data.current_stamp_ns, names, nan(nc), nan(nc),
                         {j: data.current_a[:, i].copy() for i, j in enumerate(names)}))


def _cut(a: ChamberArrays, lo: int, hi: int) -> ChamberArrays:
    def js(j: JointStateArrays) -> JointStateArrays:
        s = (j.log_time_ns >= lo) & (j.log_time_ns < hi)
        return JointStateArrays(j.log_time_ns[s], j.stamp_ns[s], j.names, {k: v[s] for k, v in j.position.items()},
                                {k: v[s] for k, v in j.velocity.items()}, {k: v[s] for k, v in j.effort.items()})
    t = a.temperature
    s = (t.log_time_ns >= lo) & (t.log_time_ns < hi)
    return ChamberArrays(TemperatureArrays(t.log_time_ns[s], t.stamp_ns[s], t.temperature_c[s]),
                         js(a.joint_states), js(a.motor_current))


def feed_in_batches(axes, settings, arrays: ChamberArrays, edges) -> tuple[MeasurementArrays, EstimatorLogic]:
    lo, hi = _span(arrays)
    edges = sorted({lo, hi, *(int(e) for e in edges if lo < int(e) < hi)})
    logic = EstimatorLogic(axes, settings)
    parts = [logic.feed(_cut(arrays, lo, hi)) for lo, hi in zip(edges[:-1], edges[1:])]
    return MeasurementArrays.concatenate(parts), logic


def _span(a: ChamberArrays) -> tuple[int, int]:
    logs = np.concatenate([a.temperature.log_time_ns, a.joint_states.log_time_ns, a.motor_current.log_time_ns])
    return int(logs.min()), int(logs.max()) + 1


def assert_same_run(a, b) -> None:
    (ma, la), (mb, lb) = a, b
    assert len(ma) == len(mb)
    for name, x, y in zip(MeasurementArrays._fields, ma, mb):
        assert np.array_equal(np.asarray(x), np.asarray(y), equal_nan=np.asarray(x).dtype.kind == 'f'), name
    assert la.counters == lb.counters
    assert {j: la.pending(j) for j in la.order} == {j: lb.pending(j) for j in lb.order}
    assert {j: la.held(j) for j in la.order} == {j: lb.held(j) for j in lb.order}
    for r, s in zip(la.statistics(), lb.statistics(), strict=True):
        for key in r:
            if isinstance(r[key], float):
                assert r[key] == pytest.approx(s[key], rel=1e-9, abs=1e-15), key
            else:
                assert r[key] == s[key], key


TWO_AXES = {'elevation': AxisParams(no_load_current_a=0.01),
            'azimuth': AxisParams(no_load_current_a=0.01, torque_constant_nm_per_a=0.06)}
_TWO_JOINT_DATA = synth.generate(synth.SynthConfig(plateaus_c=(-40.0, 20.0), hold_s=6.0,
                                                   joints=('elevation', 'azimuth'), joint_rate_hz=100.0,
                                                   current_rate_hz=130.0, no_load_current_a=0.01, seed=3))


@settings(max_examples=8, deadline=None)
@given(cuts=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40), method=st.sampled_from(est.METHODS))
@pytest.mark.slow
def test_any_batching_gives_the_same_result(cuts, method):
    arrays = arrays_of(_TWO_JOINT_DATA)
    lo, hi = _span(arrays)
    s = EstimatorSettings(pairing_tolerance_s=0.003, method=method)
    edges = sorted({lo, hi, *(lo + int(c * (hi - lo)) for c in cuts)})
    whole = feed_in_batches(TWO_AXES, s, arrays, [lo, hi])
    assert_same_run(feed_in_batches(TWO_AXES, s, arrays, edges), whole)
    assert len(whole[0]) > 300 and set(whole[0].joint.tolist()) == {'elevation', 'azimuth'}
    assert whole[1].counters.rejected['elevation']['unpaired'] > 0     # 130 Hz currents vs 100 Hz joint states


def _mangle(arrays: ChamberArrays, rng: np.random.Generator) -> ChamberArrays:
    """Inject inf, NaN (= joint absent), over-current values, an unknown joint, shuffled and jumping stamps."""
    js, mc = arrays.joint_states, arrays.motor_current
    pos = {k: v.copy() for k, v in js.position.items()}
    vel = {k: v.copy() for k, v in js.velocity.items()}
    eff = {k: v.copy() for k, v in mc.effort.items()}
    n, m = len(js), len(mc)
    pos[EL][rng.random(n) < 0.01] = np.inf
    vel[EL][rng.random(n) < 0.02] = np.nan
    eff[EL][rng.random(m) < 0.01] = -np.inf
    eff[EL][rng.random(m) < 0.02] = np.nan
    eff[EL][rng.random(m) < 0.01] = 3.0
    pos['bogus'] = np.where(rng.random(n) < 0.05, 0.0, np.nan)
    vel['bogus'] = np.full(n, np.nan)
    js_stamp = js.stamp_ns.copy()
    swap = np.flatnonzero(rng.random(n - 1) < 0.02)
    js_stamp[swap], js_stamp[swap + 1] = js.stamp_ns[swap + 1], js.stamp_ns[swap]
    js_stamp[rng.integers(0, n, 3)] += 10**6 * S          # a few far-future stamps
    js_stamp[rng.random(n) < 0.01] = 0                   # unstamped joint states
    c_stamp = mc.stamp_ns + rng.integers(-7, 8, m) * MS
    temp = arrays.temperature.temperature_c.copy()
    temp[rng.random(temp.size) < 0.1] = np.nan
    nan_n = {k: np.full(n, np.nan) for k in pos}
    return ChamberArrays(
        arrays.temperature._replace(temperature_c=temp),
        JointStateArrays(js.log_time_ns, js_stamp, tuple(pos), pos, vel, nan_n),
        JointStateArrays(mc.log_time_ns, c_stamp, mc.names, mc.position, mc.velocity, eff))


@pytest.mark.parametrize('seed', range(4))
def test_batching_invariance_with_bad_and_shuffled_inputs(seed):
    rng = np.random.default_rng(seed)
    cfg = synth.SynthConfig(plateaus_c=(-20.0, 0.0), hold_s=8.0, joint_rate_hz=50.0, seed=seed,
                            log_jitter_s=float(rng.choice([0.0, 0.009])))
    arrays = _mangle(arrays_of(synth.generate(cfg)), rng)
    s = EstimatorSettings(pairing_tolerance_s=float(rng.choice([0.0, 0.005, 0.02])), max_current_a=2.0,
                          temperature_timeout_s=float(rng.choice([0.3, 5.0])), min_dwell_s=0.2,
                          method=str(rng.choice(est.METHODS)))
    axes = {EL: AxisParams(no_load_current_a=0.005)}
    lo, hi = _span(arrays)
    whole = feed_in_batches(axes, s, arrays, [lo, hi])
    assert_same_run(feed_in_batches(axes, s, arrays, np.linspace(lo, hi, 97).astype(np.int64).tolist()), whole)
    rej = whole[1].counters.rejected
    assert rej[EL]['non-finite'] > 0 and rej[EL]['over current rating'] > 0
    assert rej[EL]['non-finite joint state'] > 0 and rej['*']['unknown joint'] > 0
    assert rej[EL]['stream restarted (stamp jumped back)'] >= 3
    assert np.all(np.isfinite(whole[0].friction_nm))
    assert np.all(np.sign(whole[0].friction_nm) == whole[0].direction)


@pytest.mark.slow
def test_message_by_message_equals_one_batch_on_the_sample_bag():
    arrays = open_chamber_bag(SAMPLE).read_arrays()
    lo, hi = _span(arrays)
    cut = lo + (hi - lo) // 12                           # the first 100 s, message by message
    part = _cut(arrays, lo, cut)
    logs = np.unique(np.concatenate([part.temperature.log_time_ns, part.joint_states.log_time_ns,
                                     part.motor_current.log_time_ns]))
    edges = [*logs.tolist(), cut]
    axes = {EL: AxisParams()}
    assert_same_run(feed_in_batches(axes, EstimatorSettings(), part, edges),
                    feed_in_batches(axes, EstimatorSettings(), part, [lo, cut]))


SAMPLE_CONFIG = dict(plateaus_c=(-40.0, -20.0, 0.0, 20.0, 40.0, 60.0), hold_s=40.0, ramp_rate_c_per_min=15.0,
                     bearing_lag_s=30.0, joint_rate_hz=25.0, temperature_rate_hz=2.0, seed=2017)


def test_sample_bag_friction_approaches_the_synthetic_truth():
    cfg = synth.SynthConfig(**SAMPLE_CONFIG)
    data = synth.generate(cfg)
    arrays = open_chamber_bag(SAMPLE).read_arrays()
    assert np.array_equal(data.current_stamp_ns, arrays.motor_current.stamp_ns)   # same test as the bag
    logic = EstimatorLogic({EL: AxisParams()}, EstimatorSettings())
    m = logic.feed(arrays)
    rej = logic.counters.rejected[EL]
    assert len(m) > 20000 and rej['outside position window'] > 0 and rej['dwell'] > 0 and 'unpaired' not in rej
    k = np.searchsorted(data.current_stamp_ns, m.stamp_ns)
    assert np.array_equal(data.current_stamp_ns[k], m.stamp_ns)
    truth = data.truth_friction_nm[k, 0]
    err = m.friction_nm - truth
    assert abs(err.mean()) < 5e-6 and err.std() == pytest.approx(cfg.current_noise_a * 0.05, rel=0.05)
    assert np.all(np.sign(m.friction_nm) == m.direction)
    summary = synth.truth_summary(cfg)['elevation']['plateaus']
    plateau_c = np.where(m.temperature_fresh, est.plateau_of(m.temperature_c, 5.0), np.nan)
    for plateau, table in zip(data.plateaus, summary):
        t0 = cfg.start_ns + int(plateau.hold_start_s * 1e9)
        t1 = cfg.start_ns + int(plateau.hold_end_s * 1e9)
        for direction, key in ((1, 'truth_cw_nmm'), (-1, 'truth_ccw_nmm')):
            sel = (m.stamp_ns >= t0) & (m.stamp_ns <= t1) & (m.direction == direction)
            n = int(sel.sum())
            assert n > 300
            assert set(plateau_c[sel].tolist()) == {plateau.temperature_c}
            mean = m.friction_nm[sel].mean()
            assert abs(mean - truth[sel].mean()) < 4 * 1e-4 / math.sqrt(n)
            assert mean * 1e3 == pytest.approx(table[key], rel=0.03)
    stats = {(r['direction'], r['plateau_c']): r for r in logic.statistics()}
    ratio = -stats[(-1, -40.0)]['mean_nm'] / stats[(1, -40.0)]['mean_nm']
    assert 0.7 < ratio < 0.85
    assert stats[(1, -40.0)]['ripple_nm'] > stats[(1, 40.0)]['ripple_nm']   # ripple doubles in the cold


def test_empty_and_joint_less_inputs():
    arrays = arrays_of(synth.generate(synth.SynthConfig(plateaus_c=(0.0,), hold_s=1.0, joint_rate_hz=10.0)))
    empty = _cut(arrays, 0, 0)
    logic = EstimatorLogic({EL: AxisParams()}, EstimatorSettings())
    assert len(logic.feed(empty)) == 0 and logic.statistics() == []
    other = EstimatorLogic({'azimuth': AxisParams()}, EstimatorSettings())   # joint not in the bag
    assert len(other.feed(arrays)) == 0 and other.counters.rejected['*']['unknown joint'] > 0
    with pytest.raises(ConfigError):
        EstimatorLogic({}, EstimatorSettings())
