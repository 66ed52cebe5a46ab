"""Starting and stopping the suite's nodes as processes: the supervisor shared by the main job and the live loop study.

:class:`Supervisor` starts node executables of this environment and always stops them (SIGINT, then SIGTERM, then
SIGKILL), whatever ends the run: a normal end, an error, or SIGINT / SIGTERM / SIGHUP at any moment, start-up
included (used as a context manager, it installs its signal handlers before the first child starts and raises
:class:`Interrupted` where the run is; a signal that arrives while a child is being started or the children are
being stopped is held until that is done, so no child is ever started unrecorded). :func:`free_domain` picks a
ROS_DOMAIN_ID that no other process of this machine reserved and on which no other node is seen;
:class:`Watcher` is a probe node in the calling process that waits for the graph to connect and counts
measurements.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from importlib import resources
from pathlib import Path
from types import FrameType, TracebackType
from typing import IO, Any, Self

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.recording import topics
from gimbal_friction.runs.live_counts import Reports

#: the nodes of the main job, in start order
NODES = ('friction_feedforward', 'friction_estimator', 'residual_logger')
#: the signals that end a supervised run (its children stopped first)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: [s] how long a stopped child gets after SIGINT, then after SIGTERM, before SIGKILL
SIGINT_GRACE_S = 15.0
SIGTERM_GRACE_S = 5.0


def node_command(name: str) -> list[str]:
    """The command that starts node executable ``name`` of this environment."""
    path = Path(sys.executable).parent / name
    return [str(path)] if path.exists() else [sys.executable, '-m', f'gimbal_friction.nodes.{name}']


@contextlib.contextmanager
def packaged_params_file() -> Iterator[Path]:
    with resources.as_file(resources.files('gimbal_friction').joinpath('data', 'gimbal_friction.yaml')) as p:
        yield p


class ChildExitedError(GimbalFrictionError, RuntimeError):
    """A supervised node ended by itself (or a run of one failed): the message names it and its last output."""


class Interrupted(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM or SIGHUP) ended the run; :attr:`exit_code` is the shell's 128 + signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


class Supervisor:
    """Starts node processes and always stops them (SIGINT, then SIGTERM, then SIGKILL).

    Use it as a context manager: on entry SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (in the main
    thread; elsewhere signals are left as they are), on exit every child still running is stopped and the previous
    handlers come back. A signal that arrives during :meth:`start` is raised once the child is recorded; one that
    arrives while stopping shortens the grace periods (a second Ctrl-C hurries the stop, it never abandons it).
    A child whose name ``may_exit(name)`` accepts (``chamber_replay``, a ``gimbal_sim`` run) may end by itself;
    any other that ends is an error for :meth:`check_alive`.
    """

    def __init__(self, env: dict[str, str], log_dir: Path, *,
                 may_exit: Callable[[str], bool] = lambda name: name == 'chamber_replay') -> None:
        self.env = env
        self.log_dir = log_dir
        self.may_exit = may_exit
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._logs: dict[str, IO[bytes]] = {}
        self._held = 0                     # > 0: inside start/stop, signals are held
        self._pending: list[int] = []      # signals received while held
        self._hurry = False
        self._previous: dict[int, Any] = {}
        #: the first stop signal received (None: none), also when a command run in-process caught the
        #: :class:`Interrupted` it raised
        self.signalled: int | None = None

    # -------------------------------------------------------------------------------------------- signals
    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                self._previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.stop_all(raise_pending=exc is None)
        finally:
            for sig, handler in self._previous.items():
                signal.signal(sig, signal.SIG_DFL if handler is None else handler)
            self._previous.clear()

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        if self.signalled is None:
            self.signalled = signum
        if self._held:
            self._pending.append(signum)
            self._hurry = True
            return
        raise Interrupted(signum)

    @contextlib.contextmanager
    def _holding_signals(self) -> Iterator[None]:
        self._held += 1
        try:
            yield
        finally:
            self._held -= 1

    def _raise_pending(self) -> None:
        if self._pending and not self._held:
            signum = self._pending[0]
            self._pending.clear()
            raise Interrupted(signum)

    # -------------------------------------------------------------------------------------------- children
    def start(self, name: str, args: Sequence[str]) -> subprocess.Popen[bytes]:
        """Start node executable ``name`` as child ``name``."""
        return self.start_as(name, name, args)

    def start_as(self, name: str, exe: str, args: Sequence[str]) -> subprocess.Popen[bytes]:
        """Start node executable ``exe`` as child ``name`` (its output in ``<log_dir>/<name>.log``), in its own
        session (a terminal's Ctrl-C reaches the supervisor, which stops it)."""
        with self._holding_signals():
            log = open(self.log_dir / f'{name}.log', 'wb')  # noqa: SIM115 - closed when the child is stopped
            try:
                proc = subprocess.Popen(node_command(exe) + list(args), env=self.env, stdout=log,
                                        stderr=subprocess.STDOUT, start_new_session=True)
            except BaseException:
                log.close()
                raise
            self.procs[name] = proc
            self._logs[name] = log
        self._raise_pending()
        return proc

    def check_alive(self) -> None:
        for name, proc in self.procs.items():
            if proc.poll() is not None and not self.may_exit(name):
                tail = (self.log_dir / f'{name}.log').read_text(errors='replace').strip().splitlines()[-3:]
                msg = f'{name} exited early (code {proc.returncode}): ' + ' | '.join(tail)
                raise ChildExitedError(msg)

    def stop(self, name: str) -> int | None:
        """Stop child ``name`` (SIGINT, then SIGTERM, then SIGKILL) and forget it; its exit code."""
        with self._holding_signals():
            code = self._stop({name: self.procs[name]})[name]
            self.procs.pop(name)
            self._logs.pop(name).close()
        self._raise_pending()
        return code

    def stop_all(self, *, raise_pending: bool = True) -> dict[str, int | None]:
        """Stop every child at once (SIGINT, then SIGTERM, then SIGKILL); their exit codes (the children stay
        listed until the supervisor is left)."""
        with self._holding_signals():
            codes = self._stop(dict(self.procs))
            for log in self._logs.values():
                log.close()
        if raise_pending:
            self._raise_pending()
        return codes

    def _stop(self, procs: dict[str, subprocess.Popen[bytes]]) -> dict[str, int | None]:
        for sig, grace_s in ((signal.SIGINT, SIGINT_GRACE_S), (signal.SIGTERM, SIGTERM_GRACE_S),
                             (signal.SIGKILL, None)):
            running = [p for p in procs.values() if p.poll() is None]
            for proc in running:
                _signal_group(proc, sig)
            deadline = time.monotonic() + (grace_s if grace_s is not None else 60.0)
            self._hurry = False
            while any(p.poll() is None for p in running) and time.monotonic() < deadline:
                if self._hurry and grace_s is not None:   # another signal: the next step now
                    break
                with contextlib.suppress(subprocess.TimeoutExpired):
                    next(p for p in running if p.poll() is None).wait(0.05)
        return {name: proc.returncode for name, proc in procs.items()}


def _signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    """Send ``sig`` to the child's process group (its session: whatever it started too)."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass
    except PermissionError:
        proc.send_signal(sig)


# ---------------------------------------------------------------------------------------------- domains
#: [s] how long a candidate domain is watched for another node before it is taken (an established node on loopback
#: is seen within about 0.1 s on an idle machine; the bound leaves room for a busy one)
DOMAIN_PROBE_S = 1.0
#: the ROS_DOMAIN_IDs a run picks from (the domain coordinator's range)
DOMAINS = range(1, 101)
#: the domain coordinator's reservation: domain d holds TCP port PORT_BASE + d on this machine
_PORT_BASE = 32768


def requested_domain(option: int | None, environ: dict[str, str] | os._Environ[str] = os.environ) -> int | None:
    """The domain the user asked for: ``option`` (``--domain``), else ``ROS_DOMAIN_ID`` if set and not empty, else
    None (pick a free one). Raises ValueError for a ROS_DOMAIN_ID that is not a domain id (0-232)."""
    if option is not None:
        return option
    text = environ.get('ROS_DOMAIN_ID', '').strip()
    if not text:
        return None
    if not text.isdigit() or not 0 <= int(text) <= 232:
        msg = f'ROS_DOMAIN_ID={text!r} is not a domain id (0-232)'
        raise ValueError(msg)
    return int(text)


def other_nodes(domain: int, window_s: float = DOMAIN_PROBE_S) -> list[str]:
    """The nodes (and node-less ROS participants, as ``<participant>``) of other processes seen on ``domain``
    within ``window_s`` [s]: returns as soon as a node is seen, else after the window (empty: the domain is
    quiet)."""
    import rclpy
    from rclpy.node import Node

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        node = Node(f'gimbal_friction_domain_probe_{os.getpid()}', context=context, enable_rosout=False,
                    start_parameter_services=False)
        try:
            deadline = time.monotonic() + window_s
            while True:
                names = [ns.rstrip('/') + '/' + n for n, ns in node.get_node_names_and_namespaces()
                         if n != node.get_name()]
                # every ROS participant publishes ros_discovery_info: more than ours is another process's
                participants = len(node.get_publishers_info_by_topic('ros_discovery_info', no_mangle=True))
                # a participant is seen before its nodes: give their names the rest of the window
                if names or time.monotonic() >= deadline:
                    return names or (['<participant>'] if participants > 1 else [])
                time.sleep(0.02)
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()


def _reserve(domain: int) -> socket.socket | None:
    """The domain coordinator's reservation of ``domain`` (its port bound), or None if another process holds it."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind(('', _PORT_BASE + domain))
    except OSError:
        sock.close()
        return None
    return sock


@contextlib.contextmanager
def free_domain(window_s: float = DOMAIN_PROBE_S, log: Callable[[str], None] = lambda text: None,
                probe: Callable[[int, float], list[str]] | None = None) -> Iterator[int]:
    """A ROS_DOMAIN_ID reserved for the ``with`` block: one that no other process reserved through the domain
    coordinator (ros-domain-coordinator's port convention, so it and this share the machine) and on which
    ``probe`` (default :func:`other_nodes`) sees no other node within ``window_s`` [s] (a process that does not
    use the coordinator: someone's ``ros2 run``, a node left behind). A busy domain is named through ``log`` and
    another is tried.

    Not the coordinator's own context manager: it swallows an OSError raised in its ``with`` block and then
    fails with "generator didn't stop"; the reservation is the same port.

    Raises:
        RuntimeError: every domain is reserved or busy.
    """
    start = random.randrange(len(DOMAINS))  # noqa: S311 - spreads concurrent pickers, not a secret
    for k in range(len(DOMAINS)):
        domain = DOMAINS[(start + k) % len(DOMAINS)]
        sock = _reserve(domain)
        if sock is None:
            continue
        try:
            others = (probe or other_nodes)(domain, window_s)
            if others:
                log(f'domain {domain} is in use by {", ".join(others[:3])}; trying another')
                continue
            yield domain
            return
        finally:
            sock.close()
    msg = f'no free ROS_DOMAIN_ID in {DOMAINS.start}-{DOMAINS.stop - 1} (each reserved or with nodes on it)'
    raise RuntimeError(msg)


# ---------------------------------------------------------------------------------------------- watcher
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
