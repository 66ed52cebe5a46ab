"""Refresh the ``--help`` blocks of docs/cli.md from the installed command line (COLUMNS=116).

    .venv/bin/python scripts/cli_reference.py        # rewrites docs/cli.md in place; test/test_docs.py checks it
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path

from gimbal_friction.cli.main import main

DOC = Path(__file__).resolve().parents[1] / 'docs' / 'cli.md'


def help_text(sub: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main([sub, '--help'])
    return out.getvalue().rstrip()


def refresh() -> int:
    os.environ['COLUMNS'] = '116'
    text = DOC.read_text(encoding='utf-8')
    count = 0

    def block(m: re.Match[str]) -> str:
        nonlocal count
        count += 1
        return f'```text\n{help_text(m.group(1))}\n```'

    DOC.write_text(re.sub(r'```text\nusage: gimbal-friction (\S+).*?\n```', block, text, flags=re.DOTALL),
                   encoding='utf-8')
    return count


if __name__ == '__main__':
    print(f'docs/cli.md: {refresh()} help blocks refreshed')
