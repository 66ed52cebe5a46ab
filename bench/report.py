"""One table of every speed figure of issue 22, each next to its reference measured in the same run.

Runs the benchmark scripts of ``bench/`` one after another (each as a subprocess with ``--json``), then prints one
markdown table -- figure | measured | reference (same run) | ratio | goal | met? -- with the date, the machine
(CPUs, CPU model, load average before and after) and the command, and writes it to ``bench/RESULTS.md``.

Run from the repository root::

    .venv/bin/python bench/report.py            # the full report (about 5 minutes on 2 cores)
    .venv/bin/python bench/report.py --quick    # fewer rounds, smaller inputs (about 1.5 minutes): a smoke run

Times are wall-clock seconds [s] and microseconds [µs]; memory in MiB. Nothing here asserts a time: the table says
which goals this run met on this machine. A load average above 1.5 (another job on the machine) is flagged in the
output because every ratio then moves.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
RESULTS = BENCH / 'RESULTS.md'
CHUNK_ROWS = 1 << 18   #: rows per chunk of the residual-log reader (gimbal_friction.refit.logs.CHUNK_ROWS)
BUSY_LOAD = 1.5   #: a 1-minute load average above this is flagged (2-core machine: another job is running)


def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo (platform.processor() when there is none)."""
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown CPU'


def run_json(script: str, args: Sequence[str]) -> tuple[dict[str, Any], float]:
    """Run ``bench/<script>`` with ``--json``: (its JSON document, wall time [s]). Its stderr goes to ours."""
    cmd = [sys.executable, str(BENCH / script), *args, '--json']
    print(f'report: {" ".join(cmd[1:])}', file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    out = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, text=True, check=False)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        msg = f'report: {script} exited with {out.returncode}; run it alone to see why: {" ".join(cmd)}'
        raise SystemExit(msg)
    return json.loads(out.stdout), seconds


def yes(ok: bool) -> str:
    return 'yes' if ok else '**no**'


def replay_rows(doc: dict[str, Any]) -> list[list[str]]:
    rows = []
    for bag in doc['bags']:
        name = Path(bag['bag']).name
        res = bag['results']
        ratio = min(bag['ratios']['replay'], bag['paired_ratios']['replay'])
        rows.append([f'`replay` of {name} ({bag["messages"]:,} messages), median of {bag["repeat"]}',
                     f'{res["replay"]["median_s"]:.3f} s ({res["replay"]["msgs_per_s"] / 1e3:.0f} k msg/s)',
                     (f'rosbags read+decode {res["decode"]["median_s"]:.3f} s '
                     f'({res["decode"]["msgs_per_s"] / 1e3:.0f} k msg/s)'),
                     (f'{ratio:.2f}× (medians {bag["ratios"]["replay"]:.2f}×, '
                     f'paired {bag["paired_ratios"]["replay"]:.2f}×)'),
                     f'≥ {bag["target"]:g}×', yes(ratio >= bag['target'])])
    return rows


def refit_rows(doc: dict[str, Any]) -> list[list[str]]:
    r = doc['rows'][-1]
    n = f'{r["n"]:.0e}'.replace('e+0', 'e').replace('1e', '10^')
    return [
        [f'refit of {n} rows in memory: accumulation', f'{r["accumulate_s"]:.3f} s',
         f'one np.mean pass {r["mean_s"]:.4f} s',
         f'{r["accumulate_ratio_to_mean"]:.0f}×', '≤ 0.3 s', yes(r['accumulate_s'] <= 0.3)],
        [f'refit of {n} rows in memory: total (`refit_model`)', f'{r["refit_model_s"]:.3f} s',
         f'one np.mean pass {r["mean_s"]:.4f} s', f'{r["ratio_to_mean"]:.0f}×', '≤ 0.5 s',
         yes(r['refit_model_s'] <= 0.5)],
    ]


def memory_rows(doc: dict[str, Any]) -> list[list[str]]:
    first, last = doc['rows'][0], doc['rows'][-1]
    growth = last['increment_mib'] / max(first['increment_mib'], 1e-9)
    scale = last['rows'] / first['rows']
    return [[f'reading a residual log in chunks: memory increment at {first["rows"]:,} → {last["rows"]:,} rows',
             (f'{first["increment_mib"]:.1f} → {last["increment_mib"]:.1f} MiB '
             f'({last["rows_per_s"] / 1e6:.2f} M rows/s)'),
             f'the rows held whole: {first["rows_whole_mib"]:.0f} → {last["rows_whole_mib"]:.0f} MiB',
             f'{growth:.2f}× for {scale:.0f}× the rows',
             f'flat (≤ 1.5× for {scale:.0f}× the rows, both above one {CHUNK_ROWS:,}-row chunk)', yes(growth <= 1.5)]]


def inprocess_rows(doc: dict[str, Any]) -> list[list[str]]:
    us = doc['per_call_us']
    base = us['numpy.interp scalar (baseline)']
    one = us['Feedforward.torque_nm, one axis']
    msg = us['Feedforward.message, two axes']
    learned = us['torque_nm, learned correction']
    return [
        ['in-process `Feedforward.torque_nm`, one axis', f'{one:.2f} µs', f'scalar numpy.interp {base:.2f} µs',
         f'{one / base:.2f}×', f'≤ {doc["target_us"]:g} µs and < numpy.interp',
         yes(one <= doc['target_us'] and one < base)],
        ['in-process `Feedforward.message`, two axes', f'{msg:.2f} µs', f'scalar numpy.interp {base:.2f} µs',
         f'{msg / base:.2f}×', f'≤ {doc["target_message_us"]:g} µs', yes(msg <= doc['target_message_us'])],
        ['in-process `Feedforward.torque_nm`, one axis, learned correction', f'{learned:.2f} µs',
         f'scalar numpy.interp {base:.2f} µs', f'{learned / base:.2f}×', '≤ numpy.interp', yes(learned <= base)],
    ]


def latency_rows(doc: dict[str, Any]) -> list[list[str]]:
    summ = doc['summary']
    q = summ['ratios']['feedforward']
    ff, relay = summ['nodes']['feedforward'], summ['nodes']['relay']
    p50s = [pr['ratio_p50'] for pr in q['per_round']]
    p99s = [pr['ratio_p99'] for pr in q['per_round']]
    n = len(p50s)
    rate = doc['config'].get('rate_hz', 1000.0)
    return [
        [f'feedforward node p50 latency, each of {n} rounds', f'{ff["p50_us"]:.0f} µs pooled',
         f'bare rclpy relay {relay["p50_us"]:.0f} µs pooled', ' / '.join(f'{x:.2f}×' for x in p50s),
         '≤ 1.2× in every round', yes(all(x <= 1.2 for x in p50s))],
        [f'feedforward node p99 latency, each of {n} rounds', f'{ff["p99_us"]:.0f} µs pooled',
         f'bare rclpy relay {relay["p99_us"]:.0f} µs pooled', ' / '.join(f'{x:.2f}×' for x in p99s),
         '≤ 1.5× in every round', yes(all(x <= 1.5 for x in p99s))],
        [f'feedforward node messages lost at {rate:g} Hz', f'{ff["lost"]} of {ff["sent"]}',
         f'relay {relay["lost"]} of {relay["sent"]}', '–', '0', yes(ff['lost'] == 0)],
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='fewer rounds and smaller inputs (a smoke run, ~1.5 min; not the figures to quote)')
    parser.add_argument('--out', type=Path, default=RESULTS, help=f'markdown file to write (default {RESULTS.name})')
    args = parser.parse_args(argv)
    if args.quick:
        plan = [
            ('replay_throughput.py', ['--repeat', '1', '--sample-only'], replay_rows),
            ('refit_scaling.py', ['--sizes', '10000000', '--exact-max', '0', '--repeat', '1'], refit_rows),
            ('refit_memory.py', ['--sizes', '300000,1000000'], memory_rows),
            ('inprocess_call.py', ['--calls', '50000', '--repeat', '3'], inprocess_rows),
            ('feedforward_latency.py', ['--rounds', '4', '--duration', '3', '--no-drops'], latency_rows),
        ]
    else:
        plan = [
            ('replay_throughput.py', ['--repeat', '3'], replay_rows),
            ('refit_scaling.py', ['--sizes', '10000000', '--exact-max', '0', '--repeat', '3'], refit_rows),
            ('refit_memory.py', ['--sizes', '300000,3000000'], memory_rows),
            ('inprocess_call.py', [], inprocess_rows),
            ('feedforward_latency.py', ['--rounds', '4', '--duration', '10', '--no-drops'], latency_rows),
        ]
    load0 = os.getloadavg()
    started = dt.datetime.now(dt.timezone.utc)
    t0 = time.perf_counter()
    rows: list[list[str]] = []
    timings = []
    for script, extra, to_rows in plan:
        doc, seconds = run_json(script, extra)
        rows += to_rows(doc)
        timings.append(f'{script} {seconds:.0f} s')
    load1 = os.getloadavg()
    total = time.perf_counter() - t0
    head = ['figure', 'measured', 'reference (same run)', 'ratio', 'goal', 'met?']
    lines = [
        '# Speed figures of issue 22' + (' (--quick smoke run: not the figures to quote)' if args.quick else ''),
        '',
        (f'Regenerate with `.venv/bin/python bench/report.py{" --quick" if args.quick else ""}` '
        f'(written by it; do not edit by hand).'),
        '',
        f'- date: {started:%Y-%m-%d %H:%M} UTC; took {total:.0f} s ({", ".join(timings)})',
        (f'- machine: {os.cpu_count()} CPUs ({cpu_model()}), Python {platform.python_version()}, {platform.system()} '
        f'{platform.release()}'),
        (f'- load average (1/5/15 min): before {load0[0]:.2f}/{load0[1]:.2f}/{load0[2]:.2f}, '
        f'after {load1[0]:.2f}/{load1[1]:.2f}/{load1[2]:.2f}'),
    ]
    if max(load0[0], load1[0]) > BUSY_LOAD:
        lines.append(f'- **the machine was busy** (1-minute load above {BUSY_LOAD:g} on {os.cpu_count()} CPUs): '
                     'other jobs shared the cores, so the ratios moved; rerun on a quiet machine before quoting')
    met = sum(r[-1] == 'yes' for r in rows)
    lines += ['', f'{met} of {len(rows)} goals met in this run.', '',
              '| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    lines += ['| ' + ' | '.join(r) + ' |' for r in rows]
    lines += ['', ('Ratios: replay = rosbags decode time / replay time (the smaller of the ratio of the medians and '
              'the median of the per-round ratios); refit = time / one np.mean pass over the same 10^7 values; '
              'in-process = per-call time / a scalar numpy.interp; latency = node / relay per round (each round runs '
              'the relay and the node back to back). How each script measures: bench/README.md.'), '']
    text = '\n'.join(lines)
    print(text)
    args.out.write_text(text, encoding='utf-8')
    print(f'report: wrote {args.out}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
