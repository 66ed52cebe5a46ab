"""Throughput of ``gimbal-friction replay`` against the decode limit of the same bag, measured in the same run.

Three workloads over one bag (default ``bags/chamber_sample``), repeated ``--repeat`` times, interleaved (the order
is reversed on every other round so that neither side always runs on a warm or a cold machine):

- ``decode``: the limit. ``rosbags`` ``AnyReader`` opens the bag and ``typestore.deserialize_cdr`` decodes every
  message (what any reader of the bag has to pay);
- ``replay``: ``replay_bag(bag, out_dir)`` end to end, with the defaults of ``gimbal-friction replay`` (parameters,
  the three nodes' logic, the residual log with the input topics copied in);
- ``replay --no-inputs`` (with ``--no-inputs``): the same without copying the input topics.

Throughput = bag messages / wall time [msg/s] (the same numerator for every workload); the median over the rounds
is reported, and replay / decode of those medians, against the target ratio (``--target``, default 0.9): PASS or
MISS. Also a per-stage breakdown of the replay (medians over the rounds), taken from ``replay_bag``'s progress
reports: setup (parameters, opening the bag), reading the bag, feedforward, estimator, pairing (and the plateau
summary), writing the residual log. A stage is timed from its first report to the first report of the next stage.

A benchmark, not a test: the numbers depend on the machine and on what else runs on it; only the ratios measured
in one run are comparable. Results: ``bench/REPLAY.md``.

Run from the repository root:  ``.venv/bin/python bench/replay_throughput.py [--bag DIR] [--repeat 3]
[--no-inputs] [--json]``
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BAG = ROOT / 'bags' / 'chamber_sample'
STAGE_ORDER = ('setup', 'reading bag', 'feedforward', 'estimator', 'pairing', 'writing residual log')


def run_decode(bag: Path) -> tuple[float, int]:
    """Open the bag with rosbags and deserialize every message: (wall time [s], messages)."""
    from rosbags.highlevel import AnyReader

    from gimbal_friction.recording.bag import default_typestore
    t0 = time.perf_counter()
    count = 0
    with AnyReader([bag], default_typestore=default_typestore()) as reader:
        deserialize = reader.typestore.deserialize_cdr
        for conn, _, data in reader.messages():
            deserialize(data, conn.msgtype)
            count += 1
    return time.perf_counter() - t0, count


def run_replay(bag: Path, work: Path, log_inputs: bool) -> tuple[float, int, dict[str, float]]:
    """``replay_bag`` into a fresh folder: (wall time [s], bag messages, seconds per stage)."""
    from gimbal_friction.chamber.replay import replay_bag
    out = Path(tempfile.mkdtemp(prefix='replay-', dir=work))
    events: list[tuple[str, float]] = []

    def progress(stage: str, frac: float) -> None:
        if not events or events[-1][0] != stage:
            events.append((stage, time.perf_counter()))

    try:
        t0 = time.perf_counter()
        result = replay_bag(bag, out, log_inputs=log_inputs, progress=progress)
        t1 = time.perf_counter()
    finally:
        shutil.rmtree(out, ignore_errors=True)
    stages: dict[str, float] = {}
    marks = [('setup', t0), *events, ('end', t1)]
    for (stage, start), (_, stop) in zip(marks, marks[1:]):
        stages[stage] = stages.get(stage, 0.0) + stop - start
    return t1 - t0, result.messages_in, stages


def median_summary(times: list[float], messages: int) -> dict[str, Any]:
    med = statistics.median(times)
    return {'median_s': round(med, 4), 'msgs_per_s': round(messages / med, 1),
            'runs_s': [round(t, 4) for t in times]}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--bag', type=Path, default=DEFAULT_BAG, help='chamber-test bag (default bags/chamber_sample)')
    parser.add_argument('--repeat', type=int, default=3, help='rounds of each workload (default 3)')
    parser.add_argument('--no-inputs', action='store_true',
                        help='also time the replay without copying the input topics (replay --no-inputs)')
    parser.add_argument('--target', type=float, default=0.9, help='target replay / decode ratio (default 0.9)')
    parser.add_argument('--json', action='store_true', help='print one JSON document instead of the table')
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error('--repeat must be >= 1')

    workloads: list[tuple[str, Callable[[Path], tuple[float, int, dict[str, float]]]]] = [
        ('decode', lambda work: (*run_decode(args.bag), {})),
        ('replay', lambda work: run_replay(args.bag, work, True)),
    ]
    if args.no_inputs:
        workloads.append(('replay_no_inputs', lambda work: run_replay(args.bag, work, False)))
    times: dict[str, list[float]] = {name: [] for name, _ in workloads}
    stages: dict[str, list[dict[str, float]]] = {name: [] for name, _ in workloads}
    messages: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix='replay-bench-') as tmp:
        for rnd in range(args.repeat):
            for name, fn in (workloads if rnd % 2 == 0 else workloads[::-1]):
                seconds, count, per_stage = fn(Path(tmp))
                times[name].append(seconds)
                stages[name].append(per_stage)
                messages[name] = count
                if not args.json:
                    print(f'  round {rnd + 1}/{args.repeat}  {name:<17} {seconds:7.3f} s  '
                          f'{count / seconds:9.0f} msg/s', file=sys.stderr)
    n_bag = messages['replay']
    if messages['decode'] != n_bag:
        print(f'note: the decode pass read {messages["decode"]} messages, the replay {n_bag} (visible topics); '
              f'throughput uses {n_bag} for both', file=sys.stderr)
    results = {name: median_summary(times[name], n_bag) for name in times}
    limit = results['decode']['msgs_per_s']
    ratios = {name: round(results[name]['msgs_per_s'] / limit, 3) for name in times if name != 'decode'}
    breakdown = {}
    for name in ratios:
        keys = [k for k in STAGE_ORDER if any(k in s for s in stages[name])]
        keys += sorted({k for s in stages[name] for k in s} - set(keys))
        breakdown[name] = {k: round(statistics.median(s.get(k, 0.0) for s in stages[name]), 4) for k in keys}
    verdict = 'PASS' if ratios['replay'] >= args.target else 'MISS'
    doc = {'bag': str(args.bag), 'messages': n_bag, 'repeat': args.repeat, 'results': results, 'ratios': ratios,
           'target': args.target, 'verdict': verdict, 'stages_s': breakdown}
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(f'bag {args.bag}: {n_bag} messages, median of {args.repeat} rounds')
    print(f'{"workload":<18} {"median s":>9} {"msg/s":>10} {"/ decode":>9}')
    for name, res in results.items():
        ratio = '' if name == 'decode' else f'{ratios[name]:9.3f}'
        print(f'{name:<18} {res["median_s"]:9.3f} {res["msgs_per_s"]:10.0f} {ratio}')
    print(f'replay / decode = {ratios["replay"]:.3f} (target >= {args.target}): {verdict}')
    for name, per_stage in breakdown.items():
        total = results[name]['median_s']
        print(f'\nstages of {name} (median s, share of the median total):')
        for stage, seconds in per_stage.items():
            print(f'  {stage:<22} {seconds:7.3f}  {100 * seconds / total:5.1f} %')
    return 0


if __name__ == '__main__':
    sys.exit(main())
