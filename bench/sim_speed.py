"""Speed of the closed-loop simulator: simulated seconds per wall second, one run and a batch of runs.

Not a test: prints, asserts nothing. Each number is put beside a baseline measured in the same run: a bare numpy
loop with the same number of controller ticks and plant sub-steps over arrays of the same size, doing a minimal
rigid-axis update (current lag, tanh friction, Euler step; about 8 array operations per sub-step, no sensors,
controller or bookkeeping). The ratio ``sim / baseline`` is what the simulator's physics and bookkeeping cost
over the least a numpy loop of that step count costs; it varies less with machine load than absolute times.

Usage (repository root, project venv)::

    .venv/bin/python bench/sim_speed.py                  # tracking profile, 5 s simulated, best of 3
    .venv/bin/python bench/sim_speed.py --duration 2 --repeat 5 --json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable

import numpy as np

from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim import DEFAULT_TEMPERATURES, SimConfig, make_profile, simulate
from gimbal_friction.sim.compensation import Compensator, constant_coulomb, suite_feedforward
from gimbal_friction.sim.engine import Run


def bare_loop(ticks: int, substeps: int, runs: int) -> None:
    """The baseline: the same step count over ``runs``-sized arrays, minimal physics."""
    h, J, K_T = 2.5e-4, 1e-4, 0.05
    theta, omega, current = np.zeros(runs), np.zeros(runs), np.zeros(runs)
    level = np.full(runs, 1e-3)
    decay = math.exp(-h / 2e-4)
    for k in range(ticks):
        i_cmd = np.clip(0.02 - 0.3 * omega, -2.0, 2.0)
        for _ in range(substeps):
            v = omega - 1e-3 * (k & 7)
            current = i_cmd + (current - i_cmd) * decay
            omega = omega + h * (K_T * current - level * np.tanh(v / 1e-3)) / J
            theta = theta + h * omega


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    """Shortest wall time of ``repeat`` calls [s]."""
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=5.0, help='simulated seconds per measurement [s]')
    parser.add_argument('--repeat', type=int, default=3, help='measurements; the best is kept')
    parser.add_argument('--json', action='store_true', help='print one JSON document')
    args = parser.parse_args(argv)
    if not (args.duration > 0 and args.repeat >= 1):
        print('sim_speed: --duration must be > 0 and --repeat >= 1', file=sys.stderr)
        return 1
    cfg, axis = SimConfig(), AxisParams()
    prof = make_profile(cfg, 'tracking', args.duration)
    ticks = prof.time_s.shape[0]
    cases = ('none', 'constant', 'feedforward', 'ideal', 'refit')
    batch = [Run(c, t) for c in cases for t in DEFAULT_TEMPERATURES]

    def comps() -> dict[str, Compensator]:
        ff = suite_feedforward(axis)
        return {'constant': constant_coulomb(axis), 'feedforward': ff, 'refit': ff}

    one = [Run('feedforward', -40.0)]
    c1, cb = comps(), comps()   # built outside the timing (the table build is a one-off 0.06 s)
    rows = []
    for label, runs, hooks in (('one run', one, c1), (f'batch of {len(batch)} runs', batch, cb)):
        def sim(runs: list[Run] = runs, hooks: dict[str, Compensator] = hooks) -> None:
            simulate(cfg, axis, prof, runs, hooks)

        def base(n: int = len(runs)) -> None:
            bare_loop(ticks, cfg.plant_substeps, n)

        sim_s, base_s = best_of(args.repeat, sim), best_of(args.repeat, base)
        rows.append({'label': label, 'runs': len(runs), 'simulated_s': args.duration, 'wall_s': sim_s,
                     'sim_s_per_wall_s': args.duration / sim_s,
                     'run_s_per_wall_s': args.duration * len(runs) / sim_s,
                     'baseline_wall_s': base_s, 'ratio_to_baseline': sim_s / base_s})
    if args.json:
        print(json.dumps({'controller_hz': cfg.rate_loop_hz, 'plant_substeps': cfg.plant_substeps,
                          'ticks': ticks, 'rows': rows}, indent=1))
        return 0
    print(f'tracking profile, {args.duration:g} s simulated = {ticks} controller ticks x {cfg.plant_substeps} '
          f'plant sub-steps; best of {args.repeat}')
    for r in rows:
        print(f'  {r["label"]:18s} {r["wall_s"]:6.2f} s wall: {r["sim_s_per_wall_s"]:5.2f} simulated s per wall s '
              f'({r["run_s_per_wall_s"]:6.1f} run-s/s); bare numpy loop {r["baseline_wall_s"]:5.2f} s -> '
              f'{r["ratio_to_baseline"]:.1f}x the baseline')
    return 0


if __name__ == '__main__':
    sys.exit(main())
