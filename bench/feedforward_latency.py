"""Benchmark: added latency of ``friction_feedforward`` over a bare rclpy relay, across processes.

For each round, and in each round for each node in turn (relay, then feedforward: interleaved to cancel drift on a
shared machine), this script

1. starts the node as its own process on a private ROS domain (ros-domain-coordinator), loopback-only discovery
   and a temporary ROS_LOG_DIR;
2. in its own rclpy context (EventsExecutor, spin_once loop) publishes ``/gimbal/temperature`` (10 Hz) and
   ``/joint_states`` (1 joint ``elevation``, velocity alternating +/-0.0349 rad/s, position integrated) at
   ``--rate`` Hz for ``--duration`` s; the header stamp carries a sequence number (``stamp.sec``) and the send time
   is kept in a monotonic send-time map keyed by it;
3. receives ``/gimbal/friction/feedforward`` and computes latency = receive time - send time (both
   ``time.monotonic_ns()`` in this process), discarding the first ``--warmup`` s;
4. reads the node's CPU time from ``/proc/<pid>/stat`` (utime + stime, all threads) over the measured window;
5. stops the node with SIGINT.

Before the measured window starts, publisher and subscriber are matched (``get_subscription_count`` /
``get_publisher_count``) and a round trip through the node has been observed (priming messages at 100 Hz).
Sends follow an absolute 1 ms schedule; if this process was descheduled, overdue messages are caught up at 4x the
rate (not in one burst), and a run with more than 1 % late sends is marked "disturbed" (the machine was busy).
``--nodes relay,feedforward,lean`` adds ``bench/lean_feedforward.py``, an experiment with a leaner callback.

Prints p50/p99/max, sent/received/lost, achieved rates, whether the node kept up (>= 99 % received and no growing
backlog: median latency of the last second no more than ``--backlog-ms`` above that of the first measured
second), CPU, and the ratios feedforward/relay of p50 and p99 against the targets (p50 <= 1.2x, p99 <= 1.5x).
Ratios, not absolute numbers, are the result: machines are shared and noisy. This is a benchmark, not a test.

Run from the repository root:  ``.venv/bin/python bench/feedforward_latency.py [--duration 10] [--rounds 2]
[--json]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PARAMS_FILE = ROOT / 'config' / 'gimbal_friction.yaml'

JOINT_STATES = '/joint_states'
TEMPERATURE = '/gimbal/temperature'
FEEDFORWARD = '/gimbal/friction/feedforward'

JOINT = 'elevation'
VELOCITY_RAD_S = 0.0349       # [rad/s] the paper's 1/3 rpm test speed
TEMPERATURE_C = 35.0          # [degC] published temperature (not the node's 20 degC fallback)
TEMPERATURE_PERIOD_S = 0.1    # [s]
TARGET_P50 = 1.2              # feedforward/relay
TARGET_P99 = 1.5
MIN_RECEIVED = 0.99           # fraction of measured messages that must come back
DISTURBED_LATE = 0.01         # a run whose driver sent more than this fraction late was disturbed by other loads
MATCH_TIMEOUT_S = 20.0        # discovery can take 3 s (late joiner); generous
PRIME_MESSAGES = 5            # round trips observed before the measured window
CLK_TCK = os.sysconf('SC_CLK_TCK')


def node_command(kind: str) -> list[str]:
    """Command line of the node under test (run with cwd = repository root)."""
    if kind == 'relay':
        return [sys.executable, str(ROOT / 'bench' / 'relay_node.py')]
    if kind == 'lean':
        return [sys.executable, str(ROOT / 'bench' / 'lean_feedforward.py'), '--ros-args', '--params-file',
                str(PARAMS_FILE)]
    exe = BIN / 'friction_feedforward'
    cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', 'gimbal_friction.nodes.feedforward']
    return cmd + ['--ros-args', '--params-file', str(PARAMS_FILE)]


def proc_cpu_s(pid: int) -> float:
    """utime + stime of a process (all its threads) [s], from /proc/<pid>/stat."""
    text = Path(f'/proc/{pid}/stat').read_text()
    fields = text[text.rindex(')') + 2:].split()  # after "pid (comm) "; fields[0] is state (field 3)
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # fields 14 and 15 of proc(5)


def percentile(sorted_values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile (q in [0, 100]) of an already sorted sequence."""
    if not sorted_values:
        return float('nan')
    k = max(0, min(len(sorted_values) - 1, math.ceil(q / 100.0 * len(sorted_values)) - 1))
    return sorted_values[k]


@dataclass
class RunResult:
    """One node, one round. Latencies in microseconds."""

    kind: str
    round: int
    sent: int = 0                 #: joint states sent in the measured window (after warm-up)
    received: int = 0             #: of those, outputs received
    lost: int = 0
    p50_us: float = float('nan')
    p99_us: float = float('nan')
    max_us: float = float('nan')
    first_s_p50_us: float = float('nan')   #: median latency of the first measured second
    last_s_p50_us: float = float('nan')    #: median latency of the last second
    send_rate_hz: float = 0.0     #: achieved send rate over the measured window
    recv_rate_hz: float = 0.0     #: outputs received per second of the measured window
    late_sends: int = 0           #: sends more than one period behind schedule (driver could not keep pace)
    node_cpu_pct: float = float('nan')     #: node process CPU, % of one core, over the measured window
    driver_cpu_pct: float = float('nan')   #: this process (publisher + receiver), % of one core
    kept_up: bool = False
    disturbed: bool = False       #: > 1 % late sends: this process was descheduled, i.e. the machine was busy
    exit_code: int | None = None
    last_effort_nm: float | None = None    #: effort[0] of the last output (sanity: the node computed a torque)
    latencies_us: list[float] = field(default_factory=list, repr=False)


class NodeProcess:
    """The node under test as its own process; stop() sends SIGINT."""

    def __init__(self, kind: str, env: dict[str, str], log: Path) -> None:
        self.log = log
        self._fh = open(log, 'wb')  # noqa: SIM115
        self.proc = subprocess.Popen(node_command(kind), cwd=ROOT, env=env, stdout=self._fh,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.terminate()
                try:
                    self.proc.wait(3)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        self._fh.close()
        return self.proc.returncode

    def tail(self, lines: int = 15) -> str:
        return '\n'.join(self.log.read_text(errors='replace').splitlines()[-lines:])


class BenchError(RuntimeError):
    """The benchmark could not run (node did not start, no round trip, ...)."""


class Driver:
    """Publisher of the inputs and receiver of the outputs, in a private rclpy context with an EventsExecutor."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rclpy.node import Node
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState, Temperature

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('feedforward_latency_bench', context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(depth=10)
        self.pub_js = self.node.create_publisher(JointState, JOINT_STATES, qos)
        self.pub_t = self.node.create_publisher(Temperature, TEMPERATURE, qos)
        # Deeper than the node's queue so this side never drops what the node delivered.
        self.sub = self.node.create_subscription(JointState, FEEDFORWARD, self._on_output, QoSProfile(depth=1000))
        self.received: list[tuple[int, int]] = []   # (sequence number, receive time [ns])
        self.last_output: Any = None
        self._msgs = []
        for sign in (1.0, -1.0):
            m = JointState(name=[JOINT], position=[0.0], velocity=[sign * VELOCITY_RAD_S])
            m.header.frame_id = 'bench'
            self._msgs.append(m)
        self._temperature = Temperature(temperature=TEMPERATURE_C, variance=0.0)
        self._position = 0.0

    def _on_output(self, msg: Any) -> None:
        t = time.monotonic_ns()
        self.received.append((msg.header.stamp.sec, t))
        self.last_output = msg

    def send(self, seq: int, period_s: float) -> int:
        """Publish joint state ``seq``; returns the send time [ns]."""
        m = self._msgs[seq & 1]
        self._position += m.velocity[0] * period_s
        m.position[0] = self._position
        m.header.stamp.sec = seq
        m.header.stamp.nanosec = 0
        t = time.monotonic_ns()
        self.pub_js.publish(m)
        return t

    def send_temperature(self) -> None:
        self.pub_t.publish(self._temperature)

    def spin_until(self, cond: Callable[[], bool], timeout_s: float, what: str,
                   every: Callable[[], None] | None = None, every_s: float = 0.01) -> None:
        deadline = time.monotonic() + timeout_s
        next_every = 0.0
        while not cond():
            now = time.monotonic()
            if now > deadline:
                raise BenchError(f'timed out after {timeout_s:g} s waiting for {what}')
            if every is not None and now >= next_every:
                every()
                next_every = now + every_s
            self.executor.spin_once(timeout_sec=every_s if every is not None else 0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def run_once(kind: str, round_no: int, domain: int, env: dict[str, str], log_dir: Path,
             duration_s: float, rate_hz: float, warmup_s: float, backlog_ms: float) -> RunResult:
    """One node, one measured window."""
    result = RunResult(kind, round_no)
    driver = Driver(domain)   # subscriber and publishers exist before the node starts
    node = NodeProcess(kind, env, log_dir / f'{kind}_{round_no}.log')
    try:
        alive = node.alive
        driver.spin_until(lambda: not alive() or (driver.pub_js.get_subscription_count() >= 1
                                                  and driver.sub.get_publisher_count() >= 1),
                          MATCH_TIMEOUT_S, f'{kind}: /joint_states subscriber and {FEEDFORWARD} publisher')
        if not alive():
            raise BenchError(f'{kind} exited early (rc={node.proc.returncode}):\n{node.tail()}')
        # Round trip: priming messages (negative sequence numbers) at 100 Hz until outputs come back.
        prime = [-1]

        def send_prime() -> None:
            if -prime[0] % 10 == 1:   # every 10th priming message, starting with the first
                driver.send_temperature()
            driver.send(prime[0], 0.01)
            prime[0] -= 1

        driver.spin_until(lambda: sum(1 for s, _ in driver.received if s < 0) >= PRIME_MESSAGES,
                          MATCH_TIMEOUT_S, f'{kind}: {PRIME_MESSAGES} round trips', every=send_prime)
        driver.received.clear()

        period_ns = int(round(1e9 / rate_hz))
        n_total = int(round(duration_s * rate_hz))
        n_warm = int(round(warmup_s * rate_hz))
        send_ns = [0] * n_total
        temp_every = max(1, int(round(TEMPERATURE_PERIOD_S * rate_hz)))
        spin_margin_ns = 80_000   # spin_once overshoots its timeout by ~80 us here
        # After a stall of this process (shared machine), overdue messages are caught up at 4x the rate rather than
        # in one back-to-back burst, which would overflow the node's depth-10 queue: a driver artefact, not load.
        min_gap_ns = period_ns // 4
        last_send = 0
        executor = driver.executor
        cpu0 = cpu1 = 0.0
        ru0 = ru1 = None
        t_start = time.monotonic_ns() + 2 * period_ns
        next_ns = t_start
        seq = 0
        while seq < n_total:
            now = time.monotonic_ns()
            if now >= next_ns and now - last_send >= min_gap_ns:
                if seq == n_warm:
                    cpu0 = proc_cpu_s(node.pid)
                    ru0 = resource.getrusage(resource.RUSAGE_SELF)
                if seq % temp_every == 0:
                    driver.send_temperature()
                send_ns[seq] = last_send = driver.send(seq, period_ns * 1e-9)
                if now - next_ns > period_ns:
                    result.late_sends += 1
                seq += 1
                next_ns += period_ns
                continue
            wait = max(next_ns, last_send + min_gap_ns) - now - spin_margin_ns
            executor.spin_once(timeout_sec=wait * 1e-9 if wait > 0 else 0.0)
        t_end = time.monotonic_ns()
        cpu1 = proc_cpu_s(node.pid)
        ru1 = resource.getrusage(resource.RUSAGE_SELF)
        # Drain: outputs still in flight.
        last_seq = n_total - 1
        try:
            driver.spin_until(lambda: any(s == last_seq for s, _ in driver.received[-50:]), 1.0, 'drain')
        except BenchError:
            pass
        t_drain = time.monotonic() + 0.1
        while time.monotonic() < t_drain:
            executor.spin_once(timeout_sec=0.02)

        window_s = (t_end - send_ns[n_warm]) * 1e-9
        latency_by_seq: dict[int, float] = {}
        for s, t in driver.received:
            if n_warm <= s < n_total and s not in latency_by_seq:
                latency_by_seq[s] = (t - send_ns[s]) * 1e-3
        measured = n_total - n_warm
        result.sent = measured
        result.received = len(latency_by_seq)
        result.lost = measured - result.received
        lat = sorted(latency_by_seq.values())
        result.latencies_us = lat
        result.p50_us = percentile(lat, 50)
        result.p99_us = percentile(lat, 99)
        result.max_us = lat[-1] if lat else float('nan')
        one_s = int(round(rate_hz))
        first = sorted(v for s, v in latency_by_seq.items() if s < n_warm + one_s)
        last = sorted(v for s, v in latency_by_seq.items() if s >= n_total - one_s)
        result.first_s_p50_us = percentile(first, 50)
        result.last_s_p50_us = percentile(last, 50)
        result.send_rate_hz = (measured - 1) / ((send_ns[-1] - send_ns[n_warm]) * 1e-9)
        result.recv_rate_hz = result.received / window_s
        result.node_cpu_pct = 100.0 * (cpu1 - cpu0) / window_s
        if ru0 is not None and ru1 is not None:
            used = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
            result.driver_cpu_pct = 100.0 * used / window_s
        result.kept_up = (result.received >= MIN_RECEIVED * measured
                          and result.last_s_p50_us <= result.first_s_p50_us + 1e3 * backlog_ms)
        result.disturbed = result.late_sends > DISTURBED_LATE * measured
        if driver.last_output is not None and len(driver.last_output.effort):
            result.last_effort_nm = float(driver.last_output.effort[0])
        if not node.alive():
            raise BenchError(f'{kind} died during the run (rc={node.proc.returncode}):\n{node.tail()}')
    finally:
        result.exit_code = node.stop()
        driver.close()
    return result


def pooled(results: list[RunResult], kind: str) -> dict[str, Any]:
    runs = [r for r in results if r.kind == kind]
    lat = sorted(v for r in runs for v in r.latencies_us)
    sent = sum(r.sent for r in runs)
    received = sum(r.received for r in runs)
    return {
        'p50_us': percentile(lat, 50), 'p99_us': percentile(lat, 99), 'max_us': lat[-1] if lat else float('nan'),
        'sent': sent, 'received': received, 'lost': sent - received,
        'send_rate_hz': min(r.send_rate_hz for r in runs), 'recv_rate_hz': min(r.recv_rate_hz for r in runs),
        'node_cpu_pct': sum(r.node_cpu_pct for r in runs) / len(runs),
        'kept_up': all(r.kept_up for r in runs),
    }


def summarize(results: list[RunResult], kinds: Sequence[str]) -> dict[str, Any]:
    """Pooled numbers per node; ratios of every candidate to the relay (pooled and per round); verdicts."""
    nodes = {kind: pooled(results, kind) for kind in kinds}
    relay = nodes['relay']
    ratios = {}
    for kind in kinds:
        if kind == 'relay':
            continue
        per_round = []
        for rnd in sorted({r.round for r in results}):
            a = next(r for r in results if r.round == rnd and r.kind == 'relay')
            b = next(r for r in results if r.round == rnd and r.kind == kind)
            per_round.append({'round': rnd, 'ratio_p50': b.p50_us / a.p50_us, 'ratio_p99': b.p99_us / a.p99_us})
        r50 = nodes[kind]['p50_us'] / relay['p50_us']
        r99 = nodes[kind]['p99_us'] / relay['p99_us']
        ratios[kind] = {'ratio_p50': r50, 'ratio_p99': r99, 'per_round': per_round,
                        'pass_p50': r50 <= TARGET_P50, 'pass_p99': r99 <= TARGET_P99,
                        'sustained': nodes[kind]['kept_up']}
    return {'nodes': nodes, 'ratios': ratios, 'target_p50': TARGET_P50, 'target_p99': TARGET_P99,
            'disturbed_runs': sum(1 for r in results if r.disturbed)}


def print_report(config: dict[str, Any], results: list[RunResult], summary: dict[str, Any]) -> None:
    print(f"feedforward_latency: {config['rounds']} round(s) x ({', '.join(config['nodes'])}), "
          f"{config['rate_hz']:g} Hz for {config['duration_s']:g} s each (first {config['warmup_s']:g} s "
          f"discarded), domain {config['domain']}")
    la0, la1 = config['loadavg_start'], config['loadavg_end']
    print(f"load average (1 min) {la0[0]:.2f} at start, {la1[0]:.2f} at end, on {config['cpus']} CPUs "
          '(other loads show up in p99 and max; compare ratios, rerun when the machine is busy)')
    head = (f"{'node':<12}{'rnd':>4}{'p50 us':>9}{'p99 us':>9}{'max us':>9}{'sent':>7}{'recv':>7}{'lost':>6}"
            f"{'tx Hz':>8}{'late':>6}{'rx Hz':>8}{'1st/last s p50':>16}{'node CPU':>9}{'drv CPU':>8}  kept up")
    print(head)
    for r in results:
        print(f'{r.kind:<12}{r.round:>4}{r.p50_us:>9.0f}{r.p99_us:>9.0f}{r.max_us:>9.0f}{r.sent:>7}{r.received:>7}'
              f'{r.lost:>6}{r.send_rate_hz:>8.1f}{r.late_sends:>6}{r.recv_rate_hz:>8.1f}'
              f'{f"{r.first_s_p50_us:.0f}/{r.last_s_p50_us:.0f}":>16}{r.node_cpu_pct:>8.1f}%'
              f'{r.driver_cpu_pct:>7.1f}%  {"yes" if r.kept_up else "NO"}{"  (disturbed)" if r.disturbed else ""}'
              f'{"" if r.exit_code == 0 else f"  (exit code {r.exit_code})"}')
    for kind, p in summary['nodes'].items():
        print(f"{kind + ' (all)':<16}{p['p50_us']:>9.0f}{p['p99_us']:>9.0f}{p['max_us']:>9.0f}{p['sent']:>7}"
              f"{p['received']:>7}{p['lost']:>6}   node CPU {p['node_cpu_pct']:.1f}%")

    def verdict(ok: bool) -> str:
        return 'PASS' if ok else 'MISS'

    for kind, q in summary['ratios'].items():
        for pr in q['per_round']:
            print(f"round {pr['round']}: {kind}/relay p50 {pr['ratio_p50']:.3f}x, p99 {pr['ratio_p99']:.3f}x")
        print(f"ratio p50 {kind}/relay = {q['ratio_p50']:.3f}x (target <= {TARGET_P50}x): "
              f"{verdict(q['pass_p50'])}")
        print(f"ratio p99 {kind}/relay = {q['ratio_p99']:.3f}x (target <= {TARGET_P99}x): "
              f"{verdict(q['pass_p99'])}")
        print(f"{kind}: sustained {config['rate_hz']:g} Hz without falling behind (>= {MIN_RECEIVED:.0%} received, "
              f"last-second median <= first + {config['backlog_ms']:g} ms): {verdict(q['sustained'])}")
    if summary['disturbed_runs']:
        print(f"note: {summary['disturbed_runs']} run(s) disturbed (> {DISTURBED_LATE:.0%} of sends late: this process "
              'was descheduled by other loads); their p99/max say more about the machine than the node: rerun, or '
              'use more --rounds')


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--duration', type=float, default=10.0, help='send window per run [s] (default 10)')
    parser.add_argument('--rounds', type=int, default=2, help='rounds of (relay, feedforward) (default 2)')
    parser.add_argument('--rate', type=float, default=1000.0, help='joint-state rate [Hz] (default 1000)')
    parser.add_argument('--warmup', type=float, default=0.5, help='discarded start of each window [s] (0.5)')
    parser.add_argument('--backlog-ms', type=float, default=1.0,
                        help='allowed growth of the median latency from first to last second [ms] (1)')
    parser.add_argument('--nodes', default='relay,feedforward',
                        help="comma-separated nodes run in this order each round; 'relay' (the baseline) is "
                             "required; 'lean' = bench/lean_feedforward.py (experiment) (default relay,feedforward)")
    parser.add_argument('--json', action='store_true', help='print one JSON document instead of the table')
    args = parser.parse_args(argv)
    if args.duration < args.warmup + 2.0 or args.rounds < 1 or args.rate <= 0:
        parser.error('need --duration >= --warmup + 2 s, --rounds >= 1, --rate > 0')
    kinds = [k.strip() for k in args.nodes.split(',') if k.strip()]
    if 'relay' not in kinds or len(kinds) < 2 or len(set(kinds)) != len(kinds) \
            or not set(kinds) <= {'relay', 'feedforward', 'lean'}:
        parser.error("--nodes: 'relay' plus one or more of feedforward, lean, each once")

    from domain_coordinator import domain_id

    with domain_id() as did, tempfile.TemporaryDirectory(prefix='ff_latency_') as tmp:
        log_dir = Path(tmp)
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   ROS_LOG_DIR=str(log_dir / 'roslog'), PYTHONUNBUFFERED='1')
        # This process's own participant: same isolation (rcl reads these at rclpy.init).
        os.environ.update(ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                          ROS_LOG_DIR=str(log_dir / 'roslog'))
        config = {'nodes': kinds, 'rounds': args.rounds, 'duration_s': args.duration, 'rate_hz': args.rate,
                  'warmup_s': args.warmup, 'backlog_ms': args.backlog_ms, 'domain': did,
                  'params_file': str(PARAMS_FILE.relative_to(ROOT)), 'cpus': os.cpu_count(),
                  'loadavg_start': os.getloadavg()}
        results: list[RunResult] = []
        try:
            for rnd in range(1, args.rounds + 1):
                for kind in kinds:
                    if not args.json:
                        print(f'round {rnd}: {kind} ...', file=sys.stderr, flush=True)
                    results.append(run_once(kind, rnd, did, env, log_dir, args.duration, args.rate, args.warmup,
                                            args.backlog_ms))
        except BenchError as err:
            print(f'feedforward_latency: error: {err}', file=sys.stderr)
            return 1
        config['loadavg_end'] = os.getloadavg()
    summary = summarize(results, kinds)
    if args.json:
        runs = []
        for r in results:
            d = asdict(r)
            del d['latencies_us']
            runs.append(d)
        print(json.dumps({'config': config, 'runs': runs, 'summary': summary}, indent=2))
    else:
        print_report(config, results, summary)
    return 0


if __name__ == '__main__':
    sys.exit(main())
