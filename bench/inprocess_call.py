"""Per-call cost of the in-process feedforward (``gimbal_friction.controller``) against ``numpy.interp``'s scalar call.

What a Python controller pays per tick for one axis: ``Feedforward.torque_nm(joint, v, time_s)`` (temperature
freshness and stale policy, table lookup, Walther viscosity, Palmgren, smooth sign, direction factor, clamp) and,
for comparison, ``Feedforward.message`` (the node's per-message path, two axes) — against the baseline measured in
the same run: one scalar ``numpy.interp`` on a 1801-point table (the cheapest lookup a controller could write with
numpy). Goals (issue 22): one axis ≤ 1.0 µs per call and below ``numpy.interp`` in the same run; a two-axis
message ≤ 3 µs.

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
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gimbal_friction.config.loader import render_parameter_file  # noqa: E402
from gimbal_friction.controller import load_feedforward  # noqa: E402

TARGET_US = 1.0          #: one axis, per call [µs] (and below numpy.interp)
TARGET_MESSAGE_US = 3.0  #: a two-axis message [µs]


def per_call_us(fn: Callable[[int], object], calls: int) -> float:
    """Wall time per call [µs] of ``fn(i)`` for i in range(calls)."""
    t0 = time.perf_counter()
    for i in range(calls):
        fn(i)
    return (time.perf_counter() - t0) / calls * 1e6


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
        ff2 = load_feedforward(two)
    finally:
        two.unlink()
    ff.update_temperature(-35.0, 0.0)
    ff2.update_temperature(-35.0, 0.0)
    grid = np.linspace(-60.0, 120.0, 1801)
    values = np.sin(grid / 30.0)
    temps = (-40.0 + (np.arange(1000) % 100)).tolist()
    vels = (0.035 * np.sin(np.arange(1000) / 7.0)).tolist()
    names = ['elevation', 'azimuth']

    workloads: dict[str, Callable[[int], object]] = {
        'numpy.interp scalar (baseline)': lambda i: np.interp(temps[i % 1000], grid, values),
        'Feedforward.torque_nm, one axis': lambda i: ff.torque_nm('elevation', vels[i % 1000], 1e-3 * (i % 1000)),
        'Feedforward.message, two axes': lambda i: ff2.message(names, [vels[i % 1000], -vels[i % 1000]],
                                                                1e-3 * (i % 1000)),
    }
    results: dict[str, list[float]] = {k: [] for k in workloads}
    for r in range(args.repeat):
        items = list(workloads.items())
        for name, fn in (items if r % 2 == 0 else items[::-1]):
            results[name].append(per_call_us(fn, args.calls))
    med = {k: statistics.median(v) for k, v in results.items()}
    base = med['numpy.interp scalar (baseline)']
    one = med['Feedforward.torque_nm, one axis']
    message = med['Feedforward.message, two axes']
    doc = {'per_call_us': med, 'ratio_to_numpy_interp': {k: v / base for k, v in med.items()},
           'target_us': TARGET_US, 'target_message_us': TARGET_MESSAGE_US,
           'pass': one <= TARGET_US and one < base, 'pass_message': message <= TARGET_MESSAGE_US}
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
    return 0


if __name__ == '__main__':
    sys.exit(main())
