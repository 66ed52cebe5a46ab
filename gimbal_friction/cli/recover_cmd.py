"""``gimbal-friction recover``: rewrite a bag or residual log that is cut short or damaged into a readable one."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from gimbal_friction.cli._common import add_common, print_json, progress


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        'recover', help='rewrite a truncated or damaged bag / residual log into a readable one, keeping every '
        'readable record',
        description='Read IN (a rosbag2 bag folder, a .mcap or .db3 bag file, or a residual-log folder or file) '
        'record by record, skipping what is damaged, and write every readable message into OUT, of the same '
        'kind: complete MCAP files (or a sqlite3 database) and, for a folder, a rosbag2 metadata.yaml, so '
        'ros2 bag, rosbags, the mcap readers, Foxglove, replay and refit open it. Prints how many messages were '
        'kept and lost. IN is only read; OUT must not exist. A bag whose messages are not CDR (JSON, protobuf, '
        'ROS 1, an MCAP profile other than ros2) is refused as not supported: it is not damaged.')
    parser.add_argument('source', type=Path, metavar='IN', help='bag folder, .mcap / .db3 file, or residual log')
    parser.add_argument('--out', type=Path, required=True, metavar='OUT', help='what to create (must not exist)')
    add_common(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gimbal_friction.recording.recover import recover

    def show(done: int, total: int, name: str) -> None:
        progress(done, total, f'recovering {name:<24.24}')

    result = recover(args.source, args.out, progress=show)
    files = [{'source': str(f.source), 'target': str(f.target), 'storage': f.storage, 'kept': f.messages,
              'lost': f.lost, 'lost_unknown': f.unknown_loss, 'cut_short': f.truncated, 'damaged': f.damaged,
              'problems': list(f.problems)} for f in result.files]
    if args.format == 'json':
        print_json({'source': str(result.source), 'target': str(result.target), 'kind': result.kind,
                    'kept': result.messages, 'lost': result.lost, 'lost_unknown': result.unknown_loss,
                    'files': files, 'skipped': list(result.skipped)})
        return 0
    print(f'recovered {result.source} -> {result.target}: kept {result.messages} messages, '
          f'lost {result.lost_text()}')
    for f in result.files:
        state = 'cut short' if f.truncated else 'complete'
        print(f'  {f.target.name if f.target else "?"}: kept {f.messages}, lost {f.lost_text()} ({state}'
              f'{f", {f.damaged} damaged parts skipped" if f.damaged else ""})')
        for line in f.problems:
            print(f'    {line}')
    for line in result.skipped:
        print(f'  skipped: {line}')
    return 0
