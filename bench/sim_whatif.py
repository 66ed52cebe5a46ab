"""Where the feedforward helps and where it hurts: the case-(c) feedforward under one change at a time.

Not a test: prints, asserts nothing. For each variant, each profile and the plateaus -40, -20 and +20 degC, the
LOS rate error RMS of the feedforward relative to no compensation (a) in the same batch (same noise), and its
reversal peak relative to (a). Two wirings are the starting points: ``defaults`` (the measured joint velocity,
v_th 0.005 rad/s) and ``recommended`` (the reference joint velocity, v_th 0.002 rad/s); every other variant
changes one thing of the recommended wiring: the transport latency (0, 5, 10 ms), the smooth-sign width, a
breakaway term (the truth's own Stribeck curve added to the rule, to see whether modelling breakaway would pay),
the gyro's inertial rate instead of the joint's rate (a wiring mistake), a temperature sensor 20 degC off, a
temperature that goes stale (the node's fallback, +20 degC), the truth without lubricant shift, twice the
shift, without position ripple, without breakaway.

Usage (repository root, project venv; about a minute)::

    .venv/bin/python bench/sim_whatif.py [--duration-scale 1.0] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim import SimConfig, batch_metrics, make_profile, simulate
from gimbal_friction.sim.compensation import Compensator, ControllerInputs, suite_feedforward
from gimbal_friction.sim.engine import Run

TEMPERATURES = (-40.0, -20.0, 20.0)
DURATIONS = {'tracking': 8.0, 'scan': 4.0, 'pointing': 4.0}
RECOMMENDED = FeedforwardSettings(velocity_threshold_rad_s=0.002)


def inertial(comp: Compensator) -> Compensator:
    """``comp`` fed the gyro's inertial LOS rate in place of the velocity it should get (the wiring mistake)."""
    def torque(inputs: ControllerInputs) -> Any:
        return comp.torque(inputs._replace(joint_velocity_rad_s=inputs.gyro_rate_rad_s,
                                           reference_velocity_rad_s=inputs.gyro_rate_rad_s))
    return Compensator(torque, comp.delayed)


def breakaway(comp: Compensator, config: SimConfig) -> Compensator:
    """``comp`` times the truth's Stribeck factor 1 + (F_S/F_C − 1) exp(−(v/v_s)²) of the reference velocity."""
    beta, v_s = config.breakaway_ratio, config.stribeck_velocity_rad_s

    def torque(inputs: ControllerInputs) -> Any:
        v = inputs.reference_velocity_rad_s
        return np.asarray(comp.torque(inputs)) * (1.0 + (beta - 1.0) * np.exp(-(v / v_s) ** 2))
    return Compensator(torque, comp.delayed)


def variants(axis: AxisParams) -> list[tuple[str, SimConfig, Callable[[], Compensator]]]:
    base = SimConfig()

    def rec() -> Compensator:
        return suite_feedforward(axis, RECOMMENDED, velocity_source='reference')

    return [
        ('defaults (measured)', base, lambda: suite_feedforward(axis)),
        ('recommended', base, rec),
        ('latency 0', base.replace(feedforward_latency_s=0.0), rec),
        ('latency 5 ms', base.replace(feedforward_latency_s=5e-3), rec),
        ('latency 10 ms', base.replace(feedforward_latency_s=10e-3), rec),
        ('v_th 0.005 rad/s', base, lambda: suite_feedforward(axis, velocity_source='reference')),
        ('v_th 0.0005 rad/s', base, lambda: suite_feedforward(
            axis, FeedforwardSettings(velocity_threshold_rad_s=0.0005), velocity_source='reference')),
        ('+ breakaway term', base, lambda: breakaway(rec(), base)),
        ('gyro (inertial) rate', base, lambda: inertial(rec())),
        ('temperature +20 C off', base.replace(temperature_bias_c=20.0), rec),
        ('stale temperature', base.replace(temperature_stop_s=0.0), rec),
        ('no lubricant shift', base.replace(lubricant_walther_a_shift=0.0), rec),
        ('2x lubricant shift', base.replace(lubricant_walther_a_shift=0.03), rec),
        ('no ripple', base.replace(ripple_amplitudes=(0.0, 0.0)), rec),
        ('no breakaway', base.replace(breakaway_ratio=1.0), rec),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration-scale', type=float, default=1.0, help='scale of the profile durations')
    parser.add_argument('--json', action='store_true', help='print one JSON document')
    args = parser.parse_args(argv)
    axis = AxisParams()
    rows: list[dict[str, Any]] = []
    for name, cfg, make in variants(axis):
        for prof_name, dur in DURATIONS.items():
            prof = make_profile(cfg, prof_name, dur * args.duration_scale)
            runs = [Run(c, t) for c in ('none', 'c') for t in TEMPERATURES]
            res = simulate(cfg, axis, prof, runs, {'c': make()})
            met = dict(zip(runs, batch_metrics(res), strict=True))
            for t in TEMPERATURES:
                a, c = met[Run('none', t)], met[Run('c', t)]
                rows.append({'variant': name, 'profile': prof_name, 'temperature_c': t,
                             'rate_rms_none_rad_s': a.rate_error_rms_rad_s, 'rate_rms_c_rad_s': c.rate_error_rms_rad_s,
                             'reduction': 1.0 - c.rate_error_rms_rad_s / a.rate_error_rms_rad_s,
                             'reversal_ratio': c.reversal_error_peak_rad / a.reversal_error_peak_rad})
        sys.stderr.write(f'{name} done\n')
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print('rate-error RMS reduction of the feedforward vs none (reversal peak ratio c/a in brackets)')
    head = ''.join(f'{p + format(t, "+.0f"):>13s} ' for p in DURATIONS for t in TEMPERATURES)
    print(f'{"variant":24s}{head}')
    for name, _, _ in variants(axis):
        cells = [r for r in rows if r['variant'] == name]
        print(f'{name:24s}' + ''.join(f'{r["reduction"]:>+6.0%} ({r["reversal_ratio"]:.2f}) ' for r in cells))
    return 0


if __name__ == '__main__':
    sys.exit(main())
