"""Per-call cost of the learned correction's scalar lookup (``Correction.along_nm``) in the caller's process.

What a feedforward pays per joint and tick on top of the model: the correction at a temperature, direction and
reference position, bounded by the model torque — without a position map and with one (64 bins) — against two
baselines measured in the same run: an empty Python call with the same arguments (the call overhead) and one scalar
``numpy.interp`` on a 1801-point table. Aim: ≤ 0.3 µs per lookup without a map.

A benchmark, not a test: the machine is shared, so only the ratios measured in one run compare. Median of
``--repeat`` rounds of ``--calls`` calls each.

Run from the repository root: ``.venv/bin/python bench/correction_lookup.py [--calls 200000] [--repeat 5] [--json]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from inprocess_call import interleaved_medians  # noqa: E402  # the same timing loop as the feedforward bench

from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity  # noqa: E402


def learned(settings: CorrectionSettings) -> Correction:
    """A correction with a value, a speed term and (with a position map) a ripple in every cell (so no lookup takes
    a shortcut)."""
    c = Correction(settings, model_identity({'elevation': {}}))
    for j in c.identity.joints:
        c.values_nm[j][:] = 1e-5 * np.sin(np.arange(c.values_nm[j].size))
        c.speed_nm[j][:] = 1e-6 * np.cos(np.arange(c.speed_nm[j].size))
        c.speed_ref[j][:] = 1.0
        if settings.position_bins:
            c.ripple[j][:] = 0.05 * np.sin(np.arange(c.ripple[j].size))
    c.rebuild()
    return c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--calls', type=int, default=200_000)
    ap.add_argument('--repeat', type=int, default=5)
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args(argv)

    flat = learned(CorrectionSettings())
    ripple = learned(CorrectionSettings(position_bins=64, position_period_rad=math.radians(3.4)))
    grid = np.linspace(-60.0, 120.0, 1801)
    values = np.sin(grid / 30.0)
    temps = (-40.0 + 0.7 * (np.arange(1000) % 100)).tolist()
    vels = (0.035 * np.sin(np.arange(1000) / 7.0)).tolist()
    pos = (0.2 * np.sin(np.arange(1000) / 11.0)).tolist()

    def empty(joint: str, t: float, v: float, p: float, m: float) -> float:
        return 0.0

    workloads: dict[str, Callable[[int], object]] = {
        'empty call (baseline)': lambda i: empty('elevation', temps[i % 1000], vels[i % 1000], pos[i % 1000], 3e-3),
        'numpy.interp scalar (baseline)': lambda i: np.interp(temps[i % 1000], grid, values),
        'along_nm, no position map': lambda i: flat.along_nm('elevation', temps[i % 1000], vels[i % 1000],
                                                             pos[i % 1000], 3e-3),
        'along_nm, 64-bin position map': lambda i: ripple.along_nm('elevation', temps[i % 1000], vels[i % 1000],
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
