"""Per-call cost of the in-process feedforward (``gimbal_friction.controller``) against ``numpy.interp``'s scalar call.

What a Python controller pays per tick for one axis: ``Feedforward.torque_nm(joint, v, time_s)`` (temperature
freshness and stale policy, table lookup, Walther viscosity, Palmgren, smooth sign, direction factor, clamp) and,
for comparison, ``Feedforward.message`` (the node's per-message path, two axes) — against the baseline measured in
the same run: one scalar ``numpy.interp`` on a 1801-point table (the cheapest lookup a controller could write with
numpy). Goals (issue 22): one axis ≤ 1.0 µs per call and below ``numpy.interp`` in the same run; a two-axis
message ≤ 3 µs. The same calls are also measured with a learned correction (issue 21): an empty one (goal: at most
~0.1 µs more than without), and one learned over every temperature bin and both directions, without and with a
position map (16 bins), looked up at the position passed. Goal (issue 33): with the learned correction loaded, one
axis at most ``numpy.interp``'s scalar call in the same run.

A benchmark, not a test: the machine is shared, so only the ratios measured in one run compare. Median of
``--repeat`` rounds of ``--calls`` calls each.

Run from the repository root: ``.venv/bin/python bench/inprocess_call.py [--calls 200000] [--repeat 5] [--json]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gimbal_friction.config.loader import render_parameter_file  # noqa: E402
from gimbal_friction.controller import load_feedforward  # noqa: E402
from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, ModelIdentity  # noqa: E402

TARGET_US = 1.0          #: one axis, per call [µs] (and below numpy.interp)
TARGET_MESSAGE_US = 3.0  #: a two-axis message [µs]
TARGET_EMPTY_EXTRA_US = 0.1  #: an empty correction adds at most this per scalar call [µs]


def learned_correction(identity: ModelIdentity, joints: Sequence[str], positions: bool) -> Correction:
    """A correction of ``joints`` (model ``identity``) learned from residuals at every temperature, both directions
    and speeds from 0.01 to 0.5 rad/s: a speed profile in every cell and, with ``positions``, a ripple at two periods
    and a trend (the guard off: every term applied). Also used by ``bench/correction_lookup.py``."""
    c = Correction(CorrectionSettings(guard_min_samples=0, guard_z=0.0, trend=positions,
                                      ripple_periods_max=4 if positions else 0), identity)
    rng = np.random.default_rng(0)
    n = 60_000
    t = rng.uniform(-62.0, 122.0, n)
    v = rng.choice([-1.0, 1.0], n) * np.exp(rng.uniform(np.log(0.01), np.log(0.5), n))
    p = rng.uniform(-0.3, 0.3, n)
    ripple = 0.08 * np.sin(2 * np.pi * p / np.radians(3.4)) + 0.04 * np.sin(2 * np.pi * p / np.radians(1.1))
    for joint in joints:
        c.learn_residuals(joint, t, v, p, np.sign(v) * 2e-3 * (0.2 + ripple) + 5e-4 * np.sin(p) * positions,
                          np.full(n, 2e-3))
    c.settle()
    return c


def per_call_us(fn: Callable[[int], object], calls: int) -> float:
    """Wall time per call [µs] of ``fn(i)`` for i in range(calls)."""
    t0 = time.perf_counter()
    for i in range(calls):
        fn(i)
    return (time.perf_counter() - t0) / calls * 1e6


def interleaved_medians(workloads: dict[str, Callable[[int], object]], repeat: int, calls: int) -> dict[str, float]:
    """Median time per call [µs] of each workload over ``repeat`` rounds, run in turn (the order reversed every
    other round, so that no workload always runs on a warm or a cold machine)."""
    results: dict[str, list[float]] = {k: [] for k in workloads}
    for r in range(repeat):
        items = list(workloads.items())
        for name, fn in (items if r % 2 == 0 else items[::-1]):
            results[name].append(per_call_us(fn, calls))
    return {k: statistics.median(v) for k, v in results.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--calls', type=int, default=200_000)
    ap.add_argument('--repeat', type=int, default=5)
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args(argv)

    ff = load_feedforward()
    two = ROOT / 'bench' / '.two_axes.yaml'
    two.write_text(render_parameter_file(axes=['elevation', 'azimuth']))
    try:
        ff2, ff2_empty = load_feedforward(two), load_feedforward(two)
    finally:
        two.unlink()
    ff_empty, ff_learned, ff_map = (load_feedforward() for _ in range(3))
    ff_empty.set_correction(Correction(CorrectionSettings(), ff.model_identity()))
    ff_learned.set_correction(learned_correction(ff.model_identity(), ff.order, positions=False))
    ff_map.set_correction(learned_correction(ff.model_identity(), ff.order, positions=True))
    ff2_empty.set_correction(Correction(CorrectionSettings(), ff2.model_identity()))
    for f in (ff, ff2, ff_empty, ff_learned, ff_map, ff2_empty):
        f.update_temperature(-35.0, 0.0)
    grid = np.linspace(-60.0, 120.0, 1801)
    values = np.sin(grid / 30.0)
    temps = (-40.0 + (np.arange(1000) % 100)).tolist()
    vels = (0.035 * np.sin(np.arange(1000) / 7.0)).tolist()
    poss = (np.arange(1000) * 0.01).tolist()
    names = ['elevation', 'azimuth']

    workloads: dict[str, Callable[[int], object]] = {
        'numpy.interp scalar (baseline)': lambda i: np.interp(temps[i % 1000], grid, values),
        'Feedforward.torque_nm, one axis': lambda i: ff.torque_nm('elevation', vels[i % 1000], 1e-3 * (i % 1000)),
        'Feedforward.message, two axes': lambda i: ff2.message(names, [vels[i % 1000], -vels[i % 1000]],
                                                                1e-3 * (i % 1000)),
        'torque_nm, empty correction': lambda i: ff_empty.torque_nm('elevation', vels[i % 1000], 1e-3 * (i % 1000),
                                                                     poss[i % 1000]),
        'torque_nm, learned correction': lambda i: ff_learned.torque_nm('elevation', vels[i % 1000],
                                                                         1e-3 * (i % 1000), poss[i % 1000]),
        'torque_nm, learned, position terms': lambda i: ff_map.torque_nm('elevation', vels[i % 1000], 1e-3 * (i % 1000),
                                                                   poss[i % 1000]),
        'message, two axes, empty corr.': lambda i: ff2_empty.message(names, [vels[i % 1000], -vels[i % 1000]],
                                                                        1e-3 * (i % 1000),
                                                                        [poss[i % 1000], poss[i % 1000]]),
    }
    med = interleaved_medians(workloads, args.repeat, args.calls)
    base = med['numpy.interp scalar (baseline)']
    one = med['Feedforward.torque_nm, one axis']
    message = med['Feedforward.message, two axes']
    extra = med['torque_nm, empty correction'] - one
    learned = med['torque_nm, learned correction']
    doc = {'per_call_us': med, 'ratio_to_numpy_interp': {k: v / base for k, v in med.items()},
           'target_us': TARGET_US, 'target_message_us': TARGET_MESSAGE_US,
           'empty_correction_extra_us': extra, 'target_empty_correction_extra_us': TARGET_EMPTY_EXTRA_US,
           'pass': one <= TARGET_US and one < base, 'pass_message': message <= TARGET_MESSAGE_US,
           'pass_empty_correction': extra <= TARGET_EMPTY_EXTRA_US, 'pass_learned_correction': learned <= base}
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(f'median of {args.repeat} rounds x {args.calls} calls (this machine, same run)')
    for name, us in med.items():
        print(f'  {name:<34} {us:6.2f} us/call   {us / base:5.2f} x numpy.interp')
    verdict = 'PASS' if doc['pass'] else 'MISS'
    print(f'one axis per call: {one:.2f} us ({one / base:.2f} x numpy.interp), target <= {TARGET_US:g} us and below '
          f'numpy.interp: {verdict}')
    verdict = 'PASS' if doc['pass_message'] else 'MISS'
    print(f'two-axis message: {message:.2f} us, target <= {TARGET_MESSAGE_US:g} us: {verdict}')
    verdict = 'PASS' if doc['pass_empty_correction'] else 'MISS'
    print(f'an empty correction adds {extra:+.3f} us per scalar call, target <= {TARGET_EMPTY_EXTRA_US:g} us: '
          f'{verdict}')
    verdict = 'PASS' if doc['pass_learned_correction'] else 'MISS'
    print(f'with a learned correction: {learned:.2f} us ({learned / base:.2f} x numpy.interp), target <= 1.0 x '
          f'numpy.interp: {verdict}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
