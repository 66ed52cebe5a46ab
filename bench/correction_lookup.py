"""Per-call cost of the learned correction's scalar lookup (``Correction.split_nm``) in the caller's process.

What a feedforward pays per joint and tick on top of the model: the correction's parts along the motion and
independent of it at a temperature, speed and reference position, bounded by the model torque — a speed profile
alone, and with the position terms (ripple at two periods, trend) — against two baselines measured in the same run:
an empty Python call with the same arguments (the call overhead) and one scalar ``numpy.interp`` on a 1801-point
table. Aim: ≤ 0.3 µs per lookup at a held temperature (a controller's calls between two temperature samples).

A benchmark, not a test: the machine is shared, so only the ratios measured in one run compare. Median of
``--repeat`` rounds of ``--calls`` calls each.

Run from the repository root: ``.venv/bin/python bench/correction_lookup.py [--calls 200000] [--repeat 5] [--json]``
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from inprocess_call import interleaved_medians, learned_correction  # noqa: E402  # the feedforward bench's loop

from gimbal_friction.feedforward.correction import Correction, model_identity  # noqa: E402


def learned(positions: bool) -> Correction:
    """The in-process bench's learned correction of one joint (speed profiles; with ``positions`` a ripple at two
    periods and a trend)."""
    return learned_correction(model_identity({'elevation': {}}), ['elevation'], positions)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--calls', type=int, default=200_000)
    ap.add_argument('--repeat', type=int, default=5)
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args(argv)

    flat = learned(positions=False)
    ripple = learned(positions=True)
    grid = np.linspace(-60.0, 120.0, 1801)
    values = np.sin(grid / 30.0)
    temps = [-40.0] * 1000                      # a held temperature (calls between two temperature samples)
    vels = (0.035 * np.sin(np.arange(1000) / 7.0)).tolist()
    pos = (0.2 * np.sin(np.arange(1000) / 11.0)).tolist()

    def empty(joint: str, t: float, v: float, p: float, m: float) -> float:
        return 0.0

    workloads: dict[str, Callable[[int], object]] = {
        'empty call (baseline)': lambda i: empty('elevation', temps[i % 1000], vels[i % 1000], pos[i % 1000], 3e-3),
        'numpy.interp scalar (baseline)': lambda i: np.interp(temps[i % 1000], grid, values),
        'split_nm, speed profile': lambda i: flat.split_nm('elevation', temps[i % 1000], vels[i % 1000],
                                                           pos[i % 1000], 3e-3),
        'split_nm, with position terms': lambda i: ripple.split_nm('elevation', temps[i % 1000], vels[i % 1000],
                                                                   pos[i % 1000], 3e-3),
    }
    med = interleaved_medians(workloads, args.repeat, args.calls)
    call = med['empty call (baseline)']
    doc = {'per_call_us': med, 'net_of_call_overhead_us': {k: v - call for k, v in med.items()},
           'ratio_to_numpy_interp': {k: v / med['numpy.interp scalar (baseline)'] for k, v in med.items()}}
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        for k, v in med.items():
            print(f'{k:34s} {v:7.3f} us/call  (net of the call: {v - call:6.3f} us; '
                  f'{doc["ratio_to_numpy_interp"][k]:5.2f}x numpy.interp)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
