#!/usr/bin/env python3
"""Fleet throughput: 20 synthetic units (varied lubricant and preload, two injected outliers) on Dask.

Each unit is a synthetic chamber-test bag (synth-bag protocol: plateaus -40..60 degC, 1/3 rpm; ``--rate`` Hz,
``--hold`` s holds) with its own truth: ``walther_a`` = 8.6345 + N(0, 0.002) (grease viscosity), gasket thickness
0.030 + N(0, 0.0005) mm (preload); unit 07 has an over-tight gasket (0.040 mm), unit 13 a different grease
(walther_a + 0.03). With ``--kind log`` the bags are replayed once into residual logs beforehand and the fleet
streams those (the refit-only path). The fleet runs on an embedded LocalCluster with 1 and with 2 worker processes;
the baseline is the same per-unit work in a plain loop in this process (no Dask), measured in the same run.

    .venv/bin/python bench/fleet_scaling.py                  # 20 bag units, workers 1 and 2 (a few minutes)
    .venv/bin/python bench/fleet_scaling.py --units 6 --kind log --json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gimbal_friction.chamber.fleet import FitSettings, discover_units, process_unit, run_fleet
from gimbal_friction.chamber.replay import replay_bag
from gimbal_friction.chamber.synth import SynthConfig, generate
from gimbal_friction.chamber.synth_bag import write_bag
from gimbal_friction.config.loader import all_axis_params, load_parameters

OVER_TIGHT, OTHER_GREASE = 7, 13


def make_units(root: Path, n: int, rate: float, hold: float, kind: str) -> None:
    rng = np.random.default_rng(2026)
    for i in range(n):
        a = 8.6345 + rng.normal(0.0, 0.002)
        gasket = 0.030 + rng.normal(0.0, 0.0005)
        if i == OVER_TIGHT:
            gasket = 0.040
        if i == OTHER_GREASE:
            a += 0.03
        cfg = SynthConfig(hold_s=hold, joint_rate_hz=rate, seed=i, asym_ratio_cold=1.0,
                          truth_overrides={'walther_a': a, 'palmgren_factor': 2.0, 'gasket_thickness_mm': gasket})
        bag = root / f'unit_{i:02d}'
        write_bag(generate(cfg), bag if kind == 'bag' else root / f'.bag_{i:02d}')
        if kind == 'log':
            replay_bag(root / f'.bag_{i:02d}', bag)
            shutil.rmtree(root / f'.bag_{i:02d}')
        print(f'made unit {i + 1}/{n}', file=sys.stderr)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--units', type=int, default=20)
    ap.add_argument('--rate', type=float, default=50.0, help='joint/current rate of the synthetic tests [Hz]')
    ap.add_argument('--hold', type=float, default=40.0, help='hold per plateau [s]')
    ap.add_argument('--kind', choices=['bag', 'log'], default='bag')
    ap.add_argument('--workers', default='1,2')
    ap.add_argument('--keep', type=Path, help='make the units here (kept) instead of a temporary folder')
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix='fleet_bench_'))
    root.mkdir(parents=True, exist_ok=True)
    try:
        if not any(root.iterdir()):
            t0 = time.perf_counter()
            make_units(root, args.units, args.rate, args.hold, args.kind)
            print(f'units made in {time.perf_counter() - t0:.1f} s', file=sys.stderr)
        units = discover_units([root])
        settings = FitSettings(axes=all_axis_params(load_parameters([])), config_paths=())
        t0 = time.perf_counter()
        serial = [process_unit(u, settings) for u in units]
        t_serial = time.perf_counter() - t0
        runs = []
        for w in (int(x) for x in args.workers.split(',')):
            run = run_fleet(units, settings, workers=w)
            flagged = sorted({(o['unit'], o['parameter']) for o in run.population['outliers']})
            work = run.seconds - run.startup_s
            runs.append({'workers': w, 'seconds': run.seconds, 'startup_s': run.startup_s,
                         'units_per_minute': 60.0 * len(units) / run.seconds,
                         'units_per_minute_after_startup': 60.0 * len(units) / work,
                         'speedup_vs_serial': t_serial / run.seconds,
                         'max_worker_rss_mb': max(r['max_rss_mb'] for r in run.records),
                         'errors': [r['unit'] for r in run.records if r['error']], 'outliers': flagged})
            print(f'{w} worker(s): {run.seconds:.1f} s', file=sys.stderr)
        messages = sum(sum(r.get('rows', {}).values()) for r in serial)
        doc = {'units': len(units), 'kind': args.kind, 'rate_hz': args.rate, 'hold_s': args.hold,
               'serial_seconds': t_serial, 'serial_units_per_minute': 60.0 * len(units) / t_serial,
               'rows_refitted': messages, 'runs': runs}
        if args.json:
            print(json.dumps(doc, indent=1))
            return 0
        print(f'{len(units)} {args.kind} units ({args.rate:g} Hz, {args.hold:g} s holds); serial in-process baseline '
              f'{t_serial:.1f} s = {doc["serial_units_per_minute"]:.1f} units/min')
        print(f'{"workers":>7} {"seconds":>8} {"startup":>8} {"units/min":>9} {"after startup":>13} '
              f'{"vs serial":>9} {"max RSS/worker [MB]":>20}')
        for r in runs:
            print(f'{r["workers"]:>7} {r["seconds"]:>8.1f} {r["startup_s"]:>8.1f} {r["units_per_minute"]:>9.1f} '
                  f'{r["units_per_minute_after_startup"]:>13.1f} {r["speedup_vs_serial"]:>8.2f}x '
                  f'{r["max_worker_rss_mb"]:>20.0f}')
        print(f'load average during the run (other processes share the 2 cores): {os.getloadavg()}')
        for r in runs:
            print(f'{r["workers"]} worker(s): outliers {r["outliers"]}; errors {r["errors"] or "none"}')
        return 0
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == '__main__':
    sys.exit(main())
