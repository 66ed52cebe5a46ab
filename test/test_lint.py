"""Static checks in the test run: mypy (strict over the whole package and bench/) and ruff (all rules but the
exclusions listed with their reasons) report 0 errors.

Both are configured in pyproject.toml; they run on the installed sources as CI runs them. mypy takes 15-60 s on a
loaded 2-core machine: it is in the full suite (``slow``), not in the fast lane ``pytest -m "not slow"``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN / cmd[0]), *cmd[1:]], cwd=ROOT, capture_output=True, text=True, check=False)


@pytest.mark.slow
def test_mypy_reports_no_error():
    run = _run('mypy', '--no-error-summary', '--cache-dir', str(ROOT / '.mypy_cache'))
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]


def test_ruff_reports_no_error():
    run = _run('ruff', 'check', '--no-cache', '--output-format', 'concise', '.')
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
