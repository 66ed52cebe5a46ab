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

Prints p50/p99/max, sent/received/lost, achieved rates, whether the node kept up (>= 99 % received and no growing
backlog: median latency of the last second no more than ``--backlog-ms`` above that of the first measured
second), CPU, and the ratios feedforward/relay of p50 and p99 against the targets (p50 <= 1.2x, p99 <= 1.5x).
Ratios, not absolute numbers, are the result: machines are shared and noisy. This is a benchmark, not a test.

Learning in service: ``--nodes relay,feedforward,learning`` adds the feedforward with ``learning_enabled`` (saving to
a temporary file every second, the correction topic every second). In every run the driver also publishes
``/gimbal/friction/measured_detail`` (accepted estimator samples, ``--detail-rate`` Hz, stamped now so the
temperature is fresh: the learning node learns from each) so that learning on and off see the same inputs; the
report adds the ratios learning/feedforward of p50 and p99 per round (the joint-state path must not get slower).

Drops, counted twice: ``lost`` = joint states sent by this process whose output never came back (whatever lost
them: the driver's own publisher history, the node's input queue, its output path); ``node lost`` = what the node
itself reports on ``/diagnostics`` (``lost: /joint_states``, from gaps in the publisher's sequence numbers), with
``accounted`` = the node's received + lost (counted from after priming) equals what this process published then.
After the latency rounds, drop runs (``--drop-rates``, default 3 kHz, relay and feedforward) and back-to-back
bursts (``--bursts``, default 20, 1000 and 5000 messages, ``--burst-repeats`` each, published without pausing,
then the outputs awaited) report the same counts. ``--no-drops`` skips them.

Run from the repository root:  ``.venv/bin/python bench/feedforward_latency.py [--duration 10] [--rounds 2]
[--json]``
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

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
DIAG_PERIOD_S = 0.2           # the feedforward's /diagnostics period in the benchmark (its drop counts)


KINDS = ('relay', 'feedforward', 'learning')
DETAIL = '/gimbal/friction/measured_detail'
DETAIL_FRICTION_NM = 1.5e-3   # [N*m] measured friction of the published samples (more than the model at 35 degC)


def node_command(kind: str, log_dir: Path | None = None) -> list[str]:
    """Command line of the node under test (run with cwd = repository root); ``learning`` saves in ``log_dir``."""
    if kind == 'relay':
        return [sys.executable, str(ROOT / 'bench' / 'relay_node.py')]
    exe = BIN / 'friction_feedforward'
    cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', 'gimbal_friction.nodes.feedforward']
    cmd = [*cmd, '--ros-args', '--params-file', str(PARAMS_FILE), '-p', f'diagnostics_period_s:={DIAG_PERIOD_S}']
    if kind == 'learning':
        out = (log_dir or Path(tempfile.gettempdir())) / 'correction.yaml'
        cmd += ['-p', 'learning_enabled:=true', '-p', f'learning_output_file:={out}',
                '-p', 'learning_save_period_s:=1.0', '-p', 'correction_publish_period_s:=1.0']
    return cmd


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
    rate_hz: float = 0.0          #: target send rate [Hz]
    js_sent_total: int = 0        #: joint states this process published after priming (warm-up included)
    node_received: int | None = None       #: the node's own count (/diagnostics 'received: /joint_states')
    node_lost: int | None = None           #: the node's own count of joint states lost on the way to it
    accounted: bool | None = None          #: node_received + node_lost == js_sent_total
    latencies_us: list[float] = field(default_factory=list, repr=False)


@dataclass
class BurstResult:
    """Back-to-back bursts of one size."""

    kind: str
    size: int                     #: messages per burst, published without pausing
    repeats: int
    sent: int = 0
    received: int = 0             #: outputs that came back within 2 s of the burst
    lost: int = 0
    worst_burst_lost: int = 0
    publish_s: float = 0.0        #: mean time to publish one burst [s]
    node_received: int | None = None
    node_lost: int | None = None
    accounted: bool | None = None


class NodeProcess:
    """The node under test as its own process; stop() sends SIGINT."""

    def __init__(self, kind: str, env: dict[str, str], log: Path) -> None:
        self.log = log
        self._fh = open(log, 'wb')  # noqa: SIM115
        self.proc = subprocess.Popen(node_command(kind, log.parent), cwd=ROOT, env=env, stdout=self._fh,
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
        from rclpy.experimental.events_executor import EventsExecutor
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
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, METHOD_OBSERVER
        self.pub_detail = self.node.create_publisher(Float64MultiArray, DETAIL, QoSProfile(depth=100))
        row = dict.fromkeys(MEASUREMENT_FIELDS, 0.0)
        row.update(velocity_rad_s=VELOCITY_RAD_S, temperature_c=TEMPERATURE_C, temperature_fresh=1.0,
                   friction_nm=DETAIL_FRICTION_NM, method=float(METHOD_OBSERVER))
        n = len(MEASUREMENT_FIELDS)
        self._detail = Float64MultiArray(data=[row[f] for f in MEASUREMENT_FIELDS])
        self._detail.layout.dim = [MultiArrayDimension(label=JOINT, size=n, stride=n)]
        self._detail_sec = (MEASUREMENT_FIELDS.index('stamp_sec'), MEASUREMENT_FIELDS.index('stamp_nanosec'))
        # Deeper than the node's queue so this side never drops what the node delivered.
        self.sub = self.node.create_subscription(JointState, FEEDFORWARD, self._on_output, QoSProfile(depth=1000))
        from diagnostic_msgs.msg import DiagnosticArray
        self.node_counts: tuple[int, int] | None = None   # (received, lost) of /joint_states, from /diagnostics
        self.diag = self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)
        self.js_sent = 0
        self.received: list[tuple[int, int]] = []   # (sequence number, receive time [ns])
        self.last_output: Any = None
        self._msgs = []
        for sign in (1.0, -1.0):
            m = JointState(name=[JOINT], position=[0.0], velocity=[sign * VELOCITY_RAD_S])
            m.header.frame_id = 'bench'
            self._msgs.append(m)
        self._temperature = Temperature(temperature=TEMPERATURE_C, variance=0.0)
        self._position = 0.0

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            received, lost = values.get(f'received: {JOINT_STATES}'), values.get(f'lost: {JOINT_STATES}')
            if received is not None and lost is not None and lost != 'unknown':
                self.node_counts = (int(received), int(lost))

    def settled_node_counts(self, timeout_s: float = 3.0) -> tuple[int, int] | None:
        """The node's (received, lost) once two successive reports agree (nothing in flight any more), or the
        latest after ``timeout_s``; None from a node that does not count (the relay)."""
        deadline = time.monotonic() + timeout_s
        previous = None
        while time.monotonic() < deadline:
            self.node_counts = None
            while self.node_counts is None and time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.05)
            if self.node_counts is not None and self.node_counts == previous:
                break
            previous = self.node_counts
        return previous if self.node_counts is None else self.node_counts

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
        self.js_sent += 1
        return t

    def send_temperature(self) -> None:
        self.pub_t.publish(self._temperature)

    def send_detail(self) -> None:
        """One accepted estimator sample, stamped now (the temperature, stamped 0 = received now, is fresh)."""
        now = self.node.get_clock().now().nanoseconds
        data = self._detail.data
        data[self._detail_sec[0]], data[self._detail_sec[1]] = float(now // 10**9), float(now % 10**9)
        self.pub_detail.publish(self._detail)

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
             duration_s: float, rate_hz: float, warmup_s: float, backlog_ms: float,
             detail_rate_hz: float = 0.0) -> RunResult:
    """One node, one measured window."""
    result = RunResult(kind, round_no)
    driver = Driver(domain)   # subscriber and publishers exist before the node starts
    try:
        node = start_and_prime(kind, driver, env, log_dir / f'{kind}_{round_no}_{rate_hz:g}.log')
    except BenchError:
        driver.close()
        raise
    try:
        # the node's counts before the measured run (messages sent before it matched us are not its to count)
        counts0 = driver.settled_node_counts() if kind != 'relay' else None
        sent0 = driver.js_sent
        period_ns = int(round(1e9 / rate_hz))
        n_total = int(round(duration_s * rate_hz))
        n_warm = int(round(warmup_s * rate_hz))
        send_ns = [0] * n_total
        temp_every = max(1, int(round(TEMPERATURE_PERIOD_S * rate_hz)))
        detail_every = max(1, int(round(rate_hz / detail_rate_hz))) if detail_rate_hz > 0 else 0
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
                if detail_every and seq % detail_every == detail_every // 2:
                    driver.send_detail()
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
        with contextlib.suppress(BenchError):
            driver.spin_until(lambda: any(s == last_seq for s, _ in driver.received[-50:]), 1.0, 'drain')
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
        result.rate_hz = rate_hz
        result.js_sent_total = driver.js_sent - sent0
        counts = driver.settled_node_counts() if counts0 is not None else None
        if counts is not None and counts0 is not None:
            result.node_received, result.node_lost = counts[0] - counts0[0], counts[1] - counts0[1]
            result.accounted = result.node_received + result.node_lost == result.js_sent_total
        if not node.alive():
            raise BenchError(f'{kind} died during the run (rc={node.proc.returncode}):\n{node.tail()}')
    finally:
        result.exit_code = node.stop()
        driver.close()
    return result


def start_and_prime(kind: str, driver: Driver, env: dict[str, str], log: Path) -> NodeProcess:
    """Start the node, wait for matching and a few round trips."""
    node = NodeProcess(kind, env, log)
    alive = node.alive
    driver.spin_until(lambda: not alive() or (driver.pub_js.get_subscription_count() >= 1
                                              and driver.sub.get_publisher_count() >= 1),
                      MATCH_TIMEOUT_S, f'{kind}: /joint_states subscriber and {FEEDFORWARD} publisher')
    if not alive():
        raise BenchError(f'{kind} exited early (rc={node.proc.returncode}):\n{node.tail()}')
    prime = [-1]

    def send_prime() -> None:
        if -prime[0] % 10 == 1:
            driver.send_temperature()
        driver.send(prime[0], 0.01)
        prime[0] -= 1

    driver.spin_until(lambda: sum(1 for s, _ in driver.received if s < 0) >= PRIME_MESSAGES,
                      MATCH_TIMEOUT_S, f'{kind}: {PRIME_MESSAGES} round trips', every=send_prime)
    driver.received.clear()
    return node


def run_bursts(kind: str, domain: int, env: dict[str, str], log_dir: Path, sizes: Sequence[int],
               repeats: int) -> list[BurstResult]:
    """Bursts of ``sizes`` messages published back to back (no pause, no spin in between), ``repeats`` times each;
    after each burst the outputs are awaited (2 s at most) before the next."""
    driver = Driver(domain)
    node = start_and_prime(kind, driver, env, log_dir / f'{kind}_bursts.log')
    results = []
    seq = 0
    try:
        counts0 = driver.settled_node_counts() if kind != 'relay' else None
        sent0 = driver.js_sent
        for size in sizes:
            res = BurstResult(kind, size, repeats)
            for _ in range(repeats):
                first = seq
                t0 = time.perf_counter()
                for _k in range(size):
                    driver.send(seq, 0.001)
                    seq += 1
                res.publish_s += (time.perf_counter() - t0) / repeats
                last = seq - 1
                def burst_back(last: int = last) -> bool:
                    return any(s == last for s, _ in driver.received[-20:])

                with contextlib.suppress(BenchError):
                    driver.spin_until(burst_back, 2.0, 'burst outputs')
                t_settle = time.monotonic() + 0.05
                while time.monotonic() < t_settle:
                    driver.executor.spin_once(timeout_sec=0.01)
                got = len({s for s, _ in driver.received if first <= s <= last})
                res.sent += size
                res.received += got
                res.worst_burst_lost = max(res.worst_burst_lost, size - got)
            res.lost = res.sent - res.received
            results.append(res)
        counts = driver.settled_node_counts() if counts0 is not None else None
        if counts is not None and counts0 is not None:   # all sizes together: shown on the last one
            last_res = results[-1]
            last_res.node_received, last_res.node_lost = counts[0] - counts0[0], counts[1] - counts0[1]
            last_res.accounted = last_res.node_received + last_res.node_lost == driver.js_sent - sent0
        if not node.alive():
            raise BenchError(f'{kind} died during the bursts (rc={node.proc.returncode}):\n{node.tail()}')
    finally:
        node.stop()
        driver.close()
    return results


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
    learning_vs_off: list[dict[str, Any]] = []
    if 'learning' in kinds and 'feedforward' in kinds:
        for rnd in sorted({r.round for r in results}):
            a = next(r for r in results if r.round == rnd and r.kind == 'feedforward')
            b = next(r for r in results if r.round == rnd and r.kind == 'learning')
            learning_vs_off.append({'round': rnd, 'ratio_p50': b.p50_us / a.p50_us, 'ratio_p99': b.p99_us / a.p99_us})
        lf, ff = nodes['learning'], nodes['feedforward']
        learning_vs_off.append({'round': 'all', 'ratio_p50': lf['p50_us'] / ff['p50_us'],
                                'ratio_p99': lf['p99_us'] / ff['p99_us']})
    return {'nodes': nodes, 'ratios': ratios, 'target_p50': TARGET_P50, 'target_p99': TARGET_P99,
            'learning_vs_feedforward': learning_vs_off,
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
    for pr in summary['learning_vs_feedforward']:
        print(f"round {pr['round']}: learning on/off p50 {pr['ratio_p50']:.3f}x, p99 {pr['ratio_p99']:.3f}x")
    if summary['disturbed_runs']:
        print(f"note: {summary['disturbed_runs']} run(s) disturbed (> {DISTURBED_LATE:.0%} of sends late: this process "
              'was descheduled by other loads); their p99/max say more about the machine than the node: rerun, or '
              'use more --rounds')


def _node_counts(received: int | None, lost: int | None, accounted: bool | None) -> str:
    if received is None:
        return 'not counted'
    return f'{received} received, {lost} lost ({"accounts for every message sent" if accounted else "INCOMPLETE"})'


def print_drops(results: list[RunResult], drop_runs: list[RunResult], burst_runs: list[BurstResult]) -> None:
    """Drops: outputs missing at the driver, and the node's own count of inputs lost on the way to it."""
    print("drops (lost = sent - outputs received by the driver, measured window; node = the node's own "
          '/diagnostics count of joint states received and lost on the way to it, after priming incl. warm-up)')
    for r in [*results, *drop_runs]:
        pct = 100.0 * r.lost / r.sent if r.sent else float('nan')
        print(f'  {r.kind:<12}{r.rate_hz:>7.0f} Hz  sent {r.sent:>6}  lost {r.lost:>5} ({pct:.2f} %)  '
              f'tx {r.send_rate_hz:7.1f} Hz, late {r.late_sends}  node: '
              f'{_node_counts(r.node_received, r.node_lost, r.accounted)}')
    for b in burst_runs:
        pct = 100.0 * b.lost / b.sent if b.sent else float('nan')
        print(f'  {b.kind:<12}burst {b.size:>5} x{b.repeats}  sent {b.sent:>6}  lost {b.lost:>5} ({pct:.2f} %), '
              f'worst burst {b.worst_burst_lost}, published in {1e3 * b.publish_s:.1f} ms'
              + (f'  node: {_node_counts(b.node_received, b.node_lost, b.accounted)}'
                 if b.node_received is not None else ''))


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
                             "required (default relay,feedforward)")
    parser.add_argument('--drop-rates', default='3000',
                        help='comma-separated rates [Hz] of extra drop runs (relay and feedforward, one each, '
                             '--drop-duration long); the latency rounds report drops at --rate already (3000)')
    parser.add_argument('--drop-duration', type=float, default=5.0, help='send window of a drop run [s] (5)')
    parser.add_argument('--bursts', default='20,1000,5000',
                        help='comma-separated sizes of back-to-back bursts (20,1000,5000: the last overflows the '
                             "node's 1000-deep queue, to show the loss is counted)")
    parser.add_argument('--burst-repeats', type=int, default=3, help='bursts of each size (3)')
    parser.add_argument('--no-drops', action='store_true', help='only the latency rounds')
    parser.add_argument('--detail-rate', type=float, default=200.0,
                        help='measured_detail samples per second published in the latency rounds [Hz] (default 200; '
                        'the learning node learns from them)')
    parser.add_argument('--json', action='store_true', help='print one JSON document instead of the table')
    args = parser.parse_args(argv)
    try:
        drop_rates = [float(x) for x in args.drop_rates.split(',') if x.strip()]
        bursts = [int(x) for x in args.bursts.split(',') if x.strip()]
    except ValueError:
        parser.error('--drop-rates and --bursts are comma-separated numbers')
    if args.no_drops:
        drop_rates, bursts = [], []
    if any(r <= 0 for r in drop_rates) or any(b < 1 for b in bursts) or args.burst_repeats < 1 \
            or args.drop_duration < args.warmup + 2.0:
        parser.error('need rates > 0, burst sizes >= 1, --burst-repeats >= 1, --drop-duration >= --warmup + 2 s')
    if args.duration < args.warmup + 2.0 or args.rounds < 1 or args.rate <= 0:
        parser.error('need --duration >= --warmup + 2 s, --rounds >= 1, --rate > 0')
    kinds = [k.strip() for k in args.nodes.split(',') if k.strip()]
    if 'relay' not in kinds or len(kinds) < 2 or len(set(kinds)) != len(kinds) \
            or not set(kinds) <= set(KINDS):
        parser.error(f"--nodes: 'relay' and at least one of {', '.join(KINDS[1:])}, each once")
    if args.detail_rate < 0:
        parser.error('--detail-rate must be >= 0')

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
                                            args.backlog_ms, args.detail_rate))
            drop_runs: list[RunResult] = []
            for rate in drop_rates:
                for kind in ('relay', 'feedforward'):
                    if not args.json:
                        print(f'drops at {rate:g} Hz: {kind} ...', file=sys.stderr, flush=True)
                    drop_runs.append(run_once(kind, 0, did, env, log_dir, args.drop_duration, rate, args.warmup,
                                              args.backlog_ms))
            burst_runs: list[BurstResult] = []
            if bursts:
                for kind in ('relay', 'feedforward'):
                    if not args.json:
                        print(f'bursts: {kind} ...', file=sys.stderr, flush=True)
                    burst_runs += run_bursts(kind, did, env, log_dir, bursts, args.burst_repeats)
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
        drops = [{k: v for k, v in asdict(r).items() if k != 'latencies_us'} for r in drop_runs]
        print(json.dumps({'config': config, 'runs': runs, 'summary': summary, 'drop_runs': drops,
                          'bursts': [asdict(b) for b in burst_runs]}, indent=2))
    else:
        print_report(config, results, summary)
        print_drops(results, drop_runs, burst_runs)
    return 0


if __name__ == '__main__':
    sys.exit(main())
