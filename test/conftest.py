"""Shared by the whole suite: the Hypothesis profiles, and the live-node harness (real rclpy nodes as their own
processes on an isolated ROS_DOMAIN_ID, loopback only) that test/ros and test/robustness both use.

Live nodes: each test gets its own domain (reserved with ros-domain-coordinator's port convention, and only if no
other node is seen on it) and ROS_LOG_DIR; nodes run as the installed
console scripts and are stopped with SIGINT; waits are on conditions with generous timeouts. rclpy is imported
only when a node fixture is used (the pure tests run without it).

Hypothesis profiles:

``ci`` (the default): derandomized, so a run of the test command is reproducible (the same examples every time;
a failure is a bug in the code, not in the draw). ``explore``: random examples on every run (500 where a test sets no
count) — run it when hunting (``HYPOTHESIS_PROFILE=explore bash scripts/test.sh test/robustness``); a random draw
found the damaged-chunk overflow that test_files_damaged.py now pins.
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
from hypothesis import HealthCheck, settings

settings.register_profile('ci', derandomize=True, print_blob=True, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile('explore', derandomize=False, print_blob=True, deadline=None,
                          max_examples=500, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Run the files with the most ``slow`` tests first (each file's tests in their own order): with xdist
    (``--dist loadfile``: a file whole on one worker) a long file at the end leaves the other workers idle."""
    by_file: dict[str, list[pytest.Item]] = {}
    for item in items:
        by_file.setdefault(item.nodeid.split('::')[0], []).append(item)
    weight = {f: sum(1 for i in its if i.get_closest_marker('slow')) for f, its in by_file.items()}
    items[:] = [i for f in sorted(by_file, key=lambda f: -weight[f]) for i in by_file[f]]


# ---------------------------------------------------------------------------------------------- live nodes
BIN = Path(sys.executable).parent
TIMEOUT = 20.0   #: [s] default wait for a condition


@pytest.fixture
def ros_env(tmp_path: Path) -> Iterator[tuple[int, dict[str, str]]]:
    """(domain id, environment) of the test: its own ROS_DOMAIN_ID (reserved through the domain coordinator, with no
    other node seen on it: :func:`gimbal_friction.runs.supervisor.free_domain`) and ROS_LOG_DIR, loopback
    discovery."""
    from gimbal_friction.runs.supervisor import free_domain

    with free_domain() as did:
        yield did, dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                        ROS_LOG_DIR=str(tmp_path / 'roslog'), PYTHONUNBUFFERED='1')


class NodeProcess:
    """A node executable as its own process (its output in a file); ``stop()`` sends SIGINT."""

    def __init__(self, exe: str, args: list[str], env: dict[str, str], log: Path) -> None:
        path = BIN / exe
        cmd = [str(path)] if path.exists() else [sys.executable, '-m', f'gimbal_friction.nodes.{exe}']
        self.log = log
        self._fh = log.open('wb')
        self.proc = subprocess.Popen([*cmd, *args], env=env, stdout=self._fh, stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def output(self) -> str:
        return self.log.read_text(errors='replace')

    def alive(self) -> bool:
        return self.proc.poll() is None

    def wait(self, timeout: float = 30.0) -> tuple[int, str]:
        """Wait for the process to end by itself: (exit code, output)."""
        code = self.proc.wait(timeout)
        self._fh.close()
        return code, self.output()

    def stop(self, sig: int = signal.SIGINT) -> tuple[int, str]:
        """Send ``sig`` (SIGINT) and wait: (exit code, output); terminate, then kill, if it does not end."""
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
    """``spawn(exe, *args, env=None)``: the executable as its own process in the test's domain; SIGINT at the end."""
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
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

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

    def call(self, srv: Any, name: str, request: Any, resend_s: float | None = None) -> Any:
        """Call the service ``name`` (type ``srv``) once it is ready; its answer. ``resend_s``: for a request that
        may be repeated (a query), ask again after this long without an answer (a response to a client whose reader
        the server had not matched yet is lost: discovery is not symmetric in time)."""
        client = self.node.create_client(srv, name)
        self.spin_until(client.service_is_ready, what=f'the service {name}')
        futures = [client.call_async(request)]
        sent = [time.monotonic()]

        def answered() -> bool:
            if resend_s is not None and time.monotonic() - sent[0] > resend_s:
                futures.append(client.call_async(request))
                sent[0] = time.monotonic()
            return any(f.done() for f in futures)

        self.spin_until(answered, what=f'an answer of {name}')
        return next(f for f in futures if f.done()).result()

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


def _zero_mcap_chunk_middle(path: Path, index: int) -> None:
    """Zero 16 bytes in the middle of chunk record ``index`` (0-based) of MCAP file ``path``: damaged chunks for the
    readers' skip-and-count rule."""
    data = bytearray(path.read_bytes())
    pos, k = 8, 0
    while True:
        length = int.from_bytes(data[pos + 1 : pos + 9], 'little')
        if data[pos] == 0x06:
            if k == index:
                data[pos + 9 + length // 2 : pos + 25 + length // 2] = bytes(16)
                break
            k += 1
        pos += 9 + length
    path.write_bytes(bytes(data))


@pytest.fixture
def damage_mcap_chunk() -> Callable[[Path, int], None]:
    """``damage_mcap_chunk(path, index)``: zero 16 bytes in the middle of chunk ``index`` of an MCAP file."""
    return _zero_mcap_chunk_middle
