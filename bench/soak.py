"""Soak: the three nodes of the suite fed at 1 kHz for ten minutes (on demand, not in CI): memory and drops.

Starts ``friction_feedforward``, ``friction_estimator`` and ``residual_logger`` as their own processes with the
documented command (``--params-file config/gimbal_friction.yaml``; the log in a temporary folder), on a private
ROS domain with loopback discovery, plus a **publisher process** (this file with ``--publisher``) that plays a
chamber test: ``/joint_states`` and ``/gimbal/motor_current`` at ``--rate`` (1 kHz), ``/gimbal/temperature`` at
10 Hz, the gimbal sweeping -6..+11 deg at 1/3 rpm while the temperature ramps from -40 to +60 degC. This process
monitors:

- **RSS** of every node (``VmRSS`` of /proc/<pid>/status) every ``--sample-s`` (10 s): start (after the first
  minute's warm-up sample), end, max, and the growth per minute over the run after the first sample;
- **drops per node**: each node's own ``/diagnostics`` counts (``received: <topic>``, ``lost: <topic>``, from gaps
  in the publisher's sequence numbers) against what the publisher sent (``accounted``: received + lost = sent);
- what came out: feedforward messages published, estimator samples accepted, residual rows logged; and that every
  node is alive at the end and exits 0 on SIGINT.

Prints a table (or ``--json``); progress on stderr once a minute. Run from the repository root::

    .venv/bin/python bench/soak.py                 # 10 minutes at 1 kHz
    .venv/bin/python bench/soak.py --minutes 2     # a short try

Numbers of this machine: see bench/README.md and docs/robustness.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PARAMS_FILE = ROOT / 'config' / 'gimbal_friction.yaml'
NODES = ('friction_feedforward', 'friction_estimator', 'residual_logger')
JS, CUR, TEMP = '/joint_states', '/gimbal/motor_current', '/gimbal/temperature'
V = 2.0 * math.pi / 180.0                 # 1/3 rpm [rad/s]
LOW, HIGH = math.radians(-6.0), math.radians(11.0)
KT, FRICTION_NM = 0.05, 0.0025           # the packaged K_T [N*m/A]; a plausible friction [N*m]


# ------------------------------------------------------------------------------------------------ the publisher
def run_publisher(rate_hz: float, seconds: float, domain: int) -> int:
    """Publish the chamber test for ``seconds``; print one JSON line with what was sent."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, qos_profile_sensor_data
    from sensor_msgs.msg import JointState, Temperature

    rclpy.init(domain_id=domain)
    node = Node('soak_publisher')
    qos = QoSProfile(depth=10)        # what a joint_state_broadcaster uses
    pub_js = node.create_publisher(JointState, JS, qos)
    pub_cur = node.create_publisher(JointState, CUR, qos)
    pub_t = node.create_publisher(Temperature, TEMP, qos_profile_sensor_data)
    # wait for the three nodes' subscriptions (feedforward, estimator, logger on /joint_states)
    deadline = time.monotonic() + 30.0
    while pub_js.get_subscription_count() < 3 or pub_cur.get_subscription_count() < 2:
        if time.monotonic() > deadline:
            print(json.dumps({'error': 'subscribers did not appear'}), flush=True)
            return 1
        time.sleep(0.05)
    time.sleep(1.0)   # let the other direction of discovery finish too
    js = JointState(name=['elevation'], position=[0.0], velocity=[V])
    cur = JointState(name=['elevation'], effort=[0.0])
    temp = Temperature(variance=0.0)
    period_ns = int(round(1e9 / rate_hz))
    n = int(seconds * rate_hz)
    t0 = time.monotonic_ns()
    stamp0 = time.time_ns()
    position, direction = 0.0, 1.0
    sent = {JS: 0, CUR: 0, TEMP: 0}
    late = 0
    temp_every = max(1, int(rate_hz / 10))
    for k in range(n):
        due = t0 + k * period_ns
        now = time.monotonic_ns()
        if due > now:
            time.sleep((due - now) * 1e-9)
        elif now - due > period_ns:
            late += 1
        stamp = stamp0 + k * period_ns
        sec, nanosec = divmod(stamp, 1_000_000_000)
        position += direction * V / rate_hz
        if position > HIGH or position < LOW:
            direction = -direction
        if k % temp_every == 0:
            temp.header.stamp.sec, temp.header.stamp.nanosec = sec, nanosec
            temp.temperature = -40.0 + 100.0 * k / max(n - 1, 1)
            pub_t.publish(temp)
            sent[TEMP] += 1
        js.header.stamp.sec, js.header.stamp.nanosec = sec, nanosec
        js.position[0], js.velocity[0] = position, direction * V
        pub_js.publish(js)
        cur.header.stamp.sec, cur.header.stamp.nanosec = sec, nanosec
        cur.effort[0] = direction * FRICTION_NM / KT + 0.001 * math.sin(0.7 * k)
        pub_cur.publish(cur)
        sent[JS] += 1
        sent[CUR] += 1
    elapsed = (time.monotonic_ns() - t0) * 1e-9
    from rclpy.duration import Duration
    acked = all(p.wait_for_all_acked(Duration(seconds=5)) for p in (pub_js, pub_cur))   # reliable: delivered
    print(json.dumps({'sent': sent, 'late': late, 'seconds': elapsed, 'all_acked': acked}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ------------------------------------------------------------------------------------------------ the monitor
def cpu_s(pid: int) -> float:
    """utime + stime of a process (all threads) [s], NaN once it is gone."""
    try:
        text = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return math.nan
    fields = text[text.rindex(')') + 2:].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def rss_mb(pid: int) -> float:
    """Resident set size of a process [MB] (VmRSS), NaN once it is gone."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


class Monitor:
    """Latest /diagnostics values of each node (by status name prefix)."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('soak_monitor', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.values: dict[str, dict[str, str]] = {}
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            key = ('friction_feedforward' if st.name.startswith('gimbal_friction/feedforward/') else
                   'friction_estimator' if st.name == 'gimbal_friction/estimator' else
                   'friction_estimator/joint' if st.name.startswith('gimbal_friction/estimator/') and
                   '/statistics/' not in st.name else
                   'residual_logger' if st.name == 'gimbal_friction/residual_logger' else None)
            if key is not None:
                self.values[key] = {kv.key: kv.value for kv in st.values}

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def start(cmd: list[str], env: dict[str, str], log: Path) -> subprocess.Popen[bytes]:
    fh = open(log, 'wb')  # noqa: SIM115 - closed with the process
    return subprocess.Popen(cmd, env=env, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True, cwd=ROOT)


def stop(proc: subprocess.Popen[bytes]) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return int(proc.returncode)


def node_command(name: str, log_dir: Path) -> list[str]:
    exe = BIN / name
    cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', f'gimbal_friction.nodes.{name.split("_", 1)[1]}']
    cmd += ['--ros-args', '--params-file', str(PARAMS_FILE)]
    if name == 'residual_logger':
        cmd += ['-p', f'output_dir:={log_dir / "residuals"}']
    return cmd


def soak(minutes: float, rate_hz: float, sample_s: float) -> dict[str, Any]:
    from domain_coordinator import domain_id

    with domain_id() as did, tempfile.TemporaryDirectory(prefix='soak_') as tmp:
        log_dir = Path(tmp)
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   ROS_LOG_DIR=str(log_dir / 'roslog'), PYTHONUNBUFFERED='1')
        os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_LOG_DIR=str(log_dir / 'roslog'))
        procs: dict[str, subprocess.Popen[bytes]] = {}
        publisher: subprocess.Popen[bytes] | None = None
        monitor: Monitor | None = None
        try:
            procs = {name: start(node_command(name, log_dir), env, log_dir / f'{name}.log') for name in NODES}
            monitor = Monitor(did)
            seconds = 60.0 * minutes
            publisher = subprocess.Popen([sys.executable, __file__, '--publisher', '--rate', str(rate_hz),
                                          '--seconds', str(seconds), '--domain', str(did)], env=env,
                                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT,
                                         start_new_session=True)
            samples: dict[str, list[tuple[float, float]]] = {n: [] for n in NODES}
            t0 = time.monotonic()
            cpu0 = {name: cpu_s(proc.pid) for name, proc in procs.items()}
            next_sample = t0
            next_report = t0 + 60.0
            while publisher.poll() is None:
                monitor.spin(0.5)
                now = time.monotonic()
                if now >= next_sample:
                    for name, proc in procs.items():
                        samples[name].append((now - t0, rss_mb(proc.pid)))
                    next_sample += sample_s
                if now >= next_report:
                    rss = ', '.join(f'{n} {samples[n][-1][1]:.0f} MB' for n in NODES)
                    print(f'soak: {(now - t0) / 60:.0f} min: RSS {rss}', file=sys.stderr, flush=True)
                    next_report += 60.0
                if now - t0 > seconds + 120.0:
                    publisher.kill()
            out = (publisher.stdout.read() if publisher.stdout else b'').decode(errors='replace')
            sent_line = [line for line in out.splitlines() if line.startswith('{')]
            pub: dict[str, Any] = json.loads(sent_line[-1]) if sent_line else {'error': out[-500:]}
            monitor.spin(3.0)                      # the last reports after the last message
            for name, proc in procs.items():
                samples[name].append((time.monotonic() - t0, rss_mb(proc.pid)))
            alive = {name: proc.poll() is None for name, proc in procs.items()}
            cpu_pct = {name: 100.0 * (cpu_s(proc.pid) - cpu0[name]) / (time.monotonic() - t0)
                       for name, proc in procs.items()}
            values = dict(monitor.values)
        finally:   # never leave a process of this run behind
            if publisher is not None and publisher.poll() is None:
                publisher.kill()
                publisher.wait()
            if monitor is not None:
                monitor.close()
            codes = {name: stop(proc) for name, proc in procs.items()}
    result: dict[str, Any] = {'minutes': minutes, 'rate_hz': rate_hz, 'publisher': pub, 'nodes': {}}
    sent = pub.get('sent', {})
    for name in NODES:
        s = [(t, r) for t, r in samples[name] if math.isfinite(r)]
        after = [(t, r) for t, r in s if t >= min(60.0, 0.25 * 60.0 * minutes)] or s
        growth = ((after[-1][1] - after[0][1]) / ((after[-1][0] - after[0][0]) / 60.0)
                  if len(after) > 1 and after[-1][0] > after[0][0] else math.nan)
        v = values.get(name, {})
        drops = {}
        for topic in (JS, CUR, TEMP, '/gimbal/friction/feedforward', '/gimbal/friction/measured_detail'):
            if f'received: {topic}' in v:
                received, lost = int(v[f'received: {topic}']), v[f'lost: {topic}']
                drops[topic] = {'received': received, 'lost': lost,
                                'sent': sent.get(topic),
                                'accounted': (lost != 'unknown' and topic in sent
                                              and received + int(lost) == sent[topic])}
        outputs = {'friction_feedforward': ('published', v.get('published')),
                   'friction_estimator': ('accepted', values.get('friction_estimator/joint', {}).get('accepted')),
                   'residual_logger': ('residuals_logged', v.get('residuals_logged'))}[name]
        result['nodes'][name] = {
            'rss_start_mb': after[0][1] if after else math.nan, 'rss_end_mb': s[-1][1] if s else math.nan,
            'rss_max_mb': max((r for _, r in s), default=math.nan), 'rss_growth_mb_per_min': growth,
            'cpu_pct': cpu_pct[name], 'alive_at_end': alive[name], 'exit_code': codes[name], 'drops': drops,
            outputs[0]: outputs[1],
            'rss_samples': s}
    return result


def print_report(r: dict[str, Any]) -> None:
    pub = r['publisher']
    print(f"soak: {r['minutes']:g} min at {r['rate_hz']:g} Hz; publisher sent {pub.get('sent')} in "
          f"{pub.get('seconds', math.nan):.1f} s ({pub.get('late', '?')} sends late)")
    print(f"{'node':<22}{'RSS start':>10}{'end':>8}{'max':>8}{'MB/min':>8}{'CPU':>7}  alive  exit  outputs")
    for name, n in r['nodes'].items():
        out_key = next(k for k in ('published', 'accepted', 'residuals_logged') if k in n)
        print(f"{name:<22}{n['rss_start_mb']:>9.1f} {n['rss_end_mb']:>7.1f} {n['rss_max_mb']:>7.1f} "
              f"{n['rss_growth_mb_per_min']:>7.2f} {n['cpu_pct']:>5.0f}%  {'yes' if n['alive_at_end'] else 'NO':>5}  "
              f"{n['exit_code']:>4}  "
              f"{out_key} {n[out_key]}")
    print("drops per node (the node's own /diagnostics count; accounted = received + lost = sent by the publisher)")
    for name, n in r['nodes'].items():
        for topic, d in n['drops'].items():
            sent = '' if d['sent'] is None else f" of {d['sent']} sent"
            acc = '' if d['sent'] is None else ('  accounted' if d['accounted'] else '  NOT ACCOUNTED')
            print(f"  {name:<22}{topic:<34} received {d['received']:>8}, lost {d['lost']}{sent}{acc}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--minutes', type=float, default=10.0, help='duration [min] (10)')
    parser.add_argument('--rate', type=float, default=1000.0, help='joint-state and current rate [Hz] (1000)')
    parser.add_argument('--sample-s', type=float, default=10.0, help='RSS sampling period [s] (10)')
    parser.add_argument('--json', action='store_true', help='one JSON document instead of the table')
    parser.add_argument('--publisher', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--seconds', type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument('--domain', type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.publisher:
        return run_publisher(args.rate, args.seconds, args.domain)
    if args.minutes <= 0 or args.rate <= 0 or args.sample_s <= 0:
        parser.error('--minutes, --rate and --sample-s must be > 0')
    r = soak(args.minutes, args.rate, args.sample_s)
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        print_report(r)
    ok = all(n['alive_at_end'] and n['exit_code'] == 0 for n in r['nodes'].values())
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
