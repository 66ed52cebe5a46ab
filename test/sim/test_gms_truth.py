"""The generalized Maxwell-slip truth (Al-Bender, Lampaert & Swevers 2005): published hysteresis properties, its
difference from LuGre, stable closed-loop integration, and the generator drawing both families."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.engine import Plant, Run, simulate
from gimbal_friction.sim.gms import gms_step_AlBender_2005, gms_virgin_curve
from gimbal_friction.sim.lugre import lugre_force_1995, lugre_z_step
from gimbal_friction.sim.profiles import make_profile

K = np.array([200.0, 80.0, 30.0, 10.0])     # N*m/rad
W = np.array([0.4, 0.3, 0.2, 0.1])          # -
S = 2e-3                                     # N*m, constant level (pre-sliding: slow motion)
H = 1e-3                                     # s


def _drive(path_rad, force=None, slipping=None):
    """Element forces along a displacement path (piecewise-constant velocity between samples)."""
    f = np.zeros(K.size) if force is None else force
    slip = np.zeros(K.size, dtype=bool) if slipping is None else slipping
    out = []
    for a, b in zip(path_rad[:-1], path_rad[1:], strict=True):
        f, slip = gms_step_AlBender_2005(f, slip, (b - a) / H, S, K, W, H)
        out.append(float(f.sum()))
    return np.array(out), f, slip


def _line(a, b, n=400):
    return np.linspace(a, b, n + 1)


def test_virgin_curve_from_rest_and_masing_reversal_branch():
    """Loading from rest follows the virgin curve; after a reversal at (x_r, F_r) the branch is
    F_r - 2 F_v((x_r - x) / 2) (Masing's rule)."""
    x_r = 12e-6
    up = _line(0.0, x_r)
    f_up, f, slip = _drive(up)
    np.testing.assert_allclose(f_up, gms_virgin_curve(up[1:], K, W, S), rtol=1e-9, atol=1e-12)
    down = _line(x_r, -x_r)
    f_down, _, _ = _drive(down, f, slip)
    masing = f_up[-1] - 2.0 * gms_virgin_curve((x_r - down[1:]) / 2.0, K, W, S)
    np.testing.assert_allclose(f_down, masing, rtol=1e-9, atol=1e-12)
    # the branch is not the virgin curve shifted: a hysteresis loop of non-zero area
    assert abs(f_down[len(f_down) // 2] - gms_virgin_curve(0.0, K, W, S)) > 0.1 * S


def test_return_point_memory_after_a_minor_loop():
    """A minor loop closed inside a major branch returns the force to the branch: continuing the motion gives the
    same forces as if the minor loop had never happened (non-local memory)."""
    x_a, x_b, x_c = 15e-6, -15e-6, -5e-6
    _, f, slip = _drive(_line(0.0, x_a))
    # major branch from x_a straight down to x_b
    direct, _, _ = _drive(_line(x_a, x_b, 600), f.copy(), slip.copy())
    # same branch down to x_c, a minor loop x_c -> x_c + 6 urad -> x_c, then on to x_b
    _, f1, s1 = _drive(_line(x_a, x_c, 400), f.copy(), slip.copy())
    _, f2, s2 = _drive(_line(x_c, x_c + 12e-6, 240), f1, s1)
    _, f3, s3 = _drive(_line(x_c + 12e-6, x_c, 240), f2, s2)
    assert float(f3.sum()) == pytest.approx(float(f1.sum()), rel=1e-9)     # closed at the point it left
    after, _, _ = _drive(_line(x_c, x_b, 200), f3, s3)
    np.testing.assert_allclose(after, direct[400:], rtol=1e-9, atol=1e-12)
    # the minor loop is a loop: at its middle the force differs going up and coming down
    minor_up, _, _ = _drive(_line(x_c, x_c + 12e-6, 240), f1.copy(), s1.copy())
    minor_down, _, _ = _drive(_line(x_c + 12e-6, x_c, 240), f2.copy(), s2.copy())
    assert abs(minor_up[119] - minor_down[119]) > 0.05 * S


def test_differs_from_lugre_on_the_same_reversal():
    """Same breakaway level and the same initial stiffness: after a reversal LuGre's single bristle and the GMS
    elements give different forces (the GMS branch is piecewise linear and saturates element by element)."""
    sigma0 = float(K.sum())
    path = np.concatenate([_line(0.0, 20e-6), _line(20e-6, -20e-6, 800)[1:]])
    f_gms, _, _ = _drive(path)
    z, f_lugre = 0.0, []
    for a, b in zip(path[:-1], path[1:], strict=True):
        v = (b - a) / H
        z_new = lugre_z_step(z, v, S, sigma0, H)
        f_lugre.append(float(lugre_force_1995(z_new, 0.0, v, sigma0, 0.0)))
        z = z_new
    diff = np.abs(f_gms - np.array(f_lugre))
    assert np.max(diff) > 0.1 * S
    # both end at the same sliding level
    assert f_gms[-1] == pytest.approx(-S, rel=1e-6) and f_lugre[-1] == pytest.approx(-S, rel=0.02)


def test_slip_law_attraction_settles_at_the_stribeck_level_and_drag_is_its_limit():
    v, s_level = 0.01, np.array(1.5e-3)
    for c in (0.0, 0.5, 5.0):
        f, slip = np.zeros(K.size), np.zeros(K.size, dtype=bool)
        for _ in range(3000):
            f, slip = gms_step_AlBender_2005(f, slip, v, s_level, K, W, H, c)
        assert slip.all() and float(f.sum()) == pytest.approx(1.5e-3, rel=1e-6)
        assert np.all(np.abs(f) <= W * s_level * (1 + 1e-12))
    # a slipping element sticks again when the velocity reverses: its force then moves by k v h
    f2, slip2 = gms_step_AlBender_2005(f, slip, -1e-4, s_level, K, W, H, 5.0)
    assert not slip2.any()
    np.testing.assert_allclose(f2, f - K * 1e-4 * H)


def test_gms_truth_in_the_closed_loop_is_stable_and_tracks():
    cfg = SimConfig(presliding_model='gms', tracking_duration_s=4.0)
    lugre = SimConfig(tracking_duration_s=4.0)
    axis = AxisParams()
    res = {}
    for name, c in (('gms', cfg), ('lugre', lugre)):
        prof = make_profile(c, 'tracking')
        res[name] = simulate(c, axis, prof, [Run('none', -40.0), Run('ideal', -40.0)])
    for name, r in res.items():
        assert np.all(np.isfinite(r.traces.los_rate_rad_s)), name
        # bounded friction: never beyond the breakaway level of the truth (plus the pre-sliding damping)
        assert np.max(np.abs(r.traces.friction_nm)) < 0.02, name
    err = {n: float(np.sqrt(np.mean((r.traces.los_rate_rad_s[1000:, 0] - r.profile.target_rate_rad_s[1000:]) ** 2)))
           for n, r in res.items()}
    # another pre-sliding truth: the friction differs around the reversals (same static curve in sliding)
    f_g, f_l = res['gms'].traces.friction_nm[:, 0], res['lugre'].traces.friction_nm[:, 0]
    assert np.max(np.abs(f_g - f_l)) > 0.1 * np.max(np.abs(f_l))
    assert err['gms'] < 0.01                                         # rad/s: it tracks


def test_a_gms_truth_too_stiff_for_the_plant_step_is_refused():
    cfg = SimConfig(presliding_model='gms', gms_stiffness_nm_per_rad=(2e5, 1e3), gms_weights=(0.5, 0.5))
    with pytest.raises(ConfigError) as info:
        Plant(cfg, AxisParams(), np.zeros(1), np.zeros(1))
    assert info.value.parameter == 'gms_stiffness_nm_per_rad'


@pytest.mark.parametrize(('values', 'parameter'), [
    ({'presliding_model': 'dahl'}, 'presliding_model'),
    ({'gms_weights': (0.5, 0.5)}, 'gms_weights'),
    ({'gms_stiffness_nm_per_rad': (1.0, -1.0), 'gms_weights': (0.5, 0.5)}, 'gms_stiffness_nm_per_rad'),
    ({'gms_attraction_nm_per_s': -1.0}, 'gms_attraction_nm_per_s'),
])
def test_bad_gms_parameters_are_refused(values, parameter):
    with pytest.raises(ConfigError) as info:
        SimConfig.from_mapping(values)
    assert info.value.parameter == parameter


def test_the_generator_draws_both_families_and_the_unbalance_at_every_plateau():
    from gimbal_friction.sim.truth import TruthFriction
    from gimbal_friction.sim.truths import draw_truth
    truths = [draw_truth(seed) for seed in range(24)]
    families = [t.truth['presliding_model'] for t in truths]
    assert 'gms' in families and 'lugre' in families
    unbalanced = [t for t in truths if 'unbalance at every plateau' in t.kinds]
    assert 0 < len(unbalanced) < len(truths)
    for t in unbalanced:
        assert 0.5e-3 <= abs(t.truth['disturbance_torque_nm']) <= 3e-3
        assert 0.5e-3 <= t.truth['unbalance_torque_nm'] <= 3e-3
        assert 'unbalance at every plateau' in t.describe()
    for t in truths:
        cfg = t.config(SimConfig())
        assert f'pre-sliding {t.truth["presliding_model"]}' in t.describe()
        if cfg.presliding_model != 'gms':
            continue
        assert 3 <= len(cfg.gms_stiffness_nm_per_rad) <= 6
        Plant(cfg, AxisParams(), np.zeros(1), np.zeros(1))           # stable at the sim's step (else refused)
        truth = TruthFriction(cfg)
        s20 = float(truth.stribeck_level_nm(truth.terms(np.array([20.0])), np.zeros(1))[0])
        distances = truth.gms_weights * s20 / truth.gms_stiffness
        assert np.all(distances >= 5e-6 / 3.0 * 0.99) and np.all(distances <= 150e-6 * 1.01)
    assert draw_truth(5).truth == draw_truth(5).truth                 # seeded: the same everywhere
