"""Do two checkouts' ``gimbal-friction replay`` write the same files? Byte for byte, on any bag.

Runs ``gimbal-friction replay BAG --out DIR --format json`` of this checkout and of another (``--before DIR``, the
code before a change: ``git worktree add /tmp/old COMMIT``), each in a child process with ``PYTHONPATH`` set to
its checkout, then compares ``summary.json`` and every file of ``residuals/`` (the MCAP log and its
``metadata.yaml``) byte for byte, and the JSON printed on stdout without its paths and timings. Exit 0 when all
are the same, 1 otherwise (the differing files named). A speed change must pass this on the bags it was measured
on (bench/REPLAY.md).

Run from the repository root:  ``.venv/bin/python bench/replay_equal.py --before DIR [--bag DIR ...]
[-- REPLAY OPTIONS]`` (default bag: ``bags/chamber_sample``; options after ``--`` go to both replays, e.g.
``-- --no-inputs``).
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BAG = ROOT / 'bags' / 'chamber_sample'
#: fields of the printed JSON that name the output folder or time the run
VARYING = ('residuals', 'summary', 'seconds', 'messages_per_s')


def replay(code: Path, bag: Path, out: Path, options: Sequence[str]) -> dict[str, Any]:
    """``gimbal-friction replay`` of the checkout ``code`` into ``out``: its JSON, without the varying fields."""
    env = {**os.environ, 'PYTHONPATH': str(code)}
    done = subprocess.run([sys.executable, '-m', 'gimbal_friction.cli.main', 'replay', str(bag), '--out', str(out),
                           '--format', 'json', *options], env=env, cwd=tempfile.gettempdir(), check=True,
                          capture_output=True, text=True)
    doc: dict[str, Any] = json.loads(done.stdout)
    return {k: v for k, v in doc.items() if k not in VARYING}


def differences(a: Path, b: Path) -> list[str]:
    """The files under ``a`` and ``b`` (relative paths) that differ or exist on one side only."""
    names = {p.relative_to(a) for p in a.rglob('*') if p.is_file()} | {p.relative_to(b) for p in b.rglob('*')
                                                                       if p.is_file()}
    return [str(n) for n in sorted(names)
            if not ((a / n).is_file() and (b / n).is_file() and filecmp.cmp(a / n, b / n, shallow=False))]


def main(argv: Sequence[str] | None = None) -> int:
    args_in = list(sys.argv[1:] if argv is None else argv)
    options: list[str] = []
    if '--' in args_in:
        k = args_in.index('--')
        args_in, options = args_in[:k], args_in[k + 1:]
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--before', type=Path, required=True, metavar='DIR', help='the other checkout')
    parser.add_argument('--bag', type=Path, action='append', help='bag to replay (repeatable; default: the sample)')
    args = parser.parse_args(args_in)
    if not (args.before / 'gimbal_friction' / '__init__.py').is_file():
        parser.error(f'--before {args.before}: no gimbal_friction package there')
    same = True
    for bag in args.bag or [SAMPLE_BAG]:
        with tempfile.TemporaryDirectory(prefix='replay-equal-') as tmp:
            new, old = Path(tmp) / 'this', Path(tmp) / 'before'
            doc_new = replay(ROOT, bag.resolve(), new, options)
            doc_old = replay(args.before.resolve(), bag.resolve(), old, options)
            diff = differences(new, old) + (['the printed JSON'] if doc_new != doc_old else [])
            files = sorted(str(p.relative_to(new)) for p in new.rglob('*') if p.is_file())
            print(f'{bag}: {"SAME" if not diff else "DIFFERENT"} ({", ".join(files)}, the printed JSON'
                  f'{"; differ: " + ", ".join(diff) if diff else ""})')
            same &= not diff
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
