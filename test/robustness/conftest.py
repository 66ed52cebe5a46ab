"""Fixtures for the robustness tests: bags and logs to damage, a full and a read-only file system, the CLI.

A full or read-only file system is a small tmpfs mounted for the test when mounting is allowed (root, as on this
machine and in CI). Where it is not, a full disk is simulated with a file-size limit (``RLIMIT_FSIZE``: writes past
it fail with EFBIG, the process ignores SIGXFSZ) in the CLI's own process, and a read-only folder with a path under
a regular file (creating it fails with ENOTDIR): either way the tool meets an OSError while writing, which is what
these tests are about.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import traceback
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import pytest

from gimbal_friction.recording.bag_write import write_chamber_bag
from gimbal_friction.recording.cdr import make_joint_state, make_temperature
from gimbal_friction.recording.topics import (
    JOINT_STATE_TYPE,
    JOINT_STATES,
    MOTOR_CURRENT,
    TEMPERATURE,
    TEMPERATURE_TYPE,
)

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / 'bags' / 'chamber_sample'
T0 = 1_700_000_000_000_000_000  # [ns]


class Run(NamedTuple):
    code: int
    out: str
    err: str


def run_cli(*args: str, preexec: Callable[[], None] | None = None, timeout: float = 120.0) -> Run:
    """``gimbal-friction ARGS``: in this process (fast), or with ``preexec`` in its own (a file-size limit stays
    there). Any exception escaping ``main`` is a failure of the tool, shown as the traceback it would print."""
    if preexec is not None:
        proc = subprocess.run([sys.executable, '-m', 'gimbal_friction.cli.main', *args], capture_output=True,
                              text=True, timeout=timeout, preexec_fn=preexec, check=False)
        return Run(proc.returncode, proc.stdout, proc.stderr)
    from gimbal_friction.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as done:  # argparse: bad arguments
            code = done.code if isinstance(done.code, int) else 1
        except Exception:
            traceback.print_exc()
            code = 1
    return Run(code, out.getvalue(), err.getvalue())


def one_line_error(run: Run, command: str) -> str:
    """Check the run failed with exactly one line on stderr naming the command; return that line."""
    assert run.code != 0, run
    lines = run.err.strip().splitlines()
    assert len(lines) == 1, run.err
    assert lines[0].startswith(f'gimbal-friction {command}: error: '), lines[0]
    assert 'Traceback' not in run.err
    return lines[0]


def chamber_messages(n: int = 300, joint: str = 'elevation') -> list[tuple[str, str, int, object]]:
    """A small chamber run: joint states at 250 Hz, currents at 125 Hz, temperatures at 25 Hz, at the commanded
    speed (0.6 s each way, inside the position window), so the estimator accepts samples (a replay that accepts
    none is refused)."""
    msgs: list[tuple[str, str, int, object]] = []
    for i in range(n):
        t = T0 + i * 4_000_000
        v = math.radians(2.0) * (1 if (i // 150) % 2 == 0 else -1)
        msgs.append((JOINT_STATES, JOINT_STATE_TYPE, t, make_joint_state(t, [joint], [0.0005 * i], [v])))
        if i % 2 == 0:
            msgs.append((MOTOR_CURRENT, JOINT_STATE_TYPE, t + 1, make_joint_state(t, [joint], effort=[0.2])))
        if i % 10 == 0:
            msgs.append((TEMPERATURE, TEMPERATURE_TYPE, t + 2, make_temperature(t, 20.0)))
    return msgs


@pytest.fixture
def small_bag(tmp_path: Path) -> Path:
    return write_chamber_bag(tmp_path / 'bag', chamber_messages())


class Mount:
    """A tmpfs mounted for one test (None when mounting is not allowed here)."""

    @staticmethod
    @contextlib.contextmanager
    def tmpfs(where: Path, size: str, *, read_only: bool = False) -> Iterator[Path | None]:
        where.mkdir(parents=True, exist_ok=True)
        options = f'size={size},mode=0777' + (',ro' if read_only else '')
        mount = shutil.which('mount')
        if mount is None or os.geteuid() != 0 or os.environ.get('GF_TEST_NO_MOUNT'):  # the env: try the fallback
            yield None
            return
        done = subprocess.run([mount, '-t', 'tmpfs', '-o', options, f'gf-{uuid.uuid4().hex[:8]}', str(where)],
                              capture_output=True, check=False)
        if done.returncode != 0:
            yield None
            return
        try:
            yield where
        finally:
            subprocess.run([shutil.which('umount') or 'umount', '-l', str(where)], capture_output=True, check=False)


class FullDisk(NamedTuple):
    """Where to write so that the disk fills up, and how to start the process that writes."""

    folder: Path
    preexec: Callable[[], None] | None
    kind: str
    """``'tmpfs'`` or ``'rlimit'``."""


def _limit_file_size(limit: int) -> Callable[[], None]:
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG, no signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Callable[[int], FullDisk]]:
    """``full_disk(bytes)``: a folder on a file system of about that size (tmpfs), or a file-size limit."""
    with contextlib.ExitStack() as stack:

        def make(size: int) -> FullDisk:
            where = tmp_path / f'fs{uuid.uuid4().hex[:6]}'
            mounted = stack.enter_context(Mount.tmpfs(where, f'{max(size // 1024, 16)}k'))
            if mounted is not None:
                return FullDisk(mounted, None, 'tmpfs')
            return FullDisk(where, _limit_file_size(size), 'rlimit')

        yield make


@pytest.fixture
def read_only_dir(tmp_path: Path) -> Iterator[Path]:
    """A folder that cannot be written: a read-only tmpfs, else a path under a regular file."""
    with Mount.tmpfs(tmp_path / 'ro', '64k', read_only=True) as mounted:
        if mounted is not None:
            yield mounted
            return
        blocker = tmp_path / 'a_file'
        blocker.write_text('not a folder')
        yield blocker


class Helpers:
    """What the robustness tests share (a fixture, since a conftest is not importable by name)."""

    ROOT = ROOT
    SAMPLE = SAMPLE
    run = staticmethod(run_cli)
    refused = staticmethod(one_line_error)
    chamber = staticmethod(chamber_messages)


@pytest.fixture
def rb() -> type[Helpers]:
    return Helpers


# -- real ROS nodes (marked ``ros``): ros_env, spawn, probe are in test/conftest.py (shared with test/ros) ---------
# the in-process node fixture of the node and parameter tests: robustness/nodes_harness.py
from robustness.nodes_harness import in_process  # noqa: E402, F401
