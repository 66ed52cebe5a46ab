"""The pre-sliding (Dahl) feedforward term: its state, the identification of its distance from friction samples
through reversals, and the guard that keeps it off where it does not help."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.feedforward.presliding import (
    PreslidingSettings,
    PreslidingTerm,
    ReversalRun,
    dahl_step,
    dahl_step_scalar,
    presliding_torque_nm,
)

DT = 1e-3
LEVEL = 2e-3     # N*m
EVEN = 1e-4      # N*m


def _motion(seconds: float = 20.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A tracking-like motion: +-0.035 rad/s with constant-acceleration reversals of 0.2 s, and velocity noise."""
    t = np.arange(0.0, seconds, DT)
    phase = np.mod(t, 2.0)
    ramp = np.clip((np.abs(phase - 1.0) - 0.4) / 0.1, -1.0, 1.0)   # +1 .. -1 with 0.2 s reversals
    v = 0.035 * ramp + np.random.default_rng(seed).normal(0.0, 2e-4, t.size)
    return t, v


def _run(friction_of, seconds: float = 20.0, temperature: float = -40.0, noise_nm: float = 1e-4, seed: int = 0,
         every: int = 2) -> ReversalRun:
    t, v = _motion(seconds, seed)
    f = friction_of(t, v) + np.random.default_rng(seed + 1).normal(0.0, noise_nm, t.size)
    f[np.arange(t.size) % every != 0] = np.nan      # the estimator's samples: not every tick
    return ReversalRun(t, v, np.full(t.size, temperature), np.full(t.size, LEVEL), np.full(t.size, EVEN), f)


def _dahl_friction(distance: float):
    def friction(t: np.ndarray, v: np.ndarray) -> np.ndarray:
        s = np.empty(t.size)
        x = math.tanh(v[0] / 0.002)
        for k in range(t.size):
            x = dahl_step_scalar(x, float(v[k]), DT if k else 0.0, distance)
            s[k] = x
        return s * LEVEL + EVEN
    return friction


def test_the_state_update_is_exact_and_the_same_on_floats_and_arrays():
    s_arr = dahl_step(np.array([-1.0, 0.3, 1.0]), np.array([1e-3, -2e-3, 0.0]), 1e-3, 1e-5)
    s_flt = [dahl_step_scalar(x, u, 1e-3, 1e-5) for x, u in ((-1.0, 1e-3), (0.3, -2e-3), (1.0, 0.0))]
    assert s_arr.tolist() == pytest.approx(s_flt, abs=1e-15)
    # after a displacement x from -1: 1 - 2 exp(-x / delta), whatever the steps
    x = -1.0
    for _ in range(37):
        x = dahl_step_scalar(x, 0.01, 1e-4, 2e-5)
    assert x == pytest.approx(1.0 - 2.0 * math.exp(-37e-6 / 2e-5), rel=1e-12)
    assert s_flt[2] == 1.0                                   # at rest the state is kept
    assert presliding_torque_nm(0.5, 2e-3, 1e-4, 1e-3).tolist() == pytest.approx(1e-3)   # clamped


@pytest.mark.parametrize('distance', [4e-6, 2e-5])
def test_identification_on_synthetic_reversals_recovers_the_distance_and_the_guard_applies_it(distance):
    term = PreslidingTerm(PreslidingSettings(), ('elevation',))
    counts = term.learn('elevation', [_run(_dahl_friction(distance))])
    assert counts['reversals'] >= 15
    (v,) = term.verdicts('elevation')
    assert v['distance_rad'] == pytest.approx(distance, rel=0.1)
    assert v['applied'], v['held_back']
    assert float(term.distance_rad('elevation', -40.0)) == pytest.approx(distance, rel=0.1)
    assert math.isnan(float(term.distance_rad('elevation', 20.0)))     # no data there: off
    assert v['rms_dynamic_nm'] < 0.5 * v['rms_static_nm']


def test_the_guard_holds_the_term_back_where_the_friction_has_no_presliding():
    """Friction that switches with the velocity exactly as the static rule does (a truth without pre-sliding): the
    term is fitted but never applied; the feedforward stays the static one."""
    def static(t: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.tanh(v / 0.002) * LEVEL + EVEN
    term = PreslidingTerm(PreslidingSettings(), ('elevation',))
    term.learn('elevation', [_run(static, seconds=30.0)])
    (v,) = term.verdicts('elevation')
    assert v['reversals_scored'] >= PreslidingSettings().min_reversals
    assert not v['applied'] and v['held_back']
    assert not term.active
    assert math.isnan(float(term.distance_rad('elevation', -40.0)))


def test_the_guard_waits_for_enough_reversals():
    term = PreslidingTerm(PreslidingSettings(min_reversals=50), ('elevation',))
    term.learn('elevation', [_run(_dahl_friction(1e-5), seconds=10.0)])
    (v,) = term.verdicts('elevation')
    assert not v['applied'] and 'reversals' in v['held_back']


def test_the_delivery_delay_is_part_of_what_is_judged():
    """A friction one tick behind the motion is fitted with that tick of delay and not without."""
    d = 1e-5

    def late(t: np.ndarray, v: np.ndarray) -> np.ndarray:
        f = _dahl_friction(d)(t, v)
        return np.concatenate([f[:1], f[:-1]])
    fits = {}
    for delay in (0.0, DT):
        term = PreslidingTerm(PreslidingSettings(delivery_delay_s=delay), ('elevation',))
        term.learn('elevation', [_run(late)])
        (fits[delay],) = term.verdicts('elevation')
    assert fits[DT]['rms_dynamic_nm'] < fits[0.0]['rms_dynamic_nm']


def test_settings_are_checked():
    with pytest.raises(ConfigError, match='distance_max_rad'):
        PreslidingSettings(distance_min_rad=1e-4, distance_max_rad=1e-5).validate()
    with pytest.raises(ConfigError, match='joints'):
        PreslidingTerm(PreslidingSettings(), ())
    with pytest.raises(ConfigError, match='joint'):
        PreslidingTerm(PreslidingSettings(), ('elevation',)).learn('azimuth', [])
