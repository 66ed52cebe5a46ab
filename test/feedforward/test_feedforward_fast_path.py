"""The scalar call (:meth:`Feedforward.torque_at`, behind ``torque_nm`` and ``message``) writes the rule out in one
function: with or without a learned correction it gives the rule's own scalar evaluation (``rule(..., SCALAR)``) to
the last bit and the array rule (the replay, the export's reference) to the last bit or two, on random inputs with
the edges: temperatures at and beyond the table and the correction's bins, speeds at zero, below the slowest learned
speed, beyond the fastest octave and absurd, positions on and beyond the grid and NaN; the same lookups clipped; a
correction changed in place is followed."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from gimbal_friction.common.xp import ARRAY, SCALAR
from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity
from gimbal_friction.feedforward.correction.fit import Params
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams

AXES = {'elevation': AxisParams(direction_asymmetry_cold=0.131, direction_asymmetry_warm=-0.121),
        'azimuth': AxisParams(interference_mm=0.004, scale_negative=0.8)}
IDENT = model_identity(AXES)
PERIODS = np.radians([3.4, 1.1])


def correction(settings: CorrectionSettings, seed: int, scale_nm: float, positions: bool = True) -> Correction:
    """Random applied terms in every cell (``scale_nm`` large against the bound: some lookups clip), ripple and
    trend over -0.3..0.3 rad with ``positions``; azimuth gets nothing learned (the model's torque)."""
    rng = np.random.default_rng(seed)
    c = Correction(settings, IDENT)
    nt, ns = settings.n_temperature, settings.n_speed
    k = PERIODS.size if positions else 0
    p = Params(scale_nm * rng.normal(size=(2, nt, ns)), PERIODS[:k].copy(), 0.3 * rng.normal(size=(nt, k, 2)),
               scale_nm * rng.normal(size=(nt, 4)) * positions)
    c.set_applied('elevation', p, (-0.3, 0.3))
    return c


def inputs(seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(temperatures [°C], velocities [rad/s], positions [rad]): random, with the edges mixed in."""
    rng = np.random.default_rng(seed)
    s = CorrectionSettings()
    edges_t = [-60.0, -40.0, -39.999, 60.0, 60.001, 120.0, -0.0, 0.0, *s.edges_c(), s.centre_c(0), s.centre_c(3)]
    t = np.where(rng.random(n) < 0.3, rng.choice(edges_t, n), rng.uniform(-60.0, 120.0, n))
    t = np.repeat(t[: n // 4], 4)[:n]   # repeats (the cache) and changes
    vmin = s.min_speed_rad_s
    edges_v = [0.0, -0.0, 1e-9, -vmin, vmin, 0.5 * vmin, -vmin * 2 ** 0.5, vmin * 2 ** 11.5, 50.0, -1e3, 1e300,
               -1e300, 5e-324]
    v = np.where(rng.random(n) < 0.3, rng.choice(edges_v, n),
                 rng.choice([-1.0, 1.0], n) * np.exp(rng.uniform(np.log(1e-4), np.log(30.0), n)))
    edges_p = [math.nan, -0.3, 0.3, -0.3 - PERIODS[0], 0.3 + PERIODS[0], -5.0, 5.0, 0.0]
    p = np.where(rng.random(n) < 0.3, rng.choice(edges_p, n), rng.uniform(-0.5, 0.5, n))
    return t, v, p


def same_bits(a: float, b: float) -> bool:
    return np.float64(a).tobytes() == np.float64(b).tobytes()


CASES = [
    pytest.param(CorrectionSettings(guard_min_samples=0, guard_z=0.0), 3e-4, True, id='ripple+trend'),
    # (3e-3: lookups clip inside the travel; the trend no longer holds its edge value outside it)
    pytest.param(CorrectionSettings(guard_min_samples=0, guard_z=0.0), 3e-3, True, id='clipped'),
    pytest.param(CorrectionSettings(guard_min_samples=0, guard_z=0.0), 3e-4, False, id='speed-only'),
    pytest.param(CorrectionSettings(guard_min_samples=0, guard_z=0.0, speed_term=False), 3e-4, True, id='no-speed'),
    pytest.param(None, 0.0, False, id='model'),
]


@pytest.mark.parametrize(('settings', 'scale_nm', 'positions'), CASES)
def test_the_scalar_call_is_the_rule_to_the_last_bit(settings, scale_nm, positions):
    s = FeedforwardSettings(max_torque_nm=0.004)
    fast = Feedforward(AXES, s, None if settings is None else correction(settings, 1, scale_nm, positions))
    ref = Feedforward(AXES, s, None if settings is None else correction(settings, 1, scale_nm, positions))
    bag = Feedforward(AXES, s, None if settings is None else correction(settings, 1, scale_nm, positions))
    t, v, p = inputs(2)
    for joint in AXES:
        got = [fast.torque_at(joint, a, b, c) for a, b, c in zip(v.tolist(), t.tolist(), p.tolist(), strict=True)]
        with np.errstate(over='ignore', invalid='ignore'):
            want = [ref.rule(joint, a, b, SCALAR, position_rad=c) for a, b, c in
                    zip(v.tolist(), t.tolist(), p.tolist(), strict=True)]
            want_array = bag.rule(joint, v, t, ARRAY, position_rad=p)
        bad = [k for k, (a, b) in enumerate(zip(got, want, strict=True)) if not same_bits(a, b)]
        assert not bad, (joint, [(t[k], v[k], p[k], got[k], want[k]) for k in bad[:5]])
        np.testing.assert_allclose(got, want_array, rtol=1e-12, atol=1e-18)
        assert fast.counters.saturated.get(joint, 0) == sum(abs(x) >= s.max_torque_nm for x in got) > 0
    if settings is not None:   # the same lookups clipped (counted by the lookup the call reads)
        assert fast.correction.lookup_saturations == ref.correction.lookup_saturations   # type: ignore[union-attr]
        assert fast.correction.lookup_saturations == bag.correction.lookup_saturations   # type: ignore[union-attr]
        assert (fast.correction.lookup_saturations > 0) == (scale_nm > 1e-3)   # type: ignore[union-attr]


def test_non_finite_inputs_give_zero():
    ff = Feedforward(AXES, FeedforwardSettings(), correction(CASES[0].values[0], 1, 3e-4))
    for v, t in [(math.nan, 20.0), (math.inf, 20.0), (-math.inf, 20.0), (0.03, math.nan)]:
        assert ff.torque_at('elevation', v, t, 0.1) == 0.0


def test_a_correction_changed_in_place_or_swapped_is_followed():
    s = CorrectionSettings(guard_min_samples=0, guard_z=0.0)
    c = correction(s, 1, 3e-4)
    ff = Feedforward(AXES, FeedforwardSettings(), c)
    before = ff.torque_at('elevation', 0.03, 10.0, 0.1)
    c.set_applied('elevation', correction(s, 7, 3e-4).applied('elevation'), (-0.3, 0.3))   # as a Learner does
    after = ff.torque_at('elevation', 0.03, 10.0, 0.1)
    assert after != before and same_bits(after, ff.rule('elevation', 0.03, 10.0, SCALAR, position_rad=0.1))
    ff.set_correction(None)
    assert same_bits(ff.torque_at('elevation', 0.03, 10.0, 0.1), Feedforward(AXES, FeedforwardSettings()).torque_at(
        'elevation', 0.03, 10.0))


def test_the_scalar_call_with_a_learned_correction_is_one_function():
    """Once warm at a temperature, ``torque_nm`` with a learned correction (ripple and trend) calls no other Python
    function (the rule's functions, the lookup's and the freshness rule written out: each Python call costs
    ~0.05-0.1 µs on a ~1 µs path); ``message`` calls it once per joint."""
    ff = Feedforward(AXES, FeedforwardSettings(velocity_source='measured'), correction(CASES[0].values[0], 1, 3e-4))
    ff.update_temperature(-35.0, 0.0)
    ff.torque_nm('elevation', 0.03, 0.001, 0.1)
    ff.message(['elevation', 'azimuth'], [0.03, -0.02], 0.001, [0.1, 0.2])
    calls: list[str] = []

    def profile(frame, event, arg):
        if event == 'call':
            calls.append(frame.f_code.co_name)

    sys.setprofile(profile)
    try:
        for k in range(10):
            ff.torque_nm('elevation', 0.01 + 0.01 * k, 0.001 * k, 0.02 * k)
        ff.message(['elevation', 'azimuth'], [0.03, -0.02], 0.002, [0.1, 0.2])
    finally:
        sys.setprofile(None)
    assert calls == ['torque_nm'] * 10 + ['message', 'torque_nm', 'torque_nm']
