#!/usr/bin/env python3
"""Peak memory of reading a residual log for a refit, against the number of rows: flat, not linear.

For each size, a synthetic residual log of that many ``residual_detail`` rows (one axis, chamber plateaus, 1 kHz)
is written, then read the way ``gimbal-friction refit`` reads it (``tools.refit_cmd.read_stats``: rows streamed in
chunks, sufficient statistics accumulated per chunk) in a fresh process whose peak resident memory is reported.
The references, measured in the same run: the peak of a process that imports the same modules and reads nothing,
and the size the rows would take in memory if read whole (13 columns). The increment over the import-only process
should stay the same whatever the number of rows. Linux (``VmHWM`` of ``/proc/self/status``).

    .venv/bin/python bench/refit_memory.py                       # 1e5, 1e6 and 3e6 rows (writing takes a while)
    .venv/bin/python bench/refit_memory.py --sizes 100000,400000 --json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gimbal_friction.recording.cdr import float64_multi_array_cdr_rows, split_rows
from gimbal_friction.recording.residual_log import ResidualLogWriter
from gimbal_friction.recording.topics import FLOAT64_MULTI_ARRAY_TYPE, RESIDUAL_DETAIL
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS

ROOT = Path(__file__).resolve().parents[1]
BATCH = 100_000
CHILD = """
import sys, threading, time
sys.path.insert(0, {root!r})
from gimbal_friction.refit.logs import read_stats
from pathlib import Path


def status(key):
    with open('/proc/self/status') as f:
        return next(int(line.split()[1]) for line in f if line.startswith(key + ':'))


peak_anon = [status('RssAnon')]
done = threading.Event()


def sample():  # the high-water mark of anonymous memory (the kernel keeps one of all pages only)
    while not done.wait(0.005):
        peak_anon[0] = max(peak_anon[0], status('RssAnon'))


watcher = threading.Thread(target=sample, daemon=True)
watcher.start()
t0 = time.perf_counter()
stats = read_stats([Path(sys.argv[1])]) if len(sys.argv) > 1 else {{}}
dt = time.perf_counter() - t0
done.set()
watcher.join()
peak_anon[0] = max(peak_anon[0], status('RssAnon'))
rows = sum(a.rows for a in stats.values())
print(rows, dt, status('VmHWM'), peak_anon[0])
"""


def write_log(folder: Path, rows: int) -> None:
    """A residual log of ``rows`` rows of axis ``elevation``: six plateaus, both directions, 1 kHz stamps."""
    rng = np.random.default_rng(rows)
    col = {name: k for k, name in enumerate(RESIDUAL_FIELDS)}
    with ResidualLogWriter(folder, flush_interval_s=None) as writer:
        for a in range(0, rows, BATCH):
            k = np.arange(a, min(a + BATCH, rows))
            data = np.zeros((k.size, len(RESIDUAL_FIELDS)))
            data[:, col['stamp_s']] = k / 1000.0
            data[:, col['temperature_c']] = -40.0 + 20.0 * np.minimum(k * 6 // rows, 5) + rng.normal(0, 0.05, k.size)
            v = np.where((k // 5000) % 2 == 0, 1.0, -1.0) * 0.0349
            data[:, col['velocity_rad_s']] = v
            data[:, col['measured_nm']] = np.sign(v) * (2e-3 + rng.normal(0.0, 1e-4, k.size))
            data[:, col['torque_constant_nm_per_a']] = 0.05
            datas = split_rows(float64_multi_array_cdr_rows(data, 'elevation'))
            writer.write_raw_many([(RESIDUAL_DETAIL, FLOAT64_MULTI_ARRAY_TYPE)], np.zeros(k.size, dtype=np.int64),
                                  1_000_000_000 + k * 1_000_000, datas)


def child(*args: str) -> tuple[int, float, float, float]:
    """(rows read, seconds, peak RSS [MiB], peak anonymous RSS [MiB]) of a fresh process reading the log ``args``
    (none: import only). The peak RSS counts the pages of the log files the reader maps (file-backed: the page
    cache, given back under pressure); the anonymous peak is sampled every 5 ms."""
    out = subprocess.run([sys.executable, '-c', CHILD.format(root=str(ROOT)), *args], check=True,
                         capture_output=True, text=True).stdout.split()
    return int(out[0]), float(out[1]), int(out[2]) / 1024.0, int(out[3]) / 1024.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--sizes', default='100000,1000000,3000000', help='comma-separated row counts')
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory(prefix='refit_memory_') as tmp:
        for rows in (int(x) for x in args.sizes.split(',')):
            folder = Path(tmp) / f'log_{rows}'
            t0 = time.perf_counter()
            write_log(folder, rows)
            print(f'wrote {rows} rows in {time.perf_counter() - t0:.1f} s', file=sys.stderr)
            _, _, base_mib, base_anon = child()
            got, seconds, peak_mib, anon_mib = child(str(folder))
            whole_mib = rows * (8 * 12 + 1 + 4 * 9) / 2**20   # 12 float64 columns, int8, joint name '<U9'
            log_mib = sum(p.stat().st_size for p in folder.iterdir()) / 2**20
            results.append({'rows': rows, 'rows_read': got, 'read_s': seconds, 'log_mib': log_mib,
                            'peak_rss_mib': peak_mib, 'import_only_rss_mib': base_mib,
                            'peak_anon_mib': anon_mib, 'import_only_anon_mib': base_anon,
                            'increment_mib': anon_mib - base_anon, 'rows_whole_mib': whole_mib,
                            'rows_per_s': got / seconds})
    if args.json:
        print(json.dumps({'rows': results}, indent=1))
        return 0
    print('peak resident memory of reading a residual log for a refit (fresh process each; same run)')
    print('anon: anonymous memory (its own pages); increment: anon peak over the import-only process; whole: '
          'the rows held at once; RSS also counts the mapped log pages')
    print(f'{"rows":>9} {"log [MiB]":>9} {"read [s]":>9} {"rows/s":>9} {"RSS [MiB]":>10} {"anon [MiB]":>10} '
          f'{"import anon":>11} {"increment":>10} {"whole [MiB]":>12} {"incr/whole":>10}')
    for r in results:
        print(f'{r["rows"]:>9} {r["log_mib"]:>9.1f} {r["read_s"]:>9.2f} {r["rows_per_s"]:>9.0f} '
              f'{r["peak_rss_mib"]:>10.1f} {r["peak_anon_mib"]:>10.1f} {r["import_only_anon_mib"]:>11.1f} '
              f'{r["increment_mib"]:>10.1f} {r["rows_whole_mib"]:>12.1f} '
              f'{r["increment_mib"] / r["rows_whole_mib"]:>10.2f}')
    first, last = results[0], results[-1]
    print(f'{last["rows"] / first["rows"]:.0f}x the rows: increment {first["increment_mib"]:.1f} -> '
          f'{last["increment_mib"]:.1f} MiB ({last["increment_mib"] / max(first["increment_mib"], 1e-9):.2f}x)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
