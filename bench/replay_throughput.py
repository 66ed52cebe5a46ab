"""Throughput of ``gimbal-friction replay`` against the decode limit of the same bag, measured in the same run.

Three bags by default: ``bags/chamber_sample`` (61 k messages), a synthetic chamber bag of 2.6 M messages
(``--big-bag``, default ``/tmp/gimbal_friction_bench/chamber_1khz``: the sample's test with the joint states and
motor currents at 1 kHz) and issue 31's composition (``--long-bag``, default
``/tmp/gimbal_friction_bench/chamber_long_holds``: ``synth-bag --seed 5 --hold-s 600 --soak-s 60 --joint-rate-hz
250 --storage mcap``, 2.19 M messages whose 945 k accepted samples make a residual log of 7.06 M messages), each
written by ``gimbal-friction synth-bag`` when absent. On each bag, repeated ``--repeat``
times, interleaved (the order is reversed on every other round so that neither side always runs on a warm or a
cold machine):

- ``decode``: the limit. ``rosbags`` ``AnyReader`` opens the bag and ``typestore.deserialize_cdr`` decodes every
  message (what any reader of the bag has to pay);
- ``replay``: ``replay_bag(bag, out_dir)`` end to end, with the defaults of ``gimbal-friction replay`` (parameters,
  the three nodes' logic, the residual log with the input topics copied in);
- ``replay --no-inputs`` (with ``--no-inputs``): the same without copying the input topics;
- ``replay before`` (with ``--before DIR``): the replay of another checkout of the package (e.g. the code before a
  change: ``git worktree add /tmp/old COMMIT``), run in a child process with ``PYTHONPATH=DIR`` in the same rounds
  (timed inside the child, so interpreter start-up is not counted). With ``--isolate`` the replay of this checkout
  and the decode run in child processes the same way, so that no workload inherits the heap or the warm caches
  (the rosbags type store) of another.

Throughput = bag messages / wall time [msg/s] (the same numerator for every workload); the median over the rounds
is reported, and replay / decode of those medians and the median over the rounds of each round's replay / decode
(robust to a load that drifts from round to round), against the target ratio (``--target``, default 1.5): PASS
when both reach it, else MISS. The same two ratios in CPU seconds of the whole process (all threads), which other
jobs on a shared machine move far less than the wall time, get their own PASS / MISS. Also a per-stage breakdown
of each replay (medians over the rounds), taken from
``replay_bag``'s progress reports: setup (parameters, opening the bag), reading the bag (and decoding its inputs),
the nodes' logic, the plateau summary, serializing the log's messages and ordering them, writing the residual log
(MCAP chunks, compression). A stage is timed from its first report to the first report of the next stage.

A benchmark, not a test: the numbers depend on the machine and on what else runs on it; only the ratios measured
in one run are comparable. Results: ``bench/REPLAY.md``.

Run from the repository root:  ``.venv/bin/python bench/replay_throughput.py [--bag DIR ...] [--big-bag DIR]
[--sample-only] [--repeat 3] [--no-inputs] [--before DIR] [--json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault('NUMPY_MADVISE_HUGEPAGE', '0')   # as the gimbal-friction command sets it (numpy not yet imported)

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BAG = ROOT / 'bags' / 'chamber_sample'
BIG_BAG = Path(tempfile.gettempdir()) / 'gimbal_friction_bench' / 'chamber_1khz'
#: ``gimbal-friction synth-bag`` options of the big bag (2,588,347 messages; about a minute to write)
BIG_BAG_OPTIONS = ('--joint-rate-hz', '1000')
#: issue 31's composition (2,188,720 messages: long holds, 250 Hz joint states; 945 k accepted samples, so the
#: residual log outweighs the bag: 7.06 M messages written for 2.19 M read; about 80 s to write)
LONG_BAG = Path(tempfile.gettempdir()) / 'gimbal_friction_bench' / 'chamber_long_holds'
LONG_BAG_OPTIONS = ('--seed', '5', '--hold-s', '600', '--soak-s', '60', '--joint-rate-hz', '250', '--storage', 'mcap')
CPU_MAIN = 'CPU, main thread'       #: reported beside the stages: CPU seconds of the replay's thread
CPU_ALL = 'CPU, all threads'        #: ... and of the process (the chunk-compressing worker thread included)
STAGE_ORDER = ('setup', 'reading bag', 'nodes', 'summary', 'serializing log', 'writing residual log')

Workload = Callable[[Path], tuple[float, int, dict[str, float]]]


def ensure_big_bag(path: Path, options: Sequence[str] = BIG_BAG_OPTIONS) -> Path:
    """The big bag at ``path``, written with ``gimbal-friction synth-bag OPTIONS`` if it is not there."""
    if (path / 'metadata.yaml').is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    print(f'writing the bag {path} (gimbal-friction synth-bag {" ".join(options)}; a minute or two)',
          file=sys.stderr)
    from gimbal_friction.cli.main import main as cli
    if cli(['synth-bag', '--out', str(path), *options]) != 0:
        msg = f'synth-bag failed to write {path}'
        raise SystemExit(msg)
    return path


def run_decode(bag: Path) -> tuple[float, int, dict[str, float]]:
    """Open the bag with rosbags and deserialize every message: (wall time [s], messages, CPU seconds)."""
    from rosbags.highlevel import AnyReader

    from gimbal_friction.recording.bag import default_typestore
    c0, p0 = time.thread_time(), time.process_time()
    t0 = time.perf_counter()
    count = 0
    with AnyReader([bag], default_typestore=default_typestore()) as reader:
        deserialize = reader.typestore.deserialize_cdr
        for conn, _, data in reader.messages():
            deserialize(data, conn.msgtype)
            count += 1
    t1 = time.perf_counter()
    return t1 - t0, count, {CPU_MAIN: time.thread_time() - c0, CPU_ALL: time.process_time() - p0}


def run_replay(bag: Path, work: Path, log_inputs: bool) -> tuple[float, int, dict[str, float]]:
    """``replay_bag`` into a fresh folder: (wall time [s], bag messages, seconds per stage)."""
    from gimbal_friction.chamber.replay import replay_bag
    out = Path(tempfile.mkdtemp(prefix='replay-', dir=work))
    events: list[tuple[str, float]] = []

    def progress(stage: str, frac: float) -> None:
        if not events or events[-1][0] != stage:
            events.append((stage, time.perf_counter()))

    try:
        c0, p0 = time.thread_time(), time.process_time()
        t0 = time.perf_counter()
        result = replay_bag(bag, out, log_inputs=log_inputs, progress=progress)
        t1 = time.perf_counter()
        c1, p1 = time.thread_time(), time.process_time()
    finally:
        shutil.rmtree(out, ignore_errors=True)
    stages: dict[str, float] = {}
    marks = [('setup', t0), *events, ('end', t1)]
    for (stage, start), (_, stop) in zip(marks, marks[1:]):
        stages[stage] = stages.get(stage, 0.0) + stop - start
    # CPU seconds (not stages: less sensitive than wall time to what else runs on the machine)
    stages[CPU_MAIN] = c1 - c0
    stages[CPU_ALL] = p1 - p0
    return t1 - t0, result.messages_in, stages


def run_before(bag: Path, work: Path, code: Path) -> tuple[float, int, dict[str, float]]:
    """One replay of the checkout ``code`` in a child process (timed inside it)."""
    return run_child(['--child-replay', str(bag), '--work', str(work)], code)


def run_child(options: list[str], code: Path | None) -> tuple[float, int, dict[str, float]]:
    """One workload in a fresh child process (``PYTHONPATH=code``, else this checkout), timed inside it."""
    env = {**os.environ, 'PYTHONPATH': str(code or ROOT)}
    out = subprocess.run([sys.executable, __file__, *options], env=env, check=True, capture_output=True, text=True)
    doc = json.loads(out.stdout)
    return doc['seconds'], doc['messages'], doc['stages']


def median_summary(times: list[float], messages: int) -> dict[str, Any]:
    med = statistics.median(times)
    return {'median_s': round(med, 4), 'msgs_per_s': round(messages / med, 1),
            'runs_s': [round(t, 4) for t in times]}


def bench_bag(bag: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Every workload on one bag, ``args.repeat`` interleaved rounds: the medians, ratios and stages."""
    workloads: list[tuple[str, Workload]] = [
        ('decode', (lambda work: run_child(['--child-decode', str(bag)], None)) if args.isolate
         else (lambda work: run_decode(bag))),
        ('replay', (lambda work: run_before(bag, work, ROOT)) if args.isolate
         else (lambda work: run_replay(bag, work, True))),
    ]
    if args.no_inputs:
        workloads.append(('replay_no_inputs', lambda work: run_replay(bag, work, False)))
    if args.before is not None:
        workloads.append(('replay_before', lambda work: run_before(bag, work, args.before)))
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
                print(f'  {bag.name}: round {rnd + 1}/{args.repeat}  {name:<17} {seconds:8.3f} s  '
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
    # the same ratio round by round (each replay against the decode of its own round, run next to it): robust to
    # a load that drifts between rounds
    paired = {name: round(statistics.median(d / r for d, r in zip(times['decode'], times[name], strict=True)), 3)
              for name in ratios}
    # the same in CPU seconds of the whole process (every thread): what the work costs, far less moved than the
    # wall time by what else runs on a shared machine
    cpu = {name: [s_[CPU_ALL] for s_ in stages[name]] for name in times}
    cpu_ratios = {name: round(statistics.median(cpu['decode']) / statistics.median(cpu[name]), 3) for name in ratios}
    cpu_paired = {name: round(statistics.median(d / r for d, r in zip(cpu['decode'], cpu[name], strict=True)), 3)
                  for name in ratios}
    doc: dict[str, Any] = {'bag': str(bag), 'messages': n_bag, 'repeat': args.repeat, 'results': results,
                           'ratios': ratios, 'paired_ratios': paired, 'target': args.target,
                           'verdict': 'PASS' if min(ratios['replay'], paired['replay']) >= args.target else 'MISS',
                           'decode_cpu_s': {'median_s': round(statistics.median(cpu['decode']), 4),
                                            'runs_s': [round(c, 4) for c in cpu['decode']]},
                           'cpu_ratios': cpu_ratios, 'cpu_paired_ratios': cpu_paired,
                           'cpu_verdict': 'PASS' if min(cpu_ratios['replay'], cpu_paired['replay']) >= args.target
                           else 'MISS',
                           'stages_s': breakdown}
    if args.before is not None:
        doc['speedup_vs_before'] = round(results['replay_before']['median_s'] / results['replay']['median_s'], 3)
    return doc


def print_table(doc: dict[str, Any]) -> None:
    print(f'\nbag {doc["bag"]}: {doc["messages"]} messages, median of {doc["repeat"]} rounds')
    print(f'{"workload":<18} {"median s":>9} {"msg/s":>10} {"/ decode":>9}')
    for name, res in doc['results'].items():
        ratio = '' if name == 'decode' else f'{doc["ratios"][name]:9.3f}'
        print(f'{name:<18} {res["median_s"]:9.3f} {res["msgs_per_s"]:10.0f} {ratio}')
    print(f'replay / decode = {doc["ratios"]["replay"]:.3f} of the medians, {doc["paired_ratios"]["replay"]:.3f} '
          f'median of the rounds (target >= {doc["target"]}, both): {doc["verdict"]}')
    print(f'in CPU seconds (all threads; decode {doc["decode_cpu_s"]["median_s"]:.3f} s): replay / decode = '
          f'{doc["cpu_ratios"]["replay"]:.3f} of the medians, {doc["cpu_paired_ratios"]["replay"]:.3f} median of the '
          f'rounds: {doc["cpu_verdict"]}'
          + ''.join(f'; {name} {doc["cpu_ratios"][name]:.3f}, {doc["cpu_paired_ratios"][name]:.3f}'
                    for name in doc['cpu_ratios'] if name != 'replay'))
    if 'speedup_vs_before' in doc:
        print(f'replay before / replay = {doc["speedup_vs_before"]:.3f} (the same rounds)')
    for name, per_stage in doc['stages_s'].items():
        total = doc['results'][name]['median_s']
        print(f'stages of {name} (median s, share of the median total):')
        for stage, seconds in per_stage.items():
            if stage in (CPU_MAIN, CPU_ALL):
                continue
            print(f'  {stage:<22} {seconds:8.3f}  {100 * seconds / total:5.1f} %')
        cpu = [f'{key} {per_stage[key]:.3f} s' for key in (CPU_MAIN, CPU_ALL) if key in per_stage]
        if cpu:
            print(f'  ({", ".join(cpu)}: medians)')
    names = [name for name, per_stage in doc['stages_s'].items() if CPU_MAIN in per_stage]
    if len(names) > 1:
        base = doc['stages_s'][names[0]]
        for name in names[1:]:
            other = doc['stages_s'][name]
            print(f'{name} / {names[0]} CPU (medians): main thread {other[CPU_MAIN] / base[CPU_MAIN]:.3f}, '
                  f'all threads {other[CPU_ALL] / base[CPU_ALL]:.3f}')


def child_decode(bag: Path) -> int:
    """``--child-decode``: one decode, its timing as JSON on stdout (for ``--isolate``)."""
    seconds, messages, stages = run_decode(bag)
    print(json.dumps({'seconds': seconds, 'messages': messages, 'stages': stages}))
    return 0


def child_replay(bag: Path, work: Path) -> int:
    """``--child-replay``: one replay, its timing as JSON on stdout (for ``--before``)."""
    seconds, messages, stages = run_replay(bag, work, True)
    print(json.dumps({'seconds': seconds, 'messages': messages, 'stages': stages}))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--bag', type=Path, action='append',
                        help='chamber-test bag (repeatable; default: bags/chamber_sample, the big bag and the '
                        'long-holds bag)')
    parser.add_argument('--big-bag', type=Path, default=BIG_BAG,
                        help=f'the big bag, written by synth-bag if absent (default {BIG_BAG})')
    parser.add_argument('--long-bag', type=Path, default=LONG_BAG,
                        help=f'the long-holds bag of issue 31, written by synth-bag if absent (default {LONG_BAG})')
    parser.add_argument('--sample-only', action='store_true', help='only bags/chamber_sample (no big bags)')
    parser.add_argument('--repeat', type=int, default=3, help='rounds of each workload (default 3)')
    parser.add_argument('--no-inputs', action='store_true',
                        help='also time the replay without copying the input topics (replay --no-inputs)')
    parser.add_argument('--before', type=Path, metavar='DIR',
                        help='also time the replay of the package checked out at DIR (PYTHONPATH=DIR)')
    parser.add_argument('--isolate', action='store_true',
                        help='run each replay of this checkout, and each decode, in a child process too, as '
                        '--before runs its own (a fresh interpreter and heap for every workload; each pays its '
                        'first use of the rosbags type store)')
    parser.add_argument('--target', type=float, default=1.5, help='target replay / decode ratio (default 1.5)')
    parser.add_argument('--json', action='store_true', help='print one JSON document instead of the tables')
    parser.add_argument('--child-replay', type=Path, help=argparse.SUPPRESS)
    parser.add_argument('--child-decode', type=Path, help=argparse.SUPPRESS)
    parser.add_argument('--work', type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child_replay is not None:
        return child_replay(args.child_replay, args.work)
    if args.child_decode is not None:
        return child_decode(args.child_decode)
    if args.repeat < 1:
        parser.error('--repeat must be >= 1')
    if args.before is not None and not (args.before / 'gimbal_friction' / '__init__.py').is_file():
        parser.error(f'--before {args.before}: no gimbal_friction package there')
    bags = list(args.bag) if args.bag else [SAMPLE_BAG] + ([] if args.sample_only else [
        ensure_big_bag(args.big_bag), ensure_big_bag(args.long_bag, LONG_BAG_OPTIONS)])
    docs = [bench_bag(bag, args) for bag in bags]
    machine = {'date': time.strftime('%Y-%m-%d %H:%M %Z'), 'machine': platform.machine(), 'cpus': os.cpu_count(),
               'python': platform.python_version(), 'processor': platform.processor() or platform.machine()}
    if args.json:
        print(json.dumps({'machine': machine, 'bags': docs}, indent=1))
        return 0
    print(f'{machine["date"]}, {machine["cpus"]} CPUs ({machine["processor"]}), Python {machine["python"]}')
    for doc in docs:
        print_table(doc)
    return 0


if __name__ == '__main__':
    sys.exit(main())
