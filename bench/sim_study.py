"""Run the closed-loop study (default or short) and print its numbers, the goals of issue 9 and the wall time.

Not a test: prints, asserts nothing. The wall time is put beside the simulated seconds of the study (simulated
run-seconds per wall second), since absolute times drift on a shared machine.

Usage (repository root, project venv)::

    .venv/bin/python bench/sim_study.py                 # default study (3 profiles x 5 cases x 6 plateaus)
    .venv/bin/python bench/sim_study.py --short         # the short CI profile
    .venv/bin/python bench/sim_study.py --extra         # also the optional feedforward_reference case
    .venv/bin/python bench/sim_study.py --json          # one JSON document (records, goals, notes, timing)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

from gimbal_friction.sim import CASES, DEFAULT_TEMPERATURES, PROFILES, SimConfig, goal_checks, run_study


def _progress(stage: str, fraction: float) -> None:
    sys.stderr.write(f'\r{100.0 * fraction:5.1f} %  {stage:<70s}')
    sys.stderr.flush()


def _table(records: list[dict[str, Any]], key: str, scale: float, unit: str) -> str:
    temps = sorted({r['temperature_c'] for r in records})
    lines = []
    for prof in dict.fromkeys(r['profile'] for r in records):
        lines.append(f'{prof}: {key} [{unit}]')
        lines.append(f'  {"case":22s}' + ''.join(f'{t:>+9.0f}' for t in temps))
        for case in dict.fromkeys(r['case'] for r in records if r['profile'] == prof):
            row = {r['temperature_c']: r[key] for r in records if r['profile'] == prof and r['case'] == case}
            lines.append(f'  {case:22s}' + ''.join(f'{row[t] * scale:9.3f}' for t in temps))
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--short', action='store_true', help='short CI durations')
    parser.add_argument('--extra', action='store_true', help='also run the feedforward_reference case')
    parser.add_argument('--json', action='store_true', help='print one JSON document')
    args = parser.parse_args(argv)
    cases = list(CASES) + (['feedforward_reference'] if args.extra else [])
    t0 = time.perf_counter()
    res = run_study(SimConfig(), short=args.short, cases=cases, progress=_progress)
    wall = time.perf_counter() - t0
    sys.stderr.write('\n')
    cfg = res.config
    run_seconds = sum(r['duration_s'] for r in res.records)
    goals = goal_checks(res.records)
    if args.json:
        doc = {'records': res.records, 'goals': goals, 'notes': res.notes, 'wall_s': wall, 'stages_s': res.wall_s,
               'simulated_run_seconds': run_seconds}
        print(json.dumps(doc, indent=1))
        return 0
    print(f'study: {"short" if args.short else "default"}; profiles {", ".join(PROFILES)}; '
          f'plateaus {", ".join(f"{t:g}" for t in DEFAULT_TEMPERATURES)} degC; durations '
          f'{cfg.tracking_duration_s:g}/{cfg.scan_duration_s:g}/{cfg.pointing_duration_s:g} s')
    print(f'wall time {wall:.1f} s for {run_seconds:.0f} simulated run-seconds '
          f'({run_seconds / wall:.1f} run-s per wall-s); stages: ' +
          ', '.join(f'{k} {v:.1f} s' for k, v in res.wall_s.items()))
    for note in res.notes:
        print('note:', note)
    print()
    print(_table(res.records, 'rate_error_rms_rad_s', 1e3, 'mrad/s'))
    print()
    print(_table(res.records, 'position_error_rms_rad', 1e6, 'urad'))
    print()
    print(_table(res.records, 'reversal_error_peak_rad', 1e6, 'urad'))
    print()
    print(_table(res.records, 'current_margin', 1.0, '-'))
    print()
    print('goals (value: reduction for c_vs_*, ratio for d_near_e_cold and c_reversal):')
    for g in goals:
        print(f'  {g["goal"]:14s} {g["profile"]:9s} {g["temperature_c"]:+5.0f} degC  value {g["value"]:+8.3f} '
              f'target {g["target"]:g}  {"met" if g["met"] else "NOT met"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
