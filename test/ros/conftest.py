"""Fixtures for node tests: real rclpy and real DDS on an isolated ROS_DOMAIN_ID, loopback only.

Each test gets its own domain (ros-domain-coordinator) and ROS_LOG_DIR; nodes run as their own processes (the
installed console scripts) and are stopped with SIGINT. Waits are on conditions with generous timeouts.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip('rclpy', reason='node tests need the ros-* wheels (requirements.txt)')
from domain_coordinator import domain_id  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
TIMEOUT = 20.0


@pytest.fixture
def ros_env(tmp_path: Path) -> Iterator[tuple[int, dict[str, str]]]:
    with domain_id() as did:
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   ROS_LOG_DIR=str(tmp_path / 'roslog'), PYTHONUNBUFFERED='1')
        yield did, env


class NodeProcess:
    """A node started as its own process; ``stop()`` sends SIGINT and returns (exit code, output)."""

    def __init__(self, exe: str, args: list[str], env: dict[str, str], log: Path) -> None:
        path = BIN / exe
        cmd = [str(path)] if path.exists() else [sys.executable, '-m', f'gimbal_friction.nodes.{exe}']
        self.log = log
        self._fh = open(log, 'wb')  # noqa: SIM115
        self.proc = subprocess.Popen(cmd + args, env=env, stdout=self._fh, stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def output(self) -> str:
        return self.log.read_text(errors='replace')

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGINT) -> tuple[int, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
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
        return self.proc.returncode, self.output()


@pytest.fixture
def spawn(ros_env: tuple[int, dict[str, str]], tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    procs: list[NodeProcess] = []

    def start(exe: str, *args: str, env: dict[str, str] | None = None) -> NodeProcess:
        p = NodeProcess(exe, list(args), env or ros_env[1], tmp_path / f'{exe}_{len(procs)}.log')
        procs.append(p)
        return p

    yield start
    for p in procs:
        p.stop()


class Probe:
    """A test-side node on a private context in the test's domain: publish, collect, wait."""

    def __init__(self, domain: int) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('probe', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict[str, list[Any]] = {}
        self.pubs: dict[str, Any] = {}

    def subscribe(self, msg_type: Any, topic: str, qos: Any = 50) -> None:
        self.received.setdefault(topic, [])
        self.node.create_subscription(msg_type, topic, lambda m, t=topic: self.received[t].append(m), qos)

    def publisher(self, msg_type: Any, topic: str, depth: int = 1000) -> Any:
        if topic not in self.pubs:
            self.pubs[topic] = self.node.create_publisher(msg_type, topic, depth)
        return self.pubs[topic]

    def spin_until(self, cond: Callable[[], bool], timeout: float = TIMEOUT, what: str = 'condition') -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if cond():
                return
            self.executor.spin_once(timeout_sec=0.05)
        if not cond():
            raise AssertionError(f'timed out after {timeout:.0f} s waiting for {what}')

    def wait_matched(self, topic: str, subscribers: int = 1, timeout: float = TIMEOUT) -> None:
        pub = self.pubs[topic]
        self.spin_until(lambda: pub.get_subscription_count() >= subscribers, timeout, f'a subscriber on {topic}')

    def wait_publisher(self, topic: str, timeout: float = TIMEOUT) -> None:
        self.spin_until(lambda: self.node.count_publishers(topic) > 0, timeout, f'a publisher on {topic}')

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def probe(ros_env: tuple[int, dict[str, str]]) -> Iterator[Probe]:
    p = Probe(ros_env[0])
    yield p
    p.close()
