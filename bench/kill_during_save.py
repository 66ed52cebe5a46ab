"""What ``friction_feedforward`` loses when it is killed (SIGKILL) during a save of its learned correction.

Starts the node as its own process (the documented command, ``learning_enabled``, a ``correction_file`` in a
temporary folder, ``--save-period-s``: 0.2 s), on a private ROS domain with loopback discovery. This process publishes
a fresh temperature and learnable samples on ``/gimbal/friction/measured_detail`` at ``--rate`` (both directions,
stamped with the wall clock) and watches the folder: as soon as a save's temporary file appears, the node is killed.
The file left behind holds N samples; the loss is the time from the sending of sample N + 1 to the kill [s].
Also read: the node's last ``last_save_duration_s`` and ``unsaved_learning_s`` before the kill (``/diagnostics``).

Prints one line per kill and the range. Run from the repository root (a few seconds per kill)::

    .venv/bin/python bench/kill_during_save.py --kills 10
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def one_kill(domain: int, folder: Path, save_period_s: float, rate_hz: float, warm_s: float) -> dict[str, Any]:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Temperature
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    from gimbal_friction.feedforward.correction import load
    from gimbal_friction.runs.supervisor import node_command
    from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS as F

    path = folder / 'correction.yaml'
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_LOG_DIR=str(folder / 'log'))
    cmd = [*node_command('friction_feedforward'), '--ros-args', '--params-file',
           str(ROOT / 'config' / 'gimbal_friction.yaml'), '-p', 'learning_enabled:=true', '-p',
           f'correction_file:={path}', '-p', f'learning_save_period_s:={save_period_s}', '-p',
           'diagnostics_period_s:=0.1', '-p', 'temperature_timeout_s:=600.0']
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node('kill_probe', context=ctx)
    ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    pub = node.create_publisher(Float64MultiArray, '/gimbal/friction/measured_detail', QoSProfile(depth=1000))
    tpub = node.create_publisher(Temperature, '/gimbal/temperature', QoSProfile(depth=10))
    diag: dict[str, str] = {}

    def on_diag(msg: Any) -> None:
        for st in msg.status:
            if st.name == 'gimbal_friction/feedforward/learning':
                diag.clear()
                diag.update({kv.key: kv.value for kv in st.values})
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QoSProfile(depth=50))
    try:
        while pub.get_subscription_count() < 1 or not diag:
            ex.spin_once(timeout_sec=0.05)
            if proc.poll() is not None:
                raise RuntimeError('the node ended before it matched')
        sent_at: list[float] = []
        t_start = time.time()
        next_t = 0.0
        killed_at = math.nan
        while True:
            now = time.time()
            if len(sent_at) % 200 == 0:
                temp = Temperature(temperature=-40.0)
                temp.header.stamp = node.get_clock().now().to_msg()
                tpub.publish(temp)
            d = [0.0] * len(F)
            sign = 1.0 if (len(sent_at) // 50) % 2 == 0 else -1.0
            d[F.index('stamp_sec')], d[F.index('stamp_nanosec')] = float(int(now)), float(int(now % 1.0 * 1e9))
            d[F.index('velocity_rad_s')], d[F.index('friction_nm')] = sign * 0.0349, sign * 3.3e-3
            d[F.index('temperature_fresh')], d[F.index('method')] = 1.0, 1.0
            msg = Float64MultiArray(data=d)
            msg.layout.dim = [MultiArrayDimension(label='elevation', size=1, stride=1)]
            pub.publish(msg)
            sent_at.append(time.time())
            ex.spin_once(timeout_sec=0.0)
            if now - t_start > warm_s and any(p.name.endswith('.tmp') for p in folder.iterdir()):
                before = dict(diag)
                proc.send_signal(signal.SIGKILL)
                killed_at = time.time()
                break
            next_t += 1.0 / rate_hz
            pause = t_start + next_t - time.time()
            if pause > 0:
                time.sleep(pause)
        proc.wait()
        n = load(path).summary()['samples'] if path.exists() else 0
        lost_s = killed_at - sent_at[n] if n < len(sent_at) else 0.0
        return {'sent': len(sent_at), 'in_file': n, 'lost_s': lost_s,
                'last_save_duration_s': before.get('last_save_duration_s'),
                'unsaved_learning_s': before.get('unsaved_learning_s'),
                'received': before.get('received: /gimbal/friction/measured_detail')}
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        node.destroy_node()
        ctx.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--kills', type=int, default=10)
    ap.add_argument('--save-period-s', type=float, default=0.2)
    ap.add_argument('--rate', type=float, default=500.0, help='samples per second sent [Hz]')
    ap.add_argument('--warm-s', type=float, default=2.0, help='learning before the first kill may come [s]')
    args = ap.parse_args(argv)
    from gimbal_friction.runs.supervisor import free_domain
    losses = []
    with free_domain() as domain:
        for k in range(args.kills):
            with tempfile.TemporaryDirectory() as tmp:
                r = one_kill(domain, Path(tmp), args.save_period_s, args.rate, args.warm_s)
            losses.append(r['lost_s'])
            print(f'kill {k + 1}: sent {r["sent"]}, in the file {r["in_file"]}, lost {r["lost_s"]:.3f} s; before the '
                  f'kill: last_save_duration_s {r["last_save_duration_s"]}, unsaved_learning_s '
                  f'{r["unsaved_learning_s"]}, received {r["received"]}', flush=True)
    print(f'save period {args.save_period_s:g} s, {args.rate:g} samples/s: lost {min(losses):.3f} .. '
          f'{max(losses):.3f} s over {len(losses)} kills during a save')
    return 0


if __name__ == '__main__':
    sys.exit(main())
