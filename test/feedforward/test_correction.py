"""The learned correction (gimbal_friction.feedforward.correction): what it learns (level, speed profile, ripple at
periods found in the data, a torque independent of the direction), the guard (test, then train), the bound, the
gate, the learner."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.xp import ARRAY
from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionSettings,
    Learner,
    LearningSettings,
    load,
    model_identity,
    save,
)
from gimbal_friction.feedforward.correction.periods import strongest_period_GLS_Zechmeister_2009
from gimbal_friction.physics.direction import direction_factor
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import FrictionTable

BASE = AxisParams()
TABLE = FrictionTable(BASE)
IDENT = model_identity({'elevation': BASE})
SPEED = 0.0349066  # the paper's 1/3 rpm [rad/s]
#: settings that apply every candidate at once (no guard): for tests of what is fitted
OPEN = CorrectionSettings(guard_min_samples=0, guard_z=0.0)
#: the guard on independent samples (these tests draw them so): blocks of a few suffice, fewer samples are needed
GUARDED = CorrectionSettings(guard_min_samples=300, guard_block_samples=25)


def model_nm(t_c, v):
    """The model friction signed like the motion [N*m] (what the feedforward's residual is taken against)."""
    t_c, v = np.asarray(t_c, dtype=float), np.asarray(v, dtype=float)
    return np.sign(v) * direction_factor(TABLE.params, t_c, v, ARRAY) * TABLE.magnitude_nm(t_c, np.abs(v), ARRAY)


def samples(n, rng, t_lo=-42.5, t_hi=62.5, speeds=(SPEED,), travel_deg=(-6.0, 11.0)):
    """Temperatures [degC], velocities at +-the speeds [rad/s] and positions over the travel [rad], in time order."""
    t = rng.uniform(t_lo, t_hi, n)
    v = rng.choice([-1.0, 1.0], n) * rng.choice(np.asarray(speeds), n)
    p = rng.uniform(*np.radians(travel_deg), n)
    return t, v, p


def learn(torque, settings=OPEN, n=60_000, seed=0, noise_nm=2e-5, **kw):
    """A correction learned test-then-train from the residuals of a truth that adds ``torque(t, v, p, m)`` [N*m]
    (signed, absolute: the motor must supply it) to the model, + noise."""
    rng = np.random.default_rng(seed)
    t, v, p = samples(n, rng, **kw)
    m = model_nm(t, v)
    r = torque(t, v, p, np.abs(m)) + rng.normal(0.0, noise_nm, n)
    c, refused = Correction.from_residuals(settings, IDENT, {'elevation': (t, v, p, r, m)})
    assert refused == {'elevation': {}}
    return c


def applied_torque(c, t, v, p):
    """What the feedforward adds to the model torque [N*m]: tanh(v/v_th)(M + odd) + even - tanh M, at |v| >> v_th."""
    m = abs(float(model_nm(t, v)))
    odd, even = c.split_nm('elevation', t, v, p, m)
    return (odd if v >= 0.0 else -odd) + even


# ------------------------------------------------------------------------------------------------ lookup
def test_an_empty_correction_is_exactly_zero():
    c = Correction(CorrectionSettings(), IDENT)
    assert c.split_nm('elevation', -40.0, SPEED, 0.1, 3e-3) == (0.0, 0.0)
    assert c.along_nm('elevation', 20.0, -SPEED, math.nan, 1e-3) == 0.0
    odd, even = c.split_nm_array('elevation', [0.0, 1.0], [1.0, -1.0], 0.0, 1e-3)
    assert np.array_equal(odd, [0.0, 0.0]) and np.array_equal(even, [0.0, 0.0])


@pytest.mark.slow
def test_the_array_lookup_gives_the_scalar_lookups_numbers():
    c = learn(lambda t, v, p, m: np.sign(v) * (2e-4 + 0.05 * m * np.sin(2 * np.pi * p / np.radians(3.4)))
              + 3e-4 * np.sin(p), speeds=(0.01, 0.03, 0.1, 0.4))
    rng = np.random.default_rng(3)
    n = 3000
    t = rng.choice([-40.0, -37.3, 0.0, 21.0, 59.0, 130.0, np.nan], n)
    v = rng.choice([-1.0, 1.0], n) * 10 ** rng.uniform(-4, 1, n)
    p = rng.uniform(-0.3, 0.4, n)
    p[::7] = np.nan
    m = np.abs(model_nm(np.where(np.isfinite(t), t, 20.0), v))
    odd, even = c.split_nm_array('elevation', t, v, p, m)
    scalar = np.array([c.split_nm('elevation', *map(float, x)) for x in zip(t, v, p, m, strict=True)])
    np.testing.assert_allclose(odd, scalar[:, 0], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(even, scalar[:, 1], rtol=1e-12, atol=1e-18)


# ------------------------------------------------------------------------------------------------ what it learns
@pytest.mark.slow
def test_a_level_off_the_model_is_learned_per_temperature_bin_and_shrunk_where_thin():
    c = learn(lambda t, v, p, m: np.sign(v) * 0.3 * m)       # 30 % more friction than the model everywhere
    for t in (-40.0, 0.0, 40.0):
        m = abs(float(model_nm(t, SPEED)))
        assert applied_torque(c, t, SPEED, 0.05) == pytest.approx(0.3 * m, rel=0.05)
        assert applied_torque(c, t, -SPEED, 0.05) == pytest.approx(-0.3 * m, rel=0.05)
    thin = learn(lambda t, v, p, m: np.sign(v) * 2e-4, n=400, t_lo=-40.5, t_hi=-39.5)
    # the part along the motion learned from 400 samples (both directions) against a prior of 50: 400/450 of it
    assert applied_torque(thin, -40.0, SPEED, 0.05) == pytest.approx(400 / 450 * 2e-4, rel=0.05)


@pytest.mark.slow
def test_a_speed_profile_that_falls_and_rises_is_learned():
    """Stribeck at low speed (more friction), a viscous rise above: one value per cell could not hold both. The
    profile is smoothed like ``speed_smoothing`` x n0 samples per octave pair, so the shape needs more samples than
    that in its cell (here 20 000 per octave and direction). Applied as learned with ``falling_friction``; by
    default the fall is learned and reported but the feedforward's friction is held from falling with speed."""
    def extra(t, v, p, m):
        a = np.abs(v)
        return np.sign(v) * (4e-4 * np.exp(-(a / 0.02) ** 2) + 3e-4 * (a / 0.4) ** (2 / 3))
    speeds = (0.007, 0.012, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64)
    c = learn(extra, settings=dataclasses.replace(OPEN, falling_friction=True), speeds=speeds, n=320_000,
              t_lo=-2.0, t_hi=2.0)
    for a in (0.01, 0.02, 0.05, 0.3, 0.6):
        want = float(extra(0.0, a, 0.0, 0.0))
        got = applied_torque(c, 0.0, a, 0.05)
        assert got == pytest.approx(want, abs=0.12 * 4e-4), (a, got, want)
    assert applied_torque(c, 0.0, 0.01, 0.0) > applied_torque(c, 0.0, 0.06, 0.0) < applied_torque(c, 0.0, 0.6, 0.0)

    held = learn(extra, speeds=speeds, n=320_000, t_lo=-2.0, t_hi=2.0)
    cand = held.joint('elevation').candidate
    b0 = 12                                                                            # the bin at 0 degC
    assert cand is not None and cand.params.speed_nm[0, b0, 1] > cand.params.speed_nm[0, b0, 4]   # the fall, learned
    speeds_up = (0.01, 0.02, 0.05, 0.1, 0.3, 0.6)
    friction = [abs(float(model_nm(0.0, a))) + applied_torque(held, 0.0, a, 0.05) for a in speeds_up]
    assert all(b >= a - 2e-6 for a, b in zip(friction, friction[1:])), friction     # delivered: never falling
    assert applied_torque(held, 0.0, 0.6, 0.05) == pytest.approx(float(extra(0.0, 0.6, 0.0, 0.0)), abs=0.12 * 4e-4)


@pytest.mark.slow
def test_two_ripple_periods_are_found_in_irregularly_sampled_residuals():
    """Periods nobody gives: 2.2 and 0.6 deg, sampled where a scan and a sweep happen to be."""
    p1, p2 = np.radians(2.2), np.radians(0.6)

    def ripple(t, v, p, m):
        return np.sign(v) * m * (0.06 * np.sin(2 * np.pi * p / p1 + 0.4) + 0.03 * np.sin(2 * np.pi * p / p2 + 1.1))
    rng = np.random.default_rng(5)
    n = 60_000
    t = rng.uniform(-42.5, 22.5, n)
    v = rng.choice([-1.0, 1.0], n) * SPEED
    # irregular: a sine scan dwells at its ends, a sweep covers the travel once
    p = np.where(rng.uniform(size=n) < 0.5, np.radians(4.0) * np.sin(rng.uniform(0, 2 * np.pi, n)),
                 rng.uniform(np.radians(-6.0), np.radians(11.0), n))
    m = model_nm(t, v)
    r = ripple(t, v, p, np.abs(m)) + rng.normal(0.0, 2e-5, n)
    c, _ = Correction.from_residuals(OPEN, IDENT, {'elevation': (t, v, p, r, m)})
    found = sorted(q.period_rad for q in c.periods['elevation'][:2])
    assert found == pytest.approx(sorted([p2, p1]), rel=0.01)
    summary = c.summary()['joints']['elevation']['periods']
    assert all(q['z'] > 8 and q['points'] > 100 for q in summary[:2])
    for angle in np.radians([-3.0, 0.0, 1.7, 5.0]):
        for temp in (-40.0, 0.0):
            want = float(ripple(temp, SPEED, angle, abs(float(model_nm(temp, SPEED)))))
            assert applied_torque(c, temp, SPEED, float(angle)) == pytest.approx(want, abs=0.1 * abs(want) + 2e-5)


def test_the_periodogram_copes_with_irregular_sampling_and_says_nothing_without_a_period():
    rng = np.random.default_rng(2)
    theta = np.sort(np.concatenate([rng.uniform(-0.1, 0.0, 300), rng.uniform(0.05, 0.2, 100)]))   # a gap
    y = 0.04 * np.sin(2 * np.pi * theta / np.radians(1.3)) + rng.normal(0, 0.01, theta.size)
    found = strongest_period_GLS_Zechmeister_2009(theta, y, np.ones(theta.size), 0.004, 0.15)
    assert found is not None and math.degrees(found.period_rad) == pytest.approx(1.3, rel=0.01) and found.z > 10
    noise = strongest_period_GLS_Zechmeister_2009(theta, rng.normal(0, 0.01, theta.size), np.ones(theta.size),
                                                  0.004, 0.15)
    assert noise is not None and noise.z < 6
    assert strongest_period_GLS_Zechmeister_2009(theta[:5], y[:5], np.ones(5), 0.004, 0.15) is None


@pytest.mark.slow
def test_a_torque_independent_of_the_direction_is_learned_as_its_own_term():
    """An unbalance (constant and with the angle) is applied without the sign of the motion: through a reversal it
    stays instead of switching off and on."""
    def unbalance(t, v, p, m):
        return -1.5e-3 + 2e-3 * np.sin(p + 0.3)          # the motor must supply it whatever the direction
    c = learn(unbalance, t_lo=17.5, t_hi=22.5, travel_deg=(-15.0, 15.0), n=80_000)
    for angle in np.radians([-10.0, 0.0, 8.0]):
        want = float(unbalance(20.0, 0.0, angle, 0.0))
        m = abs(float(model_nm(20.0, SPEED)))
        odd, even = c.split_nm('elevation', 20.0, SPEED, float(angle), m)
        assert even == pytest.approx(want, abs=1.5e-4) and abs(odd) < 1.5e-4
        assert applied_torque(c, 20.0, -SPEED, float(angle)) == pytest.approx(want, abs=2e-4)
    assert c.summary()['max_abs_unbalance_nm'] > 1e-3


@pytest.mark.slow
def test_an_asymmetry_is_learned_per_direction():
    c = learn(lambda t, v, p, m: np.where(v > 0, 0.2 * m, 0.0))     # CW 20 % above the model, CCW as the model
    m = abs(float(model_nm(-40.0, SPEED)))
    assert applied_torque(c, -40.0, SPEED, 0.0) == pytest.approx(0.2 * m, rel=0.05)
    assert applied_torque(c, -40.0, -SPEED, 0.0) == pytest.approx(0.0, abs=0.01 * m)


# ------------------------------------------------------------------------------------------------ the guard
@pytest.mark.slow
def test_the_guard_applies_nothing_that_has_not_earned_its_place_out_of_sample():
    guarded = GUARDED
    pure_noise = learn(lambda t, v, p, m: np.zeros(np.shape(t)), settings=guarded, noise_nm=5e-4)
    s = pure_noise.summary()
    assert s['cells_applied'] == 0 and s['cells_held_back'] == s['cells_with_data'] > 0
    assert pure_noise.lookups['elevation'] is None                      # exactly the model
    reasons = {r['held_back'] for r in pure_noise.cells('elevation')}
    assert all('standard errors' in r for r in reasons), reasons
    real = learn(lambda t, v, p, m: np.sign(v) * 0.3 * m, settings=guarded)
    assert real.summary()['cells_held_back'] == 0


@pytest.mark.slow
def test_correlated_noise_is_judged_over_blocks_not_sample_by_sample():
    """A kHz stream's residual is correlated over many samples (the same ripple, the same temperature for a while):
    zero-mean noise with a memory of ~1000 samples, sweeps of 2000 samples each way. Judged sample by sample its
    score looks like evidence (|z| of 6 to 23, a cell applied); over blocks of ``guard_block_samples`` (batch means)
    the default guard applies nothing."""
    from scipy.signal import lfilter
    per_sample, blocks = [], []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        n = 40_000
        t, _, p = samples(n, rng, t_lo=17.5, t_hi=22.5)
        v = np.where((np.arange(n) // 2000) % 2 == 0, SPEED, -SPEED)
        a = 0.999
        r = lfilter([math.sqrt(1.0 - a * a)], [1.0, -a], rng.normal(0.0, 3e-4, n))
        for blk, out in ((1, per_sample), (CorrectionSettings().guard_block_samples, blocks)):
            c, _ = Correction.from_residuals(CorrectionSettings(guard_block_samples=blk, guard_min_samples=3000),
                                             IDENT, {'elevation': (t, v, p, r, model_nm(t, v))})
            out.extend((x['applied'], x['z']['correction']) for x in c.cells('elevation'))
    assert max(abs(z) for _, z in per_sample) > 5.0
    assert not any(applied for applied, _ in blocks) and max(abs(z) for _, z in blocks) < 3.0, blocks


def test_a_correction_that_would_hurt_holds_back_to_the_model():
    """The friction changes sign of its error half way (a run-in, a relubrication): what the first half taught is
    wrong on the second; scored before it is learned, the candidate loses to the model and is not applied."""
    rng = np.random.default_rng(9)
    n = 40_000
    t, v, p = samples(n, rng, t_lo=17.5, t_hi=22.5)
    m = model_nm(t, v)
    step = np.where(np.arange(n) < n // 4, 1.0, -1.0)          # +0.3 mN*m for a quarter, then -0.3 mN*m
    r = np.sign(v) * 3e-4 * step + rng.normal(0.0, 2e-5, n)
    settings = CorrectionSettings(guard_min_samples=300, guard_block_samples=25, guard_memory_samples=5000)
    c, _ = Correction.from_residuals(settings, IDENT,
                                     {'elevation': (t[:n // 2], v[:n // 2], p[:n // 2], r[:n // 2], m[:n // 2])})
    cells = c.cells('elevation')
    assert cells and not any(x['applied'] for x in cells)
    assert all(x['rms_with_nm'] > x['rms_model_nm'] for x in cells)
    assert c.lookups['elevation'] is None


def test_a_term_that_does_not_earn_its_place_is_dropped():
    """A ripple found in one stretch of data that the next does not show is not applied; the level is."""
    guarded = GUARDED
    c = learn(lambda t, v, p, m: np.sign(v) * 0.2 * m, settings=guarded, t_lo=17.5, t_hi=22.5)
    for rec in c.cells('elevation'):
        assert rec['applied'] and 'ripple' not in rec['terms']


# ------------------------------------------------------------------------------------------------ bound and gate
@pytest.mark.slow
def test_the_bound_clips_and_says_so():
    c = learn(lambda t, v, p, m: np.sign(v) * 3.0 * m,
              settings=CorrectionSettings(max_relative=0.5, guard_min_samples=0, guard_z=0.0))
    assert c.summary()['saturated_cells'] > 0
    m = abs(float(model_nm(-40.0, SPEED)))
    assert applied_torque(c, -40.0, SPEED, 0.0) <= 0.5 * m + 2e-5 + 1e-12


@pytest.mark.slow
def test_the_gate_refuses_absurd_inputs_and_every_sum_stays_finite(tmp_path):
    c = Correction(CorrectionSettings(), IDENT)
    learner = Learner(c, LearningSettings(max_rate_nm_per_min=1.0, step_period_s=0.1))
    reasons = [learner.update('elevation', -40.0, v, 0.0, f, 3e-3, now_s=0.01 * k)
               for k, (v, f) in enumerate([(0.03, 1e308), (1e300, 1e-4), (0.03, -1e308), (float('inf'), 1e-4),
                                           (0.03, 1e-4)])]
    assert reasons == ['implausible friction', 'implausible speed', 'implausible friction', 'non-finite', None]
    rng = np.random.default_rng(1)
    for k in range(3000):
        absurd = rng.choice([1e300, -1e300, 1e30, 1e-300, 0.0])
        learner.update('elevation', -40.0, float(rng.choice([0.03, -0.03, absurd])), float(rng.uniform(-1, 1)),
                       float(rng.choice([2e-4, absurd])), 3e-3, now_s=0.01 * (k + 10))
    learner.step(100.0)
    summary = learner.summary()
    assert all(math.isfinite(x) for x in (summary['max_abs_correction_nm'], summary['max_abs_ripple'],
                                          summary['max_abs_unbalance_nm']))
    assert summary['rejected']['implausible friction'] > 100 and summary['rejected']['implausible speed'] > 100
    keys, sums = c.stats('elevation').rows()
    assert np.all(np.isfinite(sums)) and np.all(np.abs(sums[:, 1]) <= 5 * sums[:, 2] + 0.005 * sums[:, 0])
    path = tmp_path / 'c.yaml'
    save(learner.snapshot(), path)   # nothing learned from absurd inputs keeps a file from being written or read
    assert load(path).stats('elevation').samples() == summary['samples']


# ------------------------------------------------------------------------------------------------ the learner
def test_the_applied_correction_moves_at_most_max_rate_per_minute_and_only_with_both_directions():
    c = Correction(OPEN, IDENT)
    learner = Learner(c, LearningSettings(max_rate_nm_per_min=6e-4, step_period_s=1.0))
    m = abs(float(model_nm(20.0, SPEED)))
    learner.step(0.0)
    for k in range(400):                                   # cw only: nothing moves
        learner.update('elevation', 20.0, SPEED, 0.0, 5e-4, m, now_s=0.1 * k)
    learner.step(40.0)
    assert applied_torque(c, 20.0, SPEED, 0.0) == 0.0
    for k in range(400):
        learner.update('elevation', 20.0, -SPEED, 0.0, -5e-4, m, now_s=40.0 + 0.1 * k)
    learner.step(80.0)
    before = applied_torque(c, 20.0, SPEED, 0.0)
    learner.step(81.0)                                       # one second: at most 1e-5 N*m
    assert 0.0 < applied_torque(c, 20.0, SPEED, 0.0) - before <= 1e-5 + 1e-12
    learner.step(1000.0)                                      # a pause does not allow a jump
    assert applied_torque(c, 20.0, SPEED, 0.0) - before <= 2e-5 + 1e-12


def test_freeze_reset_and_snapshot():
    c = Correction(OPEN, IDENT)
    learner = Learner(c, LearningSettings(max_rate_nm_per_min=1.0, step_period_s=0.1))
    m = abs(float(model_nm(20.0, SPEED)))
    for k in range(600):
        learner.update('elevation', 20.0, SPEED if k % 2 else -SPEED, 0.0, 3e-4 * (1 if k % 2 else -1), m,
                       now_s=0.01 * k)
    learner.step(10.0)
    applied = applied_torque(c, 20.0, SPEED, 0.0)
    assert applied > 1e-4
    learner.freeze()
    assert learner.update('elevation', 20.0, SPEED, 0.0, 1e-3, m, now_s=11.0) == 'frozen'
    learner.step(20.0)
    assert applied_torque(c, 20.0, SPEED, 0.0) == applied
    snap = learner.snapshot()
    learner.freeze(False)
    learner.reset()
    assert c.lookups['elevation'] is None and c.stats('elevation').samples() == 0
    assert applied_torque(snap, 20.0, SPEED, 0.0) == applied


# ------------------------------------------------------------------------------------------------ identity, settings
def test_model_identity_follows_the_parameters_not_their_spelling():
    a = model_identity({'elevation': BASE, 'azimuth': BASE})
    assert a == model_identity({'elevation': BASE.to_mapping(), 'azimuth': dict(reversed(BASE.to_mapping().items()))})
    assert a != model_identity({'azimuth': BASE, 'elevation': BASE})                    # joint order matters
    assert a != model_identity({'elevation': BASE, 'azimuth': BASE.replace(scale_positive=1.01)})


def test_settings_are_validated():
    with pytest.raises(ConfigError, match='temperature_max_c'):
        CorrectionSettings(temperature_max_c=123.0).validate()
    with pytest.raises(ConfigError, match='prior_samples'):
        CorrectionSettings(prior_samples=0.0).validate()
    with pytest.raises(ConfigError, match='max_speed_rad_s'):
        CorrectionSettings(max_speed_rad_s=0.001).validate()
    with pytest.raises(ConfigError, match='max_rate_nm_per_min'):
        Learner(Correction(CorrectionSettings(), IDENT), LearningSettings(max_rate_nm_per_min=0.0))


def test_importing_the_correction_loads_no_yaml_rclpy_or_io_layer():
    code = ('import sys, gimbal_friction.feedforward.correction\n'
            'bad = [m for m in sys.modules if m.split(".")[0] in ("yaml", "rclpy", "mcap", "rosbags") '
            'or m.startswith(("gimbal_friction.nodes", "gimbal_friction.recording", "gimbal_friction.sim"))]\n'
            'assert not bad, bad\nprint("pure")')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert 'pure' in out.stdout
