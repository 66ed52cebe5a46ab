"""The gimbal_sim node's logic (RealtimeRun) against the offline loop, and the feedforward rules in the loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.compensation import JOINT, suite_feedforward
from gimbal_friction.sim.config import RealtimeSettings, SimConfig
from gimbal_friction.sim.engine import Plant, Run, simulate
from gimbal_friction.sim.metrics import batch_metrics
from gimbal_friction.sim.profiles import make_profile
from gimbal_friction.sim.realtime import RealtimeRun

AXIS = AxisParams()


def _node_loop(cfg: SimConfig, settings: RealtimeSettings, ff: Feedforward, delay_ticks: int) -> RealtimeRun:
    """What gimbal_sim + friction_feedforward do: each tick's joint state goes to the node's Feedforward object (per
    message, floats), its torque comes back ``delay_ticks`` ticks later with the joint state's stamp."""
    run = RealtimeRun(cfg, AXIS, settings, epoch_ns=5 * NS_PER_S)
    queue: list[tuple[int, float, int]] = []
    while not run.done:
        k = run.loop.k
        for item in [q for q in queue if q[0] <= k]:
            assert run.on_feedforward(item[1], item[2], wall_s=k * 1e-3)
            queue.remove(item)
        out = run.step(wall_s=k * 1e-3)
        if out.temperature_c is not None:
            ff.update_temperature(out.temperature_c, out.stamp_ns / NS_PER_S)
        tau = ff.torque_nm(JOINT, out.joint_velocity_rad_s, out.stamp_ns / NS_PER_S)
        queue.append((k + delay_ticks, tau, out.stamp_ns))
    return run


@pytest.mark.slow
def test_the_node_loop_is_the_offline_loop_with_the_same_latency():
    """Stepping tick by tick with the node's per-message Feedforward (floats) and the torque coming back one tick
    later gives the offline study's run (arrays, 1 ms latency): same traces to rounding, same metrics."""
    cfg = SimConfig(tracking_duration_s=2.0)
    settings = RealtimeSettings(profile='tracking', environment_temperature_c=-40.0)
    run = _node_loop(cfg, settings, Feedforward({JOINT: AXIS}, FeedforwardSettings()), delay_ticks=1)
    live = run.result()
    offline = simulate(cfg, AXIS, make_profile(cfg, 'tracking'), [Run('feedforward', -40.0)],
                       {'feedforward': suite_feedforward(AXIS)})
    np.testing.assert_allclose(live.traces.feedforward_nm, offline.traces.feedforward_nm, rtol=0, atol=1e-12)
    np.testing.assert_allclose(live.traces.los_rate_rad_s, offline.traces.los_rate_rad_s, rtol=0, atol=1e-9)
    assert batch_metrics(live)[0].rate_error_rms_rad_s == pytest.approx(
        batch_metrics(offline)[0].rate_error_rms_rad_s, rel=1e-6)
    summary = run.latency_summary()
    assert summary['feedforward_age_p50_ticks'] == 1.0 and summary['feedforward_latency_p50_s'] == pytest.approx(1e-3)
    assert run.received == run.ticks - 1 and run.stale == 0


def test_a_feedforward_older_than_the_timeout_is_not_applied():
    cfg = SimConfig(tracking_duration_s=0.3, feedforward_timeout_s=0.005)
    settings = RealtimeSettings(profile='tracking', environment_temperature_c=20.0)
    slow = _node_loop(cfg, settings, Feedforward({JOINT: AXIS}, FeedforwardSettings()), delay_ticks=8)
    assert np.all(slow.result().traces.feedforward_nm == 0.0) and slow.timed_out > 0
    assert np.all(slow.feedforward_age[9:] >= 8)
    # offline: a latency beyond the timeout applies nothing either
    off = simulate(cfg.replace(feedforward_latency_s=0.008), AXIS, make_profile(cfg, 'tracking'),
                   [Run('feedforward', 20.0)], {'feedforward': suite_feedforward(AXIS)})
    assert np.all(off.traces.feedforward_nm == 0.0) and np.any(off.traces.feedforward_computed_nm != 0.0)


def test_feedforward_messages_that_are_no_tick_of_the_run_are_ignored():
    run = RealtimeRun(SimConfig(pointing_duration_s=0.01), AXIS, RealtimeSettings(profile='pointing'), epoch_ns=10**9)
    out = run.step(wall_s=0.0)
    assert not run.on_feedforward(0.001, out.stamp_ns + 1, 0.0)          # between ticks
    assert not run.on_feedforward(0.001, out.stamp_ns + 10**6, 0.0)      # a tick not simulated yet
    assert not run.on_feedforward(math.nan, out.stamp_ns, 0.0)
    assert run.on_feedforward(0.001, out.stamp_ns, 0.0)
    assert not run.on_feedforward(0.002, out.stamp_ns, 0.0) and run.stale == 1   # not newer than the one in use
    assert run.foreign == 3


def test_without_feedforward_the_run_is_case_none_and_ends():
    cfg = SimConfig(pointing_duration_s=0.05)
    run = RealtimeRun(cfg, AXIS, RealtimeSettings(profile='pointing', use_feedforward=False,
                                                  environment_temperature_c=-20.0), epoch_ns=0)
    while not run.done:
        run.step(0.0)
    offline = simulate(cfg, AXIS, make_profile(cfg, 'pointing'), [Run('none', -20.0)])
    np.testing.assert_array_equal(run.result().traces.los_angle_rad, offline.traces.los_angle_rad)
    with pytest.raises(ConfigError):
        run.step(0.0)
    assert run.due_wall_s(10.0, 50) == pytest.approx(10.05)


def test_stale_temperature_in_the_loop_follows_the_nodes_rules():
    """The sensor falls silent at 0.3 s; with a 0.2 s timeout the feedforward switches to the fallback (+20 degC)
    exactly as the node's Feedforward object does with the same messages."""
    cfg = SimConfig(tracking_duration_s=1.0, temperature_stop_s=0.3)
    s = FeedforwardSettings(temperature_timeout_s=0.2)
    res = simulate(cfg, AXIS, make_profile(cfg, 'tracking'), [Run('ff', -40.0)], {'ff': suite_feedforward(AXIS, s)})
    node = Feedforward({JOINT: AXIS}, s)
    tr = res.traces
    expected = []
    for k, t in enumerate(res.profile.time_s):
        if res.temperature_sampled[k]:
            node.update_temperature(float(tr.temperature_c[k, 0]), float(t))
        expected.append(node.torque_nm(JOINT, float(tr.joint_velocity_rad_s[k, 0]), float(t)))
    np.testing.assert_allclose(tr.feedforward_computed_nm[:, 0], expected, rtol=0, atol=1e-12)
    assert not res.temperature_sampled[300:].any() and res.temperature_sampled[200]
    assert node.temperature(0.35)[1] == 0 and node.temperature(0.45) == (20.0, 2)   # last sample at 0.2 s
    ff = np.abs(tr.feedforward_computed_nm[:, 0])
    assert ff[350] > 2.5e-3 and ff[600] == pytest.approx(1.046e-3, abs=2e-6)       # -40 degC, then the fallback


def test_coast_down_with_a_heavier_true_plant():
    """inertia_truth_ratio scales the plant's J only: the coast-down under constant friction takes twice as long."""
    cfg = SimConfig(ripple_amplitudes=(0.0, 0.0), asymmetry_enabled=False, breakaway_ratio=1.0,
                    inertia_truth_ratio=2.0)
    plant = Plant(cfg, AXIS, np.zeros(1), np.array([0.5]))
    terms = plant.truth.terms(np.array([20.0]))
    friction = float(plant.truth.static_torque_nm(20.0, 0.5))
    plant.z = np.array([friction / cfg.sigma0_nm_per_rad])
    t_stop = 2.0 * AXIS.inertia_kg_m2 * 0.5 / friction
    steps = 0
    while plant.omega[0] > 0.0:
        plant.advance(np.zeros(1), np.zeros(cfg.plant_substeps), terms, 1.0)
        steps += 1
    assert abs(steps * cfg.controller_period_s - t_stop) <= cfg.controller_period_s
