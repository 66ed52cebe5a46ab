"""Benchmark (not a test): the exported C table vs the Python model, per-call time and accuracy.

Builds the table of the default axis (``gimbal_friction.export.table``), writes its C header to a temporary
directory, compiles a small driver with ``gcc -O2`` and measures, in the same run.

Two point sets of ``--points`` each: ``random`` (uniform over the table's temperature range and ±max speed: the
binary search's branches are unpredictable, the worst case) and ``trajectory`` (what a controller sees: the
temperature drifting slowly across the range, the velocity a ±2 rad/s sine of 1000 samples). For each:

- **C per call**: ``gf_<axis>_friction_nm`` and ``gf_<axis>_feedforward_nm`` over the points, ``--repeat`` times;
  the driver also times a loop that only sums its inputs (the loop overhead, subtracted) and keeps a checksum so
  that nothing is optimised away;
- **Python per call**: ``FrictionTable.torque_nm`` (the nodes' tabulated fast path) over the first
  ``--python-points`` of the same points, best of three passes;
- **accuracy**: the C friction at every point against the full model
  (:func:`~gimbal_friction.physics.model.friction_torque`), max relative error outside the Palmgren switch band and
  the number of points inside it; and the same for ``FrictionTable``.

Prints a table (or ``--json``) with the ratio Python/C. Run from the repository root::

    .venv/bin/python bench/export_table.py                      # 100000 points x 20 repeats
    .venv/bin/python bench/export_table.py --points 20000 --json

Exit code 1 with one line on stderr if gcc is missing or the driver fails.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.common.units import rpm_from_rad_s
from gimbal_friction.config.loader import all_axis_params, load_parameters
from gimbal_friction.export.formats import render_c_header
from gimbal_friction.export.table import ExportOptions, Provenance, build_table, c_identifier
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.table import FrictionTable

DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "gimbal_friction_%(a)s.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int main(int argc, char **argv)
{
    long n, r, i, k, set;
    double *t, *v, sum = 0.0, t0, loop_s, friction_s, feedforward_s;
    if (argc != 3) {
        return 2;
    }
    n = atol(argv[1]);
    r = atol(argv[2]);
    t = malloc((size_t)n * sizeof *t);
    v = malloc((size_t)n * sizeof *v);
    if (t == NULL || v == NULL) {
        return 3;
    }
    for (set = 0; set < 2; set++) {  /* 0: random points, 1: a controller-like trajectory */
        for (i = 0; i < n; i++) {
            if (scanf("%%lf %%lf", &t[i], &v[i]) != 2) {
                return 4;
            }
        }
        for (i = 0; i < n; i++) {  /* accuracy: one value per point */
            printf("%%.17g\n", gf_%(a)s_friction_nm(t[i], v[i]));
        }
        t0 = now_s();
        for (k = 0; k < r; k++) {
            for (i = 0; i < n; i++) {
                sum += t[i] * 1e-9 + v[i];
            }
        }
        loop_s = now_s() - t0;
        t0 = now_s();
        for (k = 0; k < r; k++) {
            for (i = 0; i < n; i++) {
                sum += gf_%(a)s_friction_nm(t[i], v[i]);
            }
        }
        friction_s = now_s() - t0;
        t0 = now_s();
        for (k = 0; k < r; k++) {
            for (i = 0; i < n; i++) {
                sum += gf_%(a)s_feedforward_nm(t[i], v[i]);
            }
        }
        feedforward_s = now_s() - t0;
        fprintf(stderr, "%%.9g %%.9g %%.9g %%.17g\n", loop_s, friction_s, feedforward_s, sum);
    }
    free(t);
    free(v);
    return 0;
}
"""


def _python_ns_per_call(ft: FrictionTable, t: list[float], v: list[float]) -> float:
    """Best of three passes of ``FrictionTable.torque_nm`` over the points, [ns per call]."""
    best = float('inf')
    for _ in range(3):
        s0 = time.perf_counter_ns()
        for x, y in zip(t, v, strict=True):
            ft.torque_nm(x, y)
        best = min(best, (time.perf_counter_ns() - s0) / len(t))
    return best


def point_sets(points: int, seed: int, o: ExportOptions) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``random``: uniform over the table's range (unpredictable branches: the worst case); ``trajectory``: what a
    controller sees, temperature drifting slowly over the range and velocity a ±2 rad/s sine of 1000 samples."""
    rng = np.random.default_rng(seed)
    t_r = rng.uniform(o.temperature_min_c, o.temperature_max_c, points)
    v_r = rng.uniform(-o.max_speed_rad_s, o.max_speed_rad_s, points)
    i = np.arange(points)
    t_c = o.temperature_min_c + (o.temperature_max_c - o.temperature_min_c) * i / points
    v_c = 2.0 * np.sin(2.0 * np.pi * i / 1000.0)
    return {'random': (t_r, v_r), 'trajectory': (t_c, v_c)}


def run(points: int, repeat: int, py_points: int, seed: int, relative_error: float) -> dict[str, Any]:
    gcc = shutil.which('gcc')
    if gcc is None:
        raise SystemExit('export_table: gcc not found (apt-get install gcc)')
    params = all_axis_params(load_parameters())
    axis, p = next(iter(params.items()))
    t0 = time.perf_counter()
    table = build_table(axis, p, FeedforwardSettings(), ExportOptions(relative_error=relative_error))
    build_s = time.perf_counter() - t0
    a = c_identifier(axis)
    sets = point_sets(points, seed, table.options)
    flags = ['-std=c99', '-O2', '-Wall', '-Wextra', '-Werror', '-pedantic']
    with tempfile.TemporaryDirectory(prefix='export_bench_') as tmp:
        d = Path(tmp)
        prov = Provenance('bench/export_table.py', time.strftime('%Y-%m-%dT%H:%M:%S'), ())
        (d / f'gimbal_friction_{a}.h').write_text(render_c_header(table, prov))
        (d / 'driver.c').write_text(DRIVER % {'a': a})
        done = subprocess.run([gcc, *flags, 'driver.c', '-o', 'driver', '-lm'], cwd=d, capture_output=True,
                              text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f'export_table: gcc failed: {done.stderr.strip().splitlines()[0]}')
        text = ''.join(f'{float(x)!r} {float(y)!r}\n' for t, v in sets.values() for x, y in zip(t, v, strict=True))
        out = subprocess.run([str(d / 'driver'), str(points), str(repeat)], input=text, capture_output=True,
                             text=True, check=False, timeout=600)
        if out.returncode != 0:
            raise SystemExit(f'export_table: driver exited with {out.returncode}')
    c_values = np.array(out.stdout.split(), dtype=float).reshape(len(sets), points)
    timings = [[float(x) for x in line.split()] for line in out.stderr.strip().splitlines()]
    calls = points * repeat
    ft = FrictionTable(p)
    results: dict[str, Any] = {}
    for k, (name, (t, v)) in enumerate(sets.items()):
        loop_s, friction_s, feedforward_s, _ = timings[k]
        c_ns = max(friction_s - loop_s, 0.0) / calls * 1e9
        py_ns = _python_ns_per_call(ft, t[:py_points].tolist(), v[:py_points].tolist())
        rpm = rpm_from_rad_s(np.abs(v))
        model = 1e-3 * friction_torque(p, t, rpm).m_total_nmm
        err = np.abs(c_values[k] - model) / model
        table_upper = table.evaluate_nm(t, v) != table.evaluate_nm(t, 0.0)
        outside = table_upper == (viscosity_cst(p, t) * rpm >= 2000.0)
        ft_values = np.array([ft.torque_nm(x, y) for x, y in zip(t[:py_points], v[:py_points], strict=True)])
        results[name] = {
            'c_friction_ns_per_call': c_ns, 'c_feedforward_ns_per_call': max(feedforward_s - loop_s, 0.0) / calls
            * 1e9, 'c_loop_ns_per_call': loop_s / calls * 1e9, 'python_frictiontable_ns_per_call': py_ns,
            'ratio_python_over_c': py_ns / c_ns if c_ns > 0 else None,
            'c_max_relative_error': float(err[outside].max()), 'c_points_in_switch_band': int((~outside).sum()),
            'c_max_relative_error_in_switch_band': float(err[~outside].max()) if (~outside).any() else 0.0,
            'python_frictiontable_max_relative_error': float(np.max(np.abs(ft_values - model[:py_points])
                                                                    / model[:py_points])),
        }
    return {
        'axis': axis, 'points': points, 'repeat': repeat, 'python_points': py_points, 'seed': seed,
        'relative_error_bound': relative_error, 'build_s': build_s,
        'grid': {'temperatures': table.report.temperatures, 'upper_rows': table.report.upper_rows,
                 'values': table.report.values},
        'sets': results,
        'machine': {'python': platform.python_version(), 'gcc': subprocess.run(
            [gcc, '-dumpfullversion'], capture_output=True, text=True, check=False).stdout.strip(),
            'flags': ' '.join(flags)},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or '').splitlines()[0])
    parser.add_argument('--points', type=int, default=100_000, help='points per set (default 100000)')
    parser.add_argument('--repeat', type=int, default=20, help='C passes over the points (default 20)')
    parser.add_argument('--python-points', type=int, default=20_000,
                        help='points timed in Python (default 20000)')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--relative-error', type=float, default=1e-4)
    parser.add_argument('--json', action='store_true', help='one JSON document on stdout')
    args = parser.parse_args(argv)
    doc = run(args.points, args.repeat, min(args.python_points, args.points), args.seed, args.relative_error)
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    g = doc['grid']
    a = c_identifier(doc['axis'])
    print(f"table of {doc['axis']}: {g['temperatures']} temperature breakpoints, {g['upper_rows']} speed rows, "
          f"{g['values']} numbers; built in {doc['build_s']:.2f} s (bound {doc['relative_error_bound']:g}); "
          f"gcc {doc['machine']['gcc']} {doc['machine']['flags']}")
    rows = []
    for name, r in doc['sets'].items():
        ratio = r['ratio_python_over_c']
        rows.append([name, f"{r['c_friction_ns_per_call']:.1f}", f"{r['c_feedforward_ns_per_call']:.1f}",
                     f"{r['python_frictiontable_ns_per_call']:.0f}", f'{ratio:.1f}' if ratio else 'n/a',
                     f"{r['c_max_relative_error']:.2e}", str(r['c_points_in_switch_band']),
                     f"{r['python_frictiontable_max_relative_error']:.2e}"])
    header = ['points', f'C gf_{a}_friction_nm [ns]', 'C feedforward [ns]', 'Python FrictionTable [ns]',
              'Python/C', 'C max rel err', 'in switch band', 'FrictionTable max rel err']
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    print('  '.join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    for row in rows:
        print('  '.join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
    print(f"({doc['points']} points per set, C timed {doc['repeat']} times with the loop overhead subtracted; "
          f"Python timed on {doc['python_points']}; errors vs the full model)")
    return 0


if __name__ == '__main__':
    sys.exit(main())
