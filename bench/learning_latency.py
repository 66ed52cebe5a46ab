"""Benchmark: the feedforward's latency with learning on against learning off, in the same run.

Each round runs, in turn (interleaved, to cancel drift on a shared machine), ``friction_feedforward`` as its own
process with the same learned correction loaded (a file of ``--rows-samples`` residual samples over every
temperature bin, speed octave and ±0.15 rad of travel, so every refit has real work: ~65 ms per step, seconds when
the ripple periods are searched again):

- ``plain``: learning off (the correction applied, nothing learned);
- ``learning``: learning on, refits in the default worker (``learning_fit_worker: process``);
- ``inline`` (``--kinds``): learning on, refits in the step on the executor thread (before 2026-12-02).

The driver and the measurement are those of ``bench/feedforward_latency.py`` (joint states at ``--rate`` Hz, one
joint, latency = receive − send time in this process); in every run it also publishes accepted estimator samples
(``/gimbal/friction/measured_detail``, ``--detail-rate`` Hz) at varying speeds, directions and positions, so the
learning nodes learn and refit all along and the plain one sees the same inputs. A tick "timed out" when its
feedforward came back later than ``--deadline-ms`` (default 2 ms = two ticks at 1 kHz) or never.

Prints per run and pooled per kind p50, p99, max, timed-out ticks, and the ratios learning/plain (and inline/plain)
of p50, p99 and timed-out ticks (goal ≤ 1.1×). Ratios, not absolute numbers, are the result. This is a benchmark,
not a test.

Run from the repository root:  ``.venv/bin/python bench/learning_latency.py [--duration 10] [--rounds 2]
[--kinds plain,learning,inline] [--json]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import feedforward_latency as fl

KINDS = ('plain', 'learning', 'inline')
RIPPLE_PERIOD_RAD = math.radians(2.2)
TRAVEL_RAD = 0.15


def correction_file(path: Path, n: int, seed: int = 1) -> None:
    """A learned correction of ``n`` residual samples of the packaged model's ``elevation`` (a level and a ripple of
    2.2 deg along the motion, every temperature bin), saved to ``path``."""
    from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity, save
    from gimbal_friction.physics.params import AxisParams

    rng = np.random.default_rng(seed)
    c = Correction(CorrectionSettings(), model_identity({fl.JOINT: AxisParams()}))
    v = rng.choice([-1.0, 1.0], n) * np.exp(rng.uniform(math.log(0.02), math.log(0.6), n))
    p = rng.uniform(-TRAVEL_RAD, TRAVEL_RAD, n)
    t = rng.uniform(-40.0, 60.0, n)
    m = np.full(n, 1.3e-3)
    r = np.sign(v) * (1e-4 + 1e-4 * np.sin(2 * np.pi * p / RIPPLE_PERIOD_RAD)) + rng.normal(0.0, 2e-5, n)
    c.add_residuals(fl.JOINT, t, v, p, r, m)
    c.settle(guarded=False)
    save(c, path)


def node_command(kind: str, log_dir: Path | None = None) -> list[str]:
    """The feedforward with the benchmark's correction (a copy per run: learning writes to it)."""
    log_dir = log_dir or Path(tempfile.gettempdir())
    exe = fl.BIN / 'friction_feedforward'
    cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', 'gimbal_friction.nodes.feedforward']
    own = log_dir / f'correction_{kind}_{len(list(log_dir.glob("correction_*.yaml")))}.yaml'
    shutil.copyfile(log_dir / 'correction.yaml', own)
    cmd += ['--ros-args', '--params-file', str(fl.PARAMS_FILE), '-p', f'diagnostics_period_s:={fl.DIAG_PERIOD_S}',
            '-p', f'correction_file:={own}', '-p', 'correction_publish_period_s:=1.0']
    if kind != 'plain':
        cmd += ['-p', 'learning_enabled:=true', '-p', 'learning_save_period_s:=5.0',
                '-p', f'learning_fit_worker:={"inline" if kind == "inline" else "process"}']
    return cmd


def varied_detail(self: Any) -> None:
    """One accepted estimator sample stamped now, at a speed, direction and position drawn anew (fl.Driver's)."""
    rng = getattr(self, '_bench_rng', None)
    if rng is None:
        rng = self._bench_rng = np.random.default_rng(2)
        self._bench_cols = [_fields().index(f) for f in ('velocity_rad_s', 'position_rad', 'friction_nm')]
    now = self.node.get_clock().now().nanoseconds
    data = self._detail.data
    data[self._detail_sec[0]], data[self._detail_sec[1]] = float(now // 10**9), float(now % 10**9)
    v = float(rng.choice([-1.0, 1.0]) * math.exp(rng.uniform(math.log(0.02), math.log(0.6))))
    p = float(rng.uniform(-TRAVEL_RAD, TRAVEL_RAD))
    iv, ip, i_f = self._bench_cols
    data[iv], data[ip] = v, p
    data[i_f] = math.copysign(fl.DETAIL_FRICTION_NM * (1.0 + 0.1 * math.sin(2 * math.pi * p / RIPPLE_PERIOD_RAD)), v)
    self.pub_detail.publish(self._detail)


def _fields() -> tuple[str, ...]:
    from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS
    return tuple(MEASUREMENT_FIELDS)


def timed_out(r: fl.RunResult, deadline_us: float) -> int:
    """Ticks whose feedforward came back later than the deadline, or never."""
    return r.lost + sum(1 for x in r.latencies_us if x > deadline_us)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--duration', type=float, default=10.0, help='send window per run [s] (default 10)')
    parser.add_argument('--rounds', type=int, default=2, help='rounds of the kinds (default 2)')
    parser.add_argument('--rate', type=float, default=1000.0, help='joint-state rate [Hz] (default 1000)')
    parser.add_argument('--warmup', type=float, default=0.5, help='discarded start of each window [s] (0.5)')
    parser.add_argument('--detail-rate', type=float, default=200.0, help='measured_detail samples per second [Hz]')
    parser.add_argument('--deadline-ms', type=float, default=2.0, help='a tick later than this timed out [ms] (2)')
    parser.add_argument('--rows-samples', type=int, default=40_000,
                        help='residual samples in the loaded correction (default 40000)')
    parser.add_argument('--kinds', default='plain,learning', help='comma-separated, of plain, learning, inline; '
                        'plain (the baseline) is required (default plain,learning)')
    parser.add_argument('--json', action='store_true', help='print one JSON document instead of the table')
    parser.add_argument('--logs', type=Path, default=None, help="keep the nodes' logs and files in this folder")
    args = parser.parse_args(argv)
    kinds = [k.strip() for k in args.kinds.split(',') if k.strip()]
    if 'plain' not in kinds or len(kinds) < 2 or not set(kinds) <= set(KINDS) or len(set(kinds)) != len(kinds):
        parser.error("--kinds: 'plain' and at least one of learning, inline, each once")
    if args.duration < args.warmup + 2.0 or args.rounds < 1 or args.rate <= 0 or args.detail_rate <= 0:
        parser.error('need --duration >= --warmup + 2 s, --rounds >= 1, --rate > 0, --detail-rate > 0')
    fl.node_command = node_command            # (the latency benchmark's runs, with these nodes)
    fl.Driver.send_detail = varied_detail     # type: ignore[method-assign]

    from domain_coordinator import domain_id

    with domain_id() as did, tempfile.TemporaryDirectory(prefix='learning_latency_') as tmp:
        log_dir = Path(tmp) if args.logs is None else args.logs
        log_dir.mkdir(parents=True, exist_ok=True)
        correction_file(log_dir / 'correction.yaml', args.rows_samples)
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   ROS_LOG_DIR=str(log_dir / 'roslog'), PYTHONUNBUFFERED='1')
        os.environ.update(ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                          ROS_LOG_DIR=str(log_dir / 'roslog'))
        config = {'kinds': kinds, 'rounds': args.rounds, 'duration_s': args.duration, 'rate_hz': args.rate,
                  'detail_rate_hz': args.detail_rate, 'deadline_ms': args.deadline_ms,
                  'rows_samples': args.rows_samples, 'cpus': os.cpu_count(), 'loadavg_start': os.getloadavg()}
        results: list[fl.RunResult] = []
        try:
            for rnd in range(1, args.rounds + 1):
                for kind in kinds:
                    if not args.json:
                        print(f'round {rnd}: {kind} ...', file=sys.stderr, flush=True)
                    results.append(fl.run_once(kind, rnd, did, env, log_dir, args.duration, args.rate, args.warmup,
                                               1e9, args.detail_rate))
        except fl.BenchError as err:
            print(f'learning_latency: error: {err}', file=sys.stderr)
            return 1
        config['loadavg_end'] = os.getloadavg()
    deadline_us = 1e3 * args.deadline_ms
    runs: list[dict[str, Any]] = [{'kind': r.kind, 'round': r.round, 'sent': r.sent, 'lost': r.lost, 'p50_us': r.p50_us,
             'p99_us': r.p99_us, 'max_us': r.max_us, 'timed_out': timed_out(r, deadline_us),
             'node_cpu_pct': r.node_cpu_pct, 'disturbed': r.disturbed} for r in results]
    pooled = {}
    for kind in kinds:
        mine = [r for r in results if r.kind == kind]
        lat = sorted(x for r in mine for x in r.latencies_us)
        pooled[kind] = {'p50_us': fl.percentile(lat, 50), 'p99_us': fl.percentile(lat, 99),
                        'max_us': lat[-1] if lat else math.nan,
                        'timed_out': sum(timed_out(r, deadline_us) for r in mine), 'sent': sum(r.sent for r in mine)}
    base = pooled['plain']
    ratios = {kind: {'p50': pooled[kind]['p50_us'] / base['p50_us'], 'p99': pooled[kind]['p99_us'] / base['p99_us'],
                     'timed_out': (pooled[kind]['timed_out'] / base['timed_out'] if base['timed_out']
                                   else (math.inf if pooled[kind]['timed_out'] else 1.0))}
              for kind in kinds if kind != 'plain'}
    if args.json:
        print(json.dumps({'config': config, 'runs': runs, 'pooled': pooled, 'ratios_vs_plain': ratios}, indent=2))
        return 0
    print(f"learning latency: {args.rounds} round(s) x {args.duration:g} s at {args.rate:g} Hz, "
          f"{args.detail_rate:g} samples/s learned, correction of {args.rows_samples} samples; "
          f"timed out = later than {args.deadline_ms:g} ms or lost; load {config['loadavg_start'][0]:.2f} -> "
          f"{config['loadavg_end'][0]:.2f}")
    print(f"{'run':<14}{'p50 us':>9}{'p99 us':>10}{'max us':>11}{'timed out':>11}{'lost':>6}{'cpu %':>7}")
    for d in runs:
        print(f"{d['kind'] + ' ' + str(d['round']):<14}{d['p50_us']:>9.0f}{d['p99_us']:>10.0f}{d['max_us']:>11.0f}"
              f"{d['timed_out']:>11}{d['lost']:>6}{d['node_cpu_pct']:>7.0f}{'  disturbed' if d['disturbed'] else ''}")
    for kind, p in pooled.items():
        print(f"{kind + ' all':<14}{p['p50_us']:>9.0f}{p['p99_us']:>10.0f}{p['max_us']:>11.0f}{p['timed_out']:>11}")
    for kind, q in ratios.items():
        ok = all(x <= 1.1 for x in q.values())
        print(f"{kind}/plain: p50 {q['p50']:.3f}x, p99 {q['p99']:.3f}x, timed-out ticks {q['timed_out']:.3f}x "
              f"(goal <= 1.1x: {'met' if ok else 'NOT met'})")
    return 0


if __name__ == '__main__':
    sys.exit(main())
