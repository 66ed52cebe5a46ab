"""Where the time of ``friction_feedforward``'s joint-state callback goes (in-process, no executor).

Builds the real node (``FrictionFeedforward``, config/gimbal_friction.yaml) on a private context and domain, and a
bare relay publisher on the same context, then calls the callback's steps directly and times each with
``time.perf_counter_ns`` over ``--n`` messages shaped like the benchmark's (1 joint, velocity +/-0.0349 rad/s):

- ``relay publish``: what the relay does (publish the received message);
- ``on_joint_state`` total;
- its parts: ``_velocities``, ``FeedforwardLogic.compute`` (with ``FrictionTable.components``), building the
  feedforward JointState, ``pub_ff.publish``, building the Float64MultiArray, ``pub_cmd.publish``.

A subscriber in another process can be attached with ``--subscriber`` so the publishes cost what they cost in the
benchmark (a matched reader). Results in microseconds (p50 / mean / p99). A diagnostic, not a test.

Run from the repository root:  ``.venv/bin/python bench/profile_callback.py [--n 20000] [--subscriber]``
"""

from __future__ import annotations

import argparse
import gc
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Sequence

ROOT = Path(__file__).resolve().parents[1]
FF_TOPIC = '/gimbal/friction/feedforward'
CMD_TOPIC = '/gimbal/friction/feedforward_commands'

SUBSCRIBER = r'''
import sys, rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
rclpy.init()
n = Node('profile_sink')
n.create_subscription(JointState, sys.argv[1], lambda m: None, QoSProfile(depth=10))
n.create_subscription(JointState, sys.argv[1] + '_relay', lambda m: None, QoSProfile(depth=10))
if sys.argv[3] == '1':
    n.create_subscription(Float64MultiArray, sys.argv[2], lambda m: None, QoSProfile(depth=10))
from rclpy.experimental import EventsExecutor
ex = EventsExecutor(); ex.add_node(n)
try:
    while rclpy.ok():
        ex.spin_once(timeout_sec=0.25)
except KeyboardInterrupt:
    pass
'''


def stats(ns: list[int]) -> str:
    s = sorted(ns)
    n = len(s)
    return (f'{s[n // 2] / 1e3:7.1f} {sum(s) / n / 1e3:7.1f} {s[min(n - 1, int(0.99 * n))] / 1e3:7.1f}')


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--n', type=int, default=20000, help='messages per measurement (default 20000)')
    parser.add_argument('--subscriber', action='store_true',
                        help='attach a subscriber process to the feedforward (and relay) topic first')
    parser.add_argument('--rate', type=float, default=0.0,
                        help='pace the calls at this rate [Hz] (0 = back to back; use 1000 with --subscriber so the '
                             'reader is not flooded)')
    parser.add_argument('--cmd-subscriber', action='store_true',
                        help='with --subscriber: also subscribe feedforward_commands')
    args = parser.parse_args(argv)

    from domain_coordinator import domain_id
    with domain_id() as did, tempfile.TemporaryDirectory(prefix='ff_profile_') as tmp:
        os.environ.update(ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                          ROS_LOG_DIR=str(Path(tmp) / 'roslog'))
        import rclpy
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState

        from gimbal_friction.nodes.feedforward import FrictionFeedforward

        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=did,
                   args=['profile', '--ros-args', '--params-file', str(ROOT / 'config' / 'gimbal_friction.yaml')])
        node = FrictionFeedforward(context=ctx)
        relay_pub = node.create_publisher(JointState, FF_TOPIC + '_relay', QoSProfile(depth=10))
        node.on_temperature(type('T', (), {'temperature': 35.0})())
        sink = None
        try:
            if args.subscriber:
                sink = subprocess.Popen([sys.executable, '-c', SUBSCRIBER, FF_TOPIC, CMD_TOPIC,
                                         '1' if args.cmd_subscriber else '0'], env=dict(os.environ),
                                        start_new_session=True, stderr=subprocess.DEVNULL)
                deadline = time.monotonic() + 20.0
                want_cmd = 1 if args.cmd_subscriber else 0
                while not (node.pub_ff.get_subscription_count() >= 1 and relay_pub.get_subscription_count() >= 1
                           and node.pub_cmd.get_subscription_count() >= want_cmd):
                    if time.monotonic() > deadline:
                        print('profile_callback: error: subscriber did not match in 20 s', file=sys.stderr)
                        return 1
                    time.sleep(0.02)  # noqa: discovery runs in Fast DDS threads; nothing to spin here
            msgs = []
            for i in range(2):
                m = JointState(name=['elevation'], position=[0.0], velocity=[(1 - 2 * i) * 0.0349])
                m.header.stamp.sec = i
                msgs.append(m)
            results = profile(node, relay_pub, msgs, args.n, args.rate)
        finally:
            if sink is not None:
                sink.send_signal(2)
                try:
                    sink.wait(10)
                except subprocess.TimeoutExpired:
                    sink.kill()
                    sink.wait()
            node.destroy_node()
            ctx.try_shutdown()
    print(f'friction_feedforward callback, {args.n} messages '
          f'{"back to back" if not args.rate else f"at {args.rate:g} Hz"}, '
          f'{"with" if args.subscriber else "without"} a matched subscriber on {FF_TOPIC}'
          f'{" and " + CMD_TOPIC if args.cmd_subscriber else ""}')
    print(f'{"step":<44}{"p50 us":>8}{"mean":>8}{"p99":>8}')
    for name, ns in results:
        print(f'{name:<44}{stats(ns)}')
    return 0


def profile(node, relay_pub, msgs, n: int, rate_hz: float) -> list[tuple[str, list[int]]]:  # noqa: ANN001
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    from sensor_msgs.msg import JointState

    from gimbal_friction.nodes._common import monotonic_s

    pc = time.perf_counter_ns
    out: list[tuple[str, list[int]]] = []
    period = 1.0 / rate_hz if rate_hz > 0 else 0.0
    warm = min(n, 2000) if period == 0.0 else min(n, 200)
    next_t = [time.monotonic()]

    def pace() -> None:
        if period:
            next_t[0] += period
            delay = next_t[0] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t[0] = time.monotonic()

    def run(name: str, fn: Callable[[int], None]) -> None:
        for i in range(warm):  # warm-up
            pace()
            fn(i)
        ns = []
        for i in range(n):
            pace()
            t0 = pc()
            fn(i)
            ns.append(pc() - t0)
        out.append((name, ns))

    run('relay: publish(received msg)', lambda i: relay_pub.publish(msgs[i & 1]))
    gc_log: list[tuple[int, int]] = []   # (generation, duration [ns]) of collections during the next run
    gc_start = [0]

    def on_gc(phase: str, info: dict) -> None:  # noqa: ANN001
        if phase == 'start':
            gc_start[0] = pc()
        else:
            gc_log.append((info['generation'], pc() - gc_start[0]))

    gc.callbacks.append(on_gc)
    try:
        run('feedforward: on_joint_state (total)', lambda i: node.on_joint_state(msgs[i & 1]))
    finally:
        gc.callbacks.remove(on_gc)
    for gen in (0, 1, 2):
        durations = [d for g, d in gc_log if g == gen]
        if durations:
            out.append((f'  gc gen {gen}: {len(durations)} collections in that run', durations))
    if not gc_log:
        print('gc: no collection during the on_joint_state run (objects die by refcount; GC is not a factor)')

    parts: dict[str, list[int]] = {k: [] for k in (
        '  _velocities', '  FeedforwardLogic.compute', '    of which FrictionTable.components',
        '  build feedforward JointState', '  pub_ff.publish', '  build Float64MultiArray (+command_vector)',
        '  pub_cmd.publish')}
    logic = node.logic
    table = logic.tables['elevation']
    for i in range(n + warm):
        pace()
        msg = msgs[i & 1]
        t0 = pc()
        names, velocities = node._velocities(msg)
        t1 = pc()
        o = logic.compute(names, velocities, monotonic_s())
        t2 = pc()
        ff = JointState()
        ff.header.stamp = msg.header.stamp
        ff.header.frame_id = msg.header.frame_id
        ff.name = [j.name for j in o.joints]
        ff.effort = [j.torque_nm for j in o.joints]
        t3 = pc()
        node.pub_ff.publish(ff)
        t4 = pc()
        cmd = Float64MultiArray()
        cmd.layout.dim = [MultiArrayDimension(label='joints', size=len(logic.axes), stride=len(logic.axes))]
        cmd.data = logic.command_vector(o)
        t5 = pc()
        node.pub_cmd.publish(cmd)
        t6 = pc()
        table.components(35.0, 0.0349 * 9.549296585513721)
        t7 = pc()
        if i < warm:
            continue
        for key, dt in zip(parts, (t1 - t0, t2 - t1, t7 - t6, t3 - t2, t4 - t3, t5 - t4, t6 - t5)):
            parts[key].append(dt)
    out.extend(parts.items())
    pre = [a + b + c for a, b, c in zip(parts['  _velocities'], parts['  FeedforwardLogic.compute'],
                                        parts['  build feedforward JointState'])]
    out.append(('before pub_ff.publish (current, sum of 3)', pre))

    # A leaner sketch of the same output (not the node's code): reuse one output message and the input header,
    # skip the per-joint NamedTuple/list/dict work of compute() and go straight to joint_torque().
    lean_msg = JointState()
    axes = logic.axes
    lean = []
    for i in range(n + warm):
        pace()
        msg = msgs[i & 1]
        t0 = pc()
        temperature, _ = logic.effective_temperature(monotonic_s())
        names = msg.name
        lean_msg.header = msg.header
        lean_msg.name = names
        lean_msg.effort = [logic.joint_torque(nm, v, temperature).torque_nm
                           for nm, v in zip(names, msg.velocity) if nm in axes]
        t1 = pc()
        node.pub_ff.publish(lean_msg)
        if i >= warm:
            lean.append(t1 - t0)
    out.append(('before pub_ff.publish (lean sketch)', lean))
    return out


if __name__ == '__main__':
    sys.exit(main())
