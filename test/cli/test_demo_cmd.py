"""The main job, ``python -m gimbal_friction.demo``: the domain it runs on, and nothing left behind whatever signal
arrives at whichever step (the whole job's outputs: test/ros/test_pipeline.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gimbal_friction.cli import demo
from gimbal_friction.runs import supervisor


@pytest.fixture
def ran(monkeypatch):
    """The domains ``demo.main`` would run on (``run`` replaced; the domain probe sees nobody)."""
    seen: list[int] = []

    def fake_run(bag, out, rate, domain, sup):
        seen.append(domain)
        return 0

    monkeypatch.setattr(demo, 'run', fake_run)
    monkeypatch.setattr(supervisor, 'other_nodes', lambda domain, window_s: [])
    monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
    return seen


def test_the_main_job_runs_on_ros_domain_id_when_set(ran, monkeypatch, tmp_path):
    monkeypatch.setenv('ROS_DOMAIN_ID', '77')
    assert demo.main(['--out', str(tmp_path / 'a')]) == 0
    assert demo.main(['--out', str(tmp_path / 'b'), '--domain', '12']) == 0   # the option wins
    monkeypatch.delenv('ROS_DOMAIN_ID')
    assert demo.main(['--out', str(tmp_path / 'c')]) == 0                      # neither: a free one
    assert ran[:2] == [77, 12] and ran[2] in supervisor.DOMAINS


def test_a_bad_domain_is_refused_in_one_line(ran, monkeypatch, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        demo.main(['--out', str(tmp_path / 'a'), '--domain', '300'])
    assert exc.value.code == 2 and 'not a ROS domain id' in capsys.readouterr().err
    monkeypatch.setenv('ROS_DOMAIN_ID', 'x')
    assert demo.main(['--out', str(tmp_path / 'b')]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "demo: error: ROS_DOMAIN_ID='x' is not a domain id (0-232) (unset it or give --domain)"]
    assert ran == []


# ---------------------------------------------------------------------------------------------- signals
def _children_of(out: Path, window_s: float = 1.0) -> list[int]:
    """Processes started by the main job writing to ``out`` (their environment names its ROS log folder), looked
    for during ``window_s`` [s]: a child forked but not yet executed still has its parent's environment."""
    marker = f'ROS_LOG_DIR={out / "logs" / "ros"}'.encode()
    pids: set[int] = set()
    deadline = time.monotonic() + window_s
    while True:
        for entry in Path('/proc').iterdir():
            if entry.name.isdigit():
                try:
                    if marker in (entry / 'environ').read_bytes().split(b'\0'):
                        pids.add(int(entry.name))
                except OSError:
                    continue
        if time.monotonic() >= deadline:
            return sorted(pids)
        time.sleep(0.05)


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory):
    from gimbal_friction.cli.main import main
    bag = tmp_path_factory.mktemp('bag') / 'bag'
    assert main(['synth-bag', '--out', str(bag), '--plateaus=-40,20', '--hold-s', '20', '--joint-rate-hz', '25',
                 '--seed', '7', '--format', 'json']) == 0
    return bag


#: (the line of the main job's output after which the signal is sent, the signal): every step, every signal.
#: "[1/4]" is printed just before the nodes start: the signal lands while they are being started.
STEPS = [('[1/4]', signal.SIGINT), ('[1/4]', signal.SIGTERM), ('[1/4]', signal.SIGHUP),
         ('[2/4]', signal.SIGTERM), ('[3/4]', signal.SIGHUP), ('[4/4]', signal.SIGINT)]


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize(('step', 'sig'), STEPS, ids=[f'{s}-{signal.Signals(g).name}' for s, g in STEPS])
def test_a_signal_at_any_step_leaves_no_process_behind(short_bag, tmp_path, step, sig):
    """The main job as a user runs it, signalled right after it prints ``step``: it exits with 128 + the signal and
    no process it started is left (the old main job left friction_feedforward running for ever after a Ctrl-C
    during its start-up, and every node after a SIGTERM or SIGHUP)."""
    pytest.importorskip('rclpy')
    out = tmp_path / 'demo'
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', MPLBACKEND='Agg', PYTHONUNBUFFERED='1')
    env.pop('ROS_DOMAIN_ID', None)
    job = subprocess.Popen([sys.executable, '-m', 'gimbal_friction.demo', '--bag', str(short_bag), '--rate', '20',
                            '--out', str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           start_new_session=True)
    seen: list[bytes] = []
    try:
        assert job.stdout is not None
        for line in job.stdout:
            seen.append(line)
            if line.startswith(step.encode()):
                job.send_signal(sig)
                break
        rest, _ = job.communicate(timeout=120)
        seen.append(rest)
        assert any(s.startswith(step.encode()) for s in seen), b''.join(seen).decode(errors='replace')
        assert job.returncode == 128 + sig, b''.join(seen).decode(errors='replace')
        left = _children_of(out)
        assert left == [], f'processes left behind: {left}'
    finally:
        if job.poll() is None:
            job.kill()
            job.wait()
        for pid in _children_of(out, window_s=3.0):   # what the old main job left: end it, for the tests after
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
