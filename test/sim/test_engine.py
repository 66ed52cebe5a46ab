"""Closed-loop engine against closed-form cases; batch = single runs; seeded determinism; estimator traces."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.compensation import constant_coulomb, suite_feedforward
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.engine import Plant, Run, simulate
from gimbal_friction.sim.profiles import make_profile

AXIS = AxisParams()
QUIET = {'gyro_noise_rad_s': 0.0, 'gyro_bias_rad_s': 0.0, 'resolver_noise_rad': 0.0,
         'resolver_velocity_noise_rad_s': 0.0, 'track_noise_rad': 0.0, 'temperature_noise_c': 0.0,
         'current_noise_a': 0.0}


def test_coast_down_under_constant_friction():
    """No current, constant Coulomb friction F: w(t) = w0 - F t / J, stop at J w0 / F after J w0^2 / (2F)."""
    cfg = SimConfig(ripple_amplitudes=(0.0, 0.0), asymmetry_enabled=False, breakaway_ratio=1.0)
    plant = Plant(cfg, AXIS, np.zeros(1), np.array([0.5]))
    terms = plant.truth.terms(np.array([20.0]))       # +20 degC, 4.8 rpm: Palmgren's lower branch, F independent of w
    friction = float(plant.truth.static_torque_nm(20.0, 0.5))
    plant.z = np.array([friction / cfg.sigma0_nm_per_rad])   # sliding already
    J = AXIS.inertia_kg_m2 * cfg.inertia_truth_ratio
    t_stop, angle_stop = J * 0.5 / friction, J * 0.25 / (2.0 * friction)
    T = cfg.controller_period_s
    omega, t = [], []
    for k in range(int(1.5 * t_stop / T)):
        omega.append(float(plant.omega[0]))
        t.append(k * T)
        plant.advance(np.zeros(1), np.zeros(cfg.plant_substeps), terms, 1.0)
    omega_arr, t_arr = np.array(omega), np.array(t)
    moving = t_arr < 0.95 * t_stop
    np.testing.assert_allclose(omega_arr[moving], 0.5 - friction * t_arr[moving] / J, rtol=0, atol=1e-9)
    first_stop = t_arr[np.argmax(omega_arr <= 0.0)]
    assert abs(first_stop - t_stop) <= T
    # it stays stopped: pre-sliding wobble of the order of F / sigma0 only
    assert float(plant.theta[0]) == pytest.approx(angle_stop, abs=3.0 * friction / cfg.sigma0_nm_per_rad)
    assert abs(float(plant.omega[0])) < 1e-3


def test_p_rate_loop_steady_state_error_is_the_closed_form():
    """Rate P loop only (no integral, no track loop), frictionless, constant disturbance tau: w = tau / (J K_p)."""
    tau = 1e-3
    cfg = SimConfig(**QUIET, rate_integral_hz=0.0, track_bandwidth_hz=0.0, disturbance_torque_nm=tau,
                    ripple_amplitudes=(0.0, 0.0))
    prof = make_profile(cfg, 'pointing', 1.0)
    res = simulate(cfg, AXIS, prof, [Run('ideal', 20.0)])
    expected = tau / (AXIS.inertia_kg_m2 * cfg.rate_kp_per_s)
    assert float(res.traces.los_rate_rad_s[-1, 0]) == pytest.approx(expected, rel=1e-9)
    # the ideal case cancels the friction and pays for it in current: K_T i = -tau at steady state
    assert float(res.traces.current_a[-1, 0]) * AXIS.torque_constant_nm_per_a == pytest.approx(
        -tau + float(res.traces.friction_nm[-1, 0]), rel=1e-6)


@pytest.mark.slow
def test_pi_rate_loop_with_track_loop_has_no_steady_state_error():
    cfg = SimConfig(**QUIET, disturbance_torque_nm=2e-3)
    prof = make_profile(cfg, 'pointing', 4.0)
    res = simulate(cfg, AXIS, prof, [Run('ideal', -40.0)])
    tr = res.traces
    assert np.max(np.abs(tr.los_rate_rad_s[:500, 0])) > 1e-3       # the disturbance did move the LOS first
    assert abs(float(tr.los_rate_rad_s[-1, 0])) < 1e-9
    assert abs(float(tr.los_angle_rad[-1, 0])) < 1e-9


def _traces_equal(a, b, index):
    for name in a._fields:
        np.testing.assert_array_equal(getattr(a, name)[:, index], getattr(b, name)[:, 0], err_msg=name)


@pytest.mark.slow
def test_a_batch_is_its_runs_one_by_one():
    cfg = SimConfig(environment_ramp_c_per_s=0.5, initial_bearing_offset_c=3.0)   # temperatures move too
    prof = make_profile(cfg, 'pointing', 0.6)
    runs = [Run('none', -40.0), Run('constant', 20.0, seed=3), Run('ideal', 0.0), Run('feedforward', 60.0)]

    def comps():
        return {'constant': constant_coulomb(AXIS), 'feedforward': suite_feedforward(AXIS)}

    batch = simulate(cfg, AXIS, prof, runs, comps())
    for i, run in enumerate(runs):
        single = simulate(cfg, AXIS, prof, [run], comps())
        _traces_equal(batch.traces, single.traces, i)


@pytest.mark.slow
def test_seeded_noise_is_deterministic_and_the_seed_matters():
    cfg = SimConfig()
    prof = make_profile(cfg, 'tracking', 0.5)
    a = simulate(cfg, AXIS, prof, [Run('none', -20.0)])
    b = simulate(cfg, AXIS, prof, [Run('none', -20.0)])
    c = simulate(cfg.replace(seed=1), AXIS, prof, [Run('none', -20.0)])
    d = simulate(cfg, AXIS, prof, [Run('none', -20.0, seed=1)])
    for name in a.traces._fields:
        np.testing.assert_array_equal(getattr(a.traces, name), getattr(b.traces, name))
    assert not np.array_equal(a.traces.gyro_rate_rad_s, c.traces.gyro_rate_rad_s)
    assert not np.array_equal(a.traces.gyro_rate_rad_s, d.traces.gyro_rate_rad_s)


def test_friction_acts_on_the_rate_relative_to_the_base():
    """Pointing under base motion: without friction (ideal) the base motion does not reach the LOS; with
    friction it does, and the resolver measures the relative angle."""
    cfg = SimConfig(**QUIET)
    prof = make_profile(cfg, 'pointing', 2.0)
    res = simulate(cfg, AXIS, prof, [Run('ideal', -40.0), Run('none', -40.0)])
    tr = res.traces
    assert np.max(np.abs(tr.los_angle_rad[:, 0])) < 1e-9
    assert np.max(np.abs(tr.los_angle_rad[:, 1])) > 1e-4
    np.testing.assert_allclose(tr.joint_position_rad[:, 1], tr.los_angle_rad[:, 1] - prof.base_angle_rad, atol=1e-15)


def test_feedforward_latency_delays_the_torque_by_whole_ticks():
    cfg = SimConfig(feedforward_latency_s=3e-3)
    prof = make_profile(cfg, 'tracking', 0.3)
    calls = []

    def hook(inputs):
        calls.append(inputs.time_s)
        return np.full(inputs.temperature_c.shape, inputs.time_s)   # torque = time it was computed at

    from gimbal_friction.sim.compensation import Compensator
    res = simulate(cfg, AXIS, prof, [Run('x', 20.0), Run('y', 20.0)],
                   {'x': Compensator(hook, delayed=True), 'y': Compensator(hook, delayed=False)})
    ff = res.traces.feedforward_nm
    t = prof.time_s
    np.testing.assert_allclose(ff[3:, 0], t[:-3])
    assert np.all(ff[:3, 0] == 0.0)
    np.testing.assert_allclose(ff[:, 1], t)


def test_estimator_trace_as_the_suites_input_streams():
    cfg = SimConfig()
    prof = make_profile(cfg, 'tracking', 1.0)
    res = simulate(cfg, AXIS, prof, [Run('none', -40.0), Run('none', 20.0)])
    trace = res.estimator_trace(1, start_ns=5 * NS_PER_S)
    arrays = trace.chamber_arrays('elevation', every=10)
    assert len(arrays.joint_states) == 100 and len(arrays.motor_current) == 100
    assert arrays.joint_states.stamp_ns[0] == 5 * NS_PER_S and np.all(np.diff(arrays.joint_states.stamp_ns) == 10**7)
    np.testing.assert_array_equal(arrays.joint_states.position['elevation'], res.traces.joint_position_rad[::10, 1])
    np.testing.assert_array_equal(arrays.motor_current.effort['elevation'], res.traces.current_measured_a[::10, 1])
    assert len(arrays.temperature.stamp_ns) == cfg.temperature_rate_hz * 1.0   # the sensor's own rate
    assert abs(float(np.mean(arrays.temperature.temperature_c)) - 20.0) < 0.2


def test_stepping_the_closed_loop_is_simulate():
    """A real-time adapter steps the loop tick by tick and publishes last(); same numbers as simulate()."""
    from gimbal_friction.common.errors import ConfigError
    from gimbal_friction.sim.engine import ClosedLoop

    cfg = SimConfig()
    prof = make_profile(cfg, 'pointing', 0.2)
    runs = [Run('none', -40.0), Run('ideal', 20.0)]
    whole = simulate(cfg, AXIS, prof, runs)
    loop = ClosedLoop(cfg, AXIS, prof, runs)
    for k in range(prof.time_s.shape[0]):
        loop.step()
        np.testing.assert_array_equal(loop.last().joint_position_rad, whole.traces.joint_position_rad[k])
        if k == 99:
            half = loop.result()
            assert half.traces.los_rate_rad_s.shape == (100, 2) and half.profile.time_s.shape == (100,)
    assert loop.done
    with pytest.raises(ConfigError):
        loop.step()
    for name in whole.traces._fields:
        np.testing.assert_array_equal(getattr(loop.result().traces, name), getattr(whole.traces, name))
