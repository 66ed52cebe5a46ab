"""Static checks in the test run: mypy (strict on core, recording and sim) and ruff report 0 errors.

Both are configured in pyproject.toml; they run on the installed sources as CI runs them.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN / cmd[0]), *cmd[1:]], cwd=ROOT, capture_output=True, text=True, check=False)


def test_mypy_reports_no_error():
    run = _run('mypy', '--no-error-summary', '--cache-dir', str(ROOT / '.mypy_cache'))
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]


def test_ruff_reports_no_error():
    run = _run('ruff', 'check', '--no-cache', '--output-format', 'concise', '.')
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
