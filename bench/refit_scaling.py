#!/usr/bin/env python3
"""Refit cost vs number of samples: the fit on per-bin sufficient statistics against the per-sample fit.

Synthetic chamber samples at 1 kHz (six plateaus -40..60 degC, sensor noise 0.05 degC, both directions alternating
every 5 s, +/-5 % ripple, 0.1 mN*m noise) from a truth with walther_a + 0.02. For each n: the time of
``refit_model(..., time_s=stamps)`` (binned: accumulate the statistics, then fit) split into its two parts, the
per-sample reference (``exact=True``) where affordable, and the baseline: one plain ``np.mean`` pass over the same
samples, all in this run (median of ``--repeat`` rounds; the ratios are what compare across machines). The goal
(issue 22) for 10^7 samples: accumulation <= 0.3 s and refit <= 0.5 s. No assertion: read the figures.

    .venv/bin/python bench/refit_scaling.py                 # n = 1e5, 1e6, 1e7; exact up to 1e5
    .venv/bin/python bench/refit_scaling.py --json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np

from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import refit_model, refit_stats
from gimbal_friction.refit.sufficient import SufficientStats


def samples(n: int, truth: AxisParams, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    plateaus = np.array([-40.0, -20.0, 0.0, 20.0, 40.0, 60.0])
    k = np.minimum(np.arange(n) * 6 // n, 5)
    t = plateaus[k] + rng.normal(0.0, 0.05, n)
    grid = np.linspace(-41.0, 61.0, 2041)
    m = friction_torque(truth, grid, 1 / 3).m_total_nmm * 1e-3
    d = np.where((np.arange(n) // 5000) % 2 == 0, 1.0, -1.0)
    ripple = 1.0 + 0.05 * np.sin(np.arange(n) * 2.0 * np.pi / 1700.0)
    y = np.interp(t, grid, m) * ripple + rng.normal(0.0, 1e-4, n)
    return t, np.full(n, 1 / 3), y, d, np.arange(n) / 1000.0


def one_size(n: int, base: AxisParams, truth: AxisParams, exact_max: int,
             exact_per_sample: float | None, repeat: int) -> dict[str, float]:
    """Times of one sample count [s] (medians of ``repeat`` rounds)."""
    t, s, y, d, ts = samples(n, truth)
    nu_truth = float(viscosity_cst(truth, -40.0))
    times: dict[str, list[float]] = {'mean_s': [], 'accumulate_s': [], 'fit_s': [], 'refit_model_s': []}
    for _ in range(repeat):
        c0 = time.perf_counter()
        float(np.mean(y))
        c1 = time.perf_counter()
        stats = SufficientStats.from_arrays(t, s, y, d, time=ts)
        c2 = time.perf_counter()
        res = refit_stats(base, stats)
        c3 = time.perf_counter()
        res2 = refit_model(base, t, s, y, d, time_s=ts)
        c4 = time.perf_counter()
        for key, dt in zip(times, (c1 - c0, c2 - c1, c3 - c2, c4 - c3), strict=True):
            times[key].append(dt)
    med = {k: statistics.median(v) for k, v in times.items()}
    row: dict[str, float] = {
        'n': n, 'cells': len(stats), 'bins': res.n_bins, **med,
        'accumulate_ratio_to_mean': med['accumulate_s'] / med['mean_s'],
        'ratio_to_mean': med['refit_model_s'] / med['mean_s'],
        'nu_m40_error_pct': 100 * (float(viscosity_cst(res2.params, -40.0)) / nu_truth - 1.0)}
    if n <= exact_max:
        c5 = time.perf_counter()
        ex = refit_model(base, t, s, y, d, time_s=ts, exact=True)
        row['exact_s'] = time.perf_counter() - c5
        row['exact_walther_a_minus_binned'] = ex.fitted['walther_a'] - res2.fitted['walther_a']
        row['walther_a_se'] = res2.standard_errors['walther_a']
        exact_per_sample = row['exact_per_sample_s'] = row['exact_s'] / n
    if exact_per_sample is not None:
        row['exact_projected_s'] = exact_per_sample * n
        row['speedup_vs_exact'] = exact_per_sample * n / row['refit_model_s']
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--sizes', default='100000,1000000,10000000', help='comma-separated sample counts')
    ap.add_argument('--exact-max', type=int, default=100000, help='largest n for the per-sample reference')
    ap.add_argument('--repeat', type=int, default=3, help='rounds per size (medians are reported)')
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args()
    base = AxisParams()
    truth = base.replace(walther_a=base.walther_a + 0.02)
    rows = []
    exact_per_sample = None
    for n in (int(x) for x in args.sizes.split(',')):
        row = one_size(n, base, truth, args.exact_max, exact_per_sample, args.repeat)
        exact_per_sample = row.get('exact_per_sample_s', exact_per_sample)
        rows.append(row)
        print(f'n={n}: refit_model {row["refit_model_s"]:.2f} s (accumulate {row["accumulate_s"]:.2f} + fit '
              f'{row["fit_s"]:.2f}), {row["bins"]} bins', file=sys.stderr)
    if args.json:
        print(json.dumps({'rows': rows}, indent=1))
        return 0
    print(f'median of {args.repeat} rounds (this machine, same run); reference: one np.mean pass over the samples')
    print(f'{"n":>10} {"cells":>7} {"bins":>5} {"mean [s]":>9} {"accum [s]":>9} {"accum/mean":>10} {"fit [s]":>8} '
          f'{"refit [s]":>9} {"refit/mean":>10} {"exact [s]":>10} {"speed-up":>9} {"nu err %":>8}')
    for r in rows:
        exact = f'{r["exact_s"]:.2f}' if 'exact_s' in r else (f'~{r["exact_projected_s"]:.1f}*'
                                                               if 'exact_projected_s' in r else '-')
        speed = f'{r["speedup_vs_exact"]:.0f}x' if 'speedup_vs_exact' in r else '-'
        print(f'{r["n"]:>10} {r["cells"]:>7} {r["bins"]:>5} {r["mean_s"]:>9.4f} {r["accumulate_s"]:>9.3f} '
              f'{r["accumulate_ratio_to_mean"]:>10.0f} {r["fit_s"]:>8.3f} {r["refit_model_s"]:>9.3f} '
              f'{r["ratio_to_mean"]:>10.0f} {exact:>10} {speed:>9} {r["nu_m40_error_pct"]:>8.2f}')
    print('* per-sample reference projected linearly from the largest n it was run at (its cost is linear in n)')
    big = rows[-1]
    print(f'n={big["n"]}: accumulation {big["accumulate_s"]:.3f} s (goal <= 0.3 s), refit '
          f'{big["refit_model_s"]:.3f} s (goal <= 0.5 s), one np.mean pass {big["mean_s"]:.4f} s: accumulation '
          f'{big["accumulate_ratio_to_mean"]:.0f}x, refit {big["ratio_to_mean"]:.0f}x the mean pass')
    for r in rows:
        if 'exact_s' in r:
            print(f'n={r["n"]}: exact - binned walther_a = {r["exact_walther_a_minus_binned"]:.2e} '
                  f'(its standard error {r["walther_a_se"]:.2e})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
