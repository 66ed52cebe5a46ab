"""Run the closed-loop study (default or short) under several feedforward wirings and print the numbers, the goals
of issue 9 and the wall time.

Not a test: prints, asserts nothing. The wall time is put beside the simulated seconds of the study (simulated
run-seconds per wall second), since absolute times drift on a shared machine.

Wirings (the ``friction_feedforward`` settings the study's cases (b), (c) and (d) run with):

- ``defaults``: the packaged defaults (``velocity_source: measured``, ``velocity_threshold_rad_s: 0.005``);
- ``v_th 0.002``: the measured velocity with a narrower smooth sign;
- ``reference``: the reference joint velocity (``/gimbal/reference_velocity``), v_th 0.005;
- ``recommended``: the reference joint velocity and v_th 0.002.

Usage (repository root, project venv)::

    .venv/bin/python bench/sim_study.py                       # default study, every wiring (about a minute)
    .venv/bin/python bench/sim_study.py --wiring recommended  # one wiring
    .venv/bin/python bench/sim_study.py --short               # the short CI profile
    .venv/bin/python bench/sim_study.py --json                # one JSON document
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.runs.loop_study import load_study_inputs, study
from gimbal_friction.sim import goal_checks
from gimbal_friction.sim.study import FeedforwardSetup

WIRINGS = {
    'defaults': None,
    'v_th 0.002': FeedforwardSetup(FeedforwardSettings(velocity_threshold_rad_s=0.002), 'measured'),
    'reference': FeedforwardSetup(FeedforwardSettings(), 'reference'),
    'recommended': FeedforwardSetup(FeedforwardSettings(velocity_threshold_rad_s=0.002), 'reference'),
}


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
    parser.add_argument('--wiring', action='append', choices=list(WIRINGS), help='wiring(s) to run (default all)')
    parser.add_argument('--json', action='store_true', help='print one JSON document')
    args = parser.parse_args(argv)
    base = load_study_inputs()
    out: dict[str, Any] = {}
    for name in args.wiring or list(WIRINGS):
        ff = WIRINGS[name]
        inputs = base if ff is None else base._replace(feedforward=ff)
        t0 = time.perf_counter()
        res = study(inputs, short=args.short, progress=_progress)
        wall = time.perf_counter() - t0
        sys.stderr.write('\n')
        run_seconds = sum(r['duration_s'] for r in res.records)
        goals = goal_checks(res.records)
        out[name] = {'records': res.records, 'goals': goals, 'notes': res.notes, 'wall_s': wall,
                     'stages_s': res.wall_s, 'simulated_run_seconds': run_seconds}
        if args.json:
            continue
        s = inputs.feedforward
        print(f'=== wiring {name}: velocity_source {s.velocity_source}, v_th {s.settings.velocity_threshold_rad_s:g} '
              f'rad/s; {"short" if args.short else "default"} study')
        print(f'wall time {wall:.1f} s for {run_seconds:.0f} simulated run-seconds '
              f'({run_seconds / wall:.1f} run-s per wall-s); stages: ' +
              ', '.join(f'{k} {v:.1f} s' for k, v in res.wall_s.items()))
        for note in res.notes:
            print('note:', note)
        print(_table(res.records, 'rate_error_rms_rad_s', 1e3, 'mrad/s'))
        print(_table(res.records, 'reversal_error_peak_rad', 1e3, 'mrad'))
        print(_table(res.records, 'position_error_rms_rad', 1e6, 'urad'))
        print(f'current margin: min {min(r["current_margin"] for r in res.records):.3f}')
        met = sum(g['met'] for g in goals)
        print(f'goals: {met} of {len(goals)} met')
        for g in goals:
            if not g['met']:
                print(f'  NOT met {g["goal"]:14s} {g["profile"]:9s} {g["temperature_c"]:+5.0f} degC  value '
                      f'{g["value"]:+8.3f} target {g["target"]:g}')
        print()
    if args.json:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
