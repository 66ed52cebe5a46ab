"""``gimbal-friction replay``: the three nodes' logic over a chamber-test bag, offline, in log-time order."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from gimbal_friction.cli._common import add_common, print_json, progress, refuse_existing, write_text_atomic
from gimbal_friction.common.errors import ConfigError
from gimbal_friction.recording.topics import CHAMBER_TOPICS

SUMMARY_FIELDS = ('temperature_c', 'direction', 'measured_mean_nmm', 'predicted_nmm', 'residual_nmm', 'samples')


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('replay', help='run the three nodes\' logic over a bag offline (same code, same numbers '
                            'as the live nodes)',
                            description='Replay a chamber-test bag (rosbag2 MCAP or sqlite3, or a bare .mcap) '
                            'through the feedforward, estimator and residual-logger logic in log-time order. '
                            'Writes OUT/residuals/ (the residual log) and OUT/summary.json (per temperature '
                            'plateau and direction). A bag in which no configured axis is found, or no friction '
                            'sample is accepted, is refused (exit 1, nothing written) with the joints it records '
                            'and the option that maps them.')
    parser.add_argument('bag', type=Path, metavar='BAG', help='chamber-test bag directory or .mcap file')
    parser.add_argument('--out', type=Path, required=True, metavar='DIR', help='output folder')
    add_common(parser)
    parser.add_argument('--topic', action='append', default=[], metavar='CONTRACT=BAG',
                        help='remap a contract topic to the name recorded in the bag, e.g. '
                        '/joint_states=/gimbal/joint_states (repeatable)')
    parser.add_argument('--joint', action='append', default=[], metavar='CONFIGURED=RECORDED',
                        help='the configured axis CONFIGURED is the joint recorded as RECORDED in the bag, e.g. '
                        'elevation=joint_2 (repeatable)')
    parser.add_argument('--correction', type=Path, metavar='FILE',
                        help='learned correction file (refit --correction-out) the feedforward adds, as the node '
                        'does; default: the correction_file of friction_feedforward in --config, if it exists. A '
                        'corrupt file or one learned against other parameters is refused (exit 1)')
    parser.add_argument('--no-inputs', action='store_true',
                        help='do not copy the input topics into the residual log (smaller, faster)')
    parser.set_defaults(func=run)


def parse_topic_options(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        if '=' not in item:
            raise ConfigError('--topic', "expected CONTRACT=BAG, e.g. /joint_states=/gimbal/joint_states", item)
        key, value = (x.strip() for x in item.split('=', 1))
        if key not in CHAMBER_TOPICS:
            raise ConfigError('--topic', f'{key} is not a chamber-test topic ({", ".join(CHAMBER_TOPICS)})', item)
        out[key] = value
    return out


def parse_joint_options(items: list[str]) -> dict[str, str]:
    """``['elevation=joint_2']`` -> ``{'joint_2': 'elevation'}`` (recorded name -> configured name).

    >>> parse_joint_options(['elevation=joint_2', 'azimuth = joint_1'])
    {'joint_2': 'elevation', 'joint_1': 'azimuth'}
    """
    out: dict[str, str] = {}
    for item in items:
        configured, sep, recorded = (x.strip() for x in item.partition('='))
        if not sep or not configured or not recorded:
            raise ConfigError('--joint', 'expected CONFIGURED=RECORDED, e.g. elevation=joint_2', item)
        if configured in out.values():
            raise ConfigError('--joint', f'axis {configured!r} is mapped twice', item)
        if recorded in out:
            raise ConfigError('--joint', f'recorded joint {recorded!r} is mapped twice', item)
        out[recorded] = configured
    return out


def run(args: argparse.Namespace) -> int:
    from gimbal_friction.chamber.replay import replay_bag
    from gimbal_friction.cli.report_cmd import summary_table
    topic_map = parse_topic_options(args.topic)
    joint_map = parse_joint_options(args.joint)
    out: Path = args.out
    refuse_existing(out / 'residuals', '--out', what='a log')  # the one rule of every command's outputs
    t0 = time.perf_counter()
    stages: dict[str, int] = {}

    def show(stage: str, frac: float) -> None:
        stages.setdefault(stage, len(stages))
        progress(int(frac * 1000), 1000, f'{stage:<22}')

    result = replay_bag(args.bag, out, config_paths=args.config, topic_map=topic_map or None,
                        joint_map=joint_map or None, log_inputs=not args.no_inputs, progress=show,
                        correction_path=args.correction)
    elapsed = time.perf_counter() - t0
    summary = [{k: r[k] for k in ('joint', *SUMMARY_FIELDS, 'sign', 'measured_std_nmm')} for r in result.summary]
    write_text_atomic(out / 'summary.json', json.dumps(summary, indent=1) + '\n')
    for line in result.findings:  # why a bag matched little or nothing, one line each
        print(f'note: {line}', file=sys.stderr)
    est = result.measurements
    info = {
        'bag': str(args.bag), 'residuals': str(result.residual_dir), 'summary': str(out / 'summary.json'),
        'messages_in': result.messages_in, 'messages_logged': result.messages_out,
        'feedforward_outputs': len(result.feedforward), 'accepted_samples': len(est),
        'rejected': result.estimator_counters.as_dict().get('rejected', {}), 'seconds': round(elapsed, 3),
        'messages_per_s': round(result.messages_in / elapsed, 1) if elapsed > 0 else None,
        'notes': result.findings, 'correction': result.correction,
    }
    if args.format == 'json':
        print_json({**info, 'plateaus': summary})
        return 0
    print(f'replayed {args.bag}: {result.messages_in} messages in {elapsed:.2f} s '
          f'({info["messages_per_s"]:.0f} msg/s); {len(est)} samples accepted')
    print(summary_table(result.summary))
    if result.correction is not None:
        print(f'feedforward with the learned correction {result.correction}')
    print(f'residual log: {result.residual_dir}/   summary: {out / "summary.json"}')
    return 0
