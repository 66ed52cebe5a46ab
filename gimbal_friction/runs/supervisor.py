"""Starting and stopping the suite's nodes as processes: the supervisor shared by the main job and the live loop study.

:class:`Supervisor` starts node executables of this environment and always stops them (SIGINT, then SIGTERM, then
SIGKILL); :class:`Watcher` is a probe node in the calling process that waits for the graph to connect and counts
measurements.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from gimbal_friction.recording import topics
from gimbal_friction.runs.live_counts import Reports

#: the nodes of the main job, in start order
NODES = ('friction_feedforward', 'friction_estimator', 'residual_logger')


def node_command(name: str) -> list[str]:
    """The command that starts node executable ``name`` of this environment."""
    path = Path(sys.executable).parent / name
    return [str(path)] if path.exists() else [sys.executable, '-m', f'gimbal_friction.nodes.{name}']


@contextlib.contextmanager
def packaged_params_file() -> Iterator[Path]:
    with resources.as_file(resources.files('gimbal_friction').joinpath('data', 'gimbal_friction.yaml')) as p:
        yield p


class Supervisor:
    """Starts node processes and always stops them (SIGINT, then SIGTERM, then SIGKILL)."""

    def __init__(self, env: dict[str, str], log_dir: Path) -> None:
        self.env = env
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, args: Sequence[str]) -> subprocess.Popen[bytes]:
        log = open(self.log_dir / f'{name}.log', 'wb')  # noqa: SIM115 - closed with the process
        proc = subprocess.Popen(node_command(name) + list(args), env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.procs[name] = proc
        return proc

    def check_alive(self) -> None:
        for name, proc in self.procs.items():
            if proc.poll() is not None and name != 'chamber_replay':
                tail = (self.log_dir / f'{name}.log').read_text(errors='replace').strip().splitlines()[-3:]
                msg = f'{name} exited early (code {proc.returncode}): ' + ' | '.join(tail)
                raise RuntimeError(msg)

    def stop(self, name: str) -> int | None:
        """Stop process ``name`` (SIGINT, then SIGTERM, then SIGKILL) and forget it; its exit code."""
        proc = self.procs.pop(name)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        return _wait_stopped(proc)

    def stop_all(self) -> dict[str, int | None]:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        return {name: _wait_stopped(proc) for name, proc in self.procs.items()}


def _wait_stopped(proc: subprocess.Popen[bytes]) -> int | None:
    """Wait for a process sent SIGINT (15 s), then SIGTERM (5 s), then SIGKILL; its exit code."""
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


class Watcher:
    """A probe node in this process: waits for the graph to connect, counts the measurements it sees (for progress
    only: a busy machine makes it miss some) and keeps what the nodes report on ``/diagnostics``
    (:attr:`reports`, :mod:`gimbal_friction.runs.live_counts`)."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import JointState
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('demo_watcher', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.measured = 0
        self.last_measured = time.monotonic()
        self.node.create_subscription(JointState, topics.MEASURED, self._on_measured, 100)
        self.reports = Reports()
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 100)

    def _on_measured(self, _msg: Any) -> None:
        self.measured += 1
        self.last_measured = time.monotonic()

    def _on_diagnostics(self, msg: Any) -> None:
        for st in msg.status:
            self.reports.add(st.name, {kv.key: kv.value for kv in st.values})

    def wait_settled(self, timeout_s: float) -> bool:
        """Spin until the nodes' counts have settled (:meth:`Reports.settled`) or ``timeout_s`` [s] passed."""
        deadline = time.monotonic() + timeout_s
        while not self.reports.settled():
            if time.monotonic() > deadline:
                return False
            self.spin(0.1)
        return True

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))

    def connected(self) -> bool:
        n = self.node
        return (n.count_subscribers(topics.JOINT_STATES) >= 3 and n.count_subscribers(topics.MOTOR_CURRENT) >= 2
                and n.count_subscribers(topics.TEMPERATURE) >= 3 and n.count_subscribers(topics.FEEDFORWARD) >= 1
                and n.count_subscribers(topics.MEASURED) >= 2 and n.count_publishers(topics.MEASURED) >= 1
                and n.count_publishers(topics.FEEDFORWARD) >= 1)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
