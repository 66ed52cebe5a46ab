"""Where the feedforward helps and where it hurts: the case-(c) feedforward under one change at a time.

Not a test: prints, asserts nothing. For each variant, each profile and the plateaus -40, -20 and +20 degC, the
LOS rate error RMS of the feedforward relative to no compensation (a) in the same batch (same noise), and its
reversal peak relative to (a). Variants: the defaults; no transport latency; 3 ticks of latency; a wider smooth
sign (v_th 0.02 rad/s); the reference velocity instead of the measured one (``velocity_source: reference``); the
gyro's inertial rate instead of the joint's rate relative to the base (a wiring mistake); a
temperature that reads 20 degC too warm; a stale temperature (the node's fallback, +20 degC); the truth without
lubricant shift; twice the shift; no position ripple; no breakaway.

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

from gimbal_friction.core.feedforward import FeedforwardSettings
from gimbal_friction.core.params import AxisParams
from gimbal_friction.sim import SimConfig, batch_metrics, make_profile, simulate
from gimbal_friction.sim.compensation import Compensator, ControllerInputs, suite_feedforward
from gimbal_friction.sim.engine import Run

TEMPERATURES = (-40.0, -20.0, 20.0)
DURATIONS = {'tracking': 8.0, 'scan': 4.0, 'pointing': 4.0}


def stale(comp: Compensator, temperature_c: float) -> Compensator:
    """``comp`` fed a fixed temperature (what the node does with a stale one under ``fallback_temperature``)."""
    def torque(inputs: ControllerInputs) -> Any:
        return comp.torque(inputs._replace(temperature_c=np.full(inputs.temperature_c.shape, temperature_c)))
    return Compensator(torque, comp.delayed)


def inertial(comp: Compensator) -> Compensator:
    """``comp`` fed the gyro's inertial LOS rate in place of the joint's rate relative to the base (the mistake)."""
    def torque(inputs: ControllerInputs) -> Any:
        return comp.torque(inputs._replace(joint_velocity_rad_s=inputs.gyro_rate_rad_s))
    return Compensator(torque, comp.delayed)


def variants(axis: AxisParams) -> list[tuple[str, SimConfig, Callable[[], Compensator]]]:
    base = SimConfig()
    return [
        ('defaults', base, lambda: suite_feedforward(axis)),
        ('latency 0', base.replace(feedforward_latency_s=0.0), lambda: suite_feedforward(axis)),
        ('latency 3 ms', base.replace(feedforward_latency_s=3e-3), lambda: suite_feedforward(axis)),
        ('v_th 0.02 rad/s', base,
         lambda: suite_feedforward(axis, FeedforwardSettings(velocity_threshold_rad_s=0.02))),
        ('reference velocity', base, lambda: suite_feedforward(axis, velocity_source='reference')),
        ('gyro (inertial) rate', base, lambda: inertial(suite_feedforward(axis))),
        ('temperature +20 C off', base.replace(temperature_bias_c=20.0), lambda: suite_feedforward(axis)),
        ('stale temperature', base, lambda: stale(suite_feedforward(axis), 20.0)),
        ('no lubricant shift', base.replace(lubricant_walther_a_shift=0.0), lambda: suite_feedforward(axis)),
        ('2x lubricant shift', base.replace(lubricant_walther_a_shift=0.03), lambda: suite_feedforward(axis)),
        ('no ripple', base.replace(ripple_amplitudes=(0.0, 0.0)), lambda: suite_feedforward(axis)),
        ('no breakaway', base.replace(breakaway_ratio=1.0), lambda: suite_feedforward(axis)),
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
