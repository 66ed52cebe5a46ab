"""The supervisor of the main job and ``loop-study --live``: every child it started ends, whatever signal arrives
when; a picked domain is one nobody else is on.

The children here are plain Python processes (``node_command`` replaced): what is tested is the supervisor's
bookkeeping and signal handling, not the nodes (test/cli/test_demo_cmd.py runs the real main job).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from gimbal_friction.runs import supervisor
from gimbal_friction.runs.supervisor import Interrupted, Supervisor, free_domain, requested_domain

SLEEPER = [sys.executable, '-c', 'import time; time.sleep(120)']
#: a child that ignores SIGINT and SIGTERM: only SIGKILL ends it
STUBBORN = [sys.executable, '-c', 'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); '
            'signal.signal(signal.SIGTERM, signal.SIG_IGN); print("ready", flush=True); time.sleep(120)']


@pytest.fixture
def children(monkeypatch, tmp_path):
    """Every process the supervisor starts (sleepers), recorded as Popen made them; all ended at the end."""
    made: list[subprocess.Popen[bytes]] = []
    real = subprocess.Popen

    def popen(*args, **kwargs):
        proc = real(*args, **kwargs)
        made.append(proc)
        return proc

    monkeypatch.setattr(supervisor, 'node_command', lambda name: list(SLEEPER))
    monkeypatch.setattr(subprocess, 'Popen', popen)
    yield made
    for proc in made:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_while_a_child_is_being_started_ends_every_child(children, monkeypatch, tmp_path, sig):
    """The moment the issue found: the signal arrives inside the start of a child, after the fork and before the
    child is recorded. The child is recorded all the same, every child is stopped, and the run ends with the
    signal's exit code (128 + signal)."""
    real = subprocess.Popen

    def signalled_popen(*args, **kwargs):
        proc = real(*args, **kwargs)
        children.append(proc)
        if len(children) == 2:
            os.kill(os.getpid(), sig)   # delivered here, before start_as has the child in its books
        return proc

    monkeypatch.setattr(subprocess, 'Popen', signalled_popen)
    with pytest.raises(Interrupted) as caught, Supervisor(dict(os.environ), tmp_path) as sup:
        for name in ('a', 'b', 'c'):
            sup.start(name, [])
    assert caught.value.signum == sig and caught.value.exit_code == 128 + sig
    assert len(children) == 2   # the third was never started
    assert all(p.poll() is not None for p in children), 'a child outlived the supervisor'
    assert signal.getsignal(sig) is not sup._on_signal   # the handlers are the caller's again


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_at_any_other_moment_ends_every_child(children, tmp_path, sig):
    with pytest.raises(Interrupted) as caught, Supervisor(dict(os.environ), tmp_path) as sup:
        sup.start('a', [])
        sup.start('b', [])
        os.kill(os.getpid(), sig)
        pytest.fail('the signal did not end the run')
    assert caught.value.exit_code == 128 + sig
    assert [p.poll() is not None for p in children] == [True, True]


def test_a_child_that_ignores_sigint_and_sigterm_is_killed(monkeypatch, tmp_path):
    monkeypatch.setattr(supervisor, 'node_command', lambda name: list(STUBBORN))
    monkeypatch.setattr(supervisor, 'SIGINT_GRACE_S', 0.3)
    monkeypatch.setattr(supervisor, 'SIGTERM_GRACE_S', 0.3)
    with Supervisor(dict(os.environ), tmp_path) as sup:
        proc = sup.start('stubborn', [])
        deadline = time.monotonic() + 30.0
        while b'ready' not in (tmp_path / 'stubborn.log').read_bytes():   # wait until its handlers are set
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.02)
    assert proc.returncode == -signal.SIGKILL


def test_a_child_that_ends_by_itself_is_named_unless_it_may(children, tmp_path):
    from gimbal_friction.common.errors import GimbalFrictionError

    with Supervisor(dict(os.environ), tmp_path, may_exit=lambda name: name == 'once') as sup:
        for name in ('once', 'node'):
            sup.start(name, []).kill()
        for proc in children:
            proc.wait()
        with pytest.raises(GimbalFrictionError, match='node exited early'):
            sup.check_alive()


def test_the_requested_domain_is_the_option_then_ros_domain_id():
    assert requested_domain(None, {}) is None
    assert requested_domain(None, {'ROS_DOMAIN_ID': ''}) is None
    assert requested_domain(None, {'ROS_DOMAIN_ID': '77'}) == 77
    assert requested_domain(5, {'ROS_DOMAIN_ID': '77'}) == 5
    with pytest.raises(ValueError, match='not a domain id'):
        requested_domain(None, {'ROS_DOMAIN_ID': 'seven'})


def test_a_domain_with_someone_on_it_is_not_picked(monkeypatch):
    """A domain another process uses without the coordinator (a node left behind, someone's ros2 run) is seen by
    the probe and skipped, and said so."""
    monkeypatch.setattr(supervisor, 'DOMAINS', range(40, 43))
    monkeypatch.setattr(supervisor.random, 'randrange', lambda n: 0)   # 40 first
    busy = {40: ['/friction_feedforward'], 41: ['<participant>']}
    said: list[str] = []
    with free_domain(log=said.append, probe=lambda d, _window: busy.get(d, [])) as did:
        assert did == 42
    assert sorted(said) == ['domain 40 is in use by /friction_feedforward; trying another',
                            'domain 41 is in use by <participant>; trying another']
    with pytest.raises(RuntimeError, match='no free ROS_DOMAIN_ID'), \
            free_domain(probe=lambda d, _window: ['/x']):
        pass


def test_a_picked_domain_is_reserved_until_the_block_ends(monkeypatch):
    """Two pickers at once never get the same domain (the coordinator's reservation), and an error in the block
    comes out as itself."""
    def quiet(_domain, _window):
        return []

    with free_domain(probe=quiet) as first, free_domain(probe=quiet) as second:
        assert first != second
    with pytest.raises(OSError, match='disk full'), free_domain(probe=quiet):
        raise OSError('disk full')


@pytest.mark.ros
@pytest.mark.slow
def test_the_probe_sees_a_node_left_running_on_a_domain(tmp_path):
    """The real probe: a node running on a domain nobody reserved (what an orphan of the old main job was) makes
    the domain busy."""
    pytest.importorskip('rclpy')
    with free_domain() as did:
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   ROS_LOG_DIR=str(tmp_path / 'roslog'))
        proc = subprocess.Popen(supervisor.node_command('friction_feedforward'), env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        assert supervisor.other_nodes(did, window_s=30.0) == ['/friction_feedforward']   # named once discovered
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(20)
