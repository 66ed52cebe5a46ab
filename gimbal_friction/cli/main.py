"""``gimbal-friction``: the one command line of the suite (argparse layer).

Each subcommand module provides ``add_parser(subparsers)`` and ``run(args) -> int``; the logic lives in
:mod:`gimbal_friction.physics` and :mod:`gimbal_friction.recording`. Errors raised on purpose
(:class:`GimbalFrictionError`) and bad arguments end in one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn

from gimbal_friction.cli._common import os_error_text
from gimbal_friction.common.errors import GimbalFrictionError

#: subcommand -> module under gimbal_friction.cli
SUBCOMMANDS = {
    'model': 'model_cmd',
    'calibrate-kt': 'calibrate_kt_cmd',
    'synth-bag': 'synth_bag_cmd',
    'replay': 'replay_cmd',
    'report': 'report_cmd',
    'refit': 'refit_cmd',
    'export': 'export_cmd',
    'fleet': 'fleet_cmd',
    'recover': 'recover_cmd',
    'loop-study': 'loop_study_cmd',
}

#: options whose values may start with '-' (negative temperatures): '--temperature -40,0' is rewritten.
NEGATIVE_VALUE_OPTIONS = ('--temperature', '-t', '--plateaus', '--temperatures')


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line: ``gimbal-friction model: error: ...`` (exit code 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f'{self.prog}: error: {message} (see --help)\n')


def package_version() -> str:
    """The installed package's version (setup.py takes it from package.xml)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version('gimbal_friction')
    except PackageNotFoundError:  # run from a source tree that was never installed
        return 'unknown (gimbal_friction is not installed: pip install -e . or colcon build)'


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog='gimbal-friction', description='Gimbal-bearing friction torque vs temperature '
                           '(Yu & Shang 2017): model, calibration, bag replay and refit.')
    parser.add_argument('--version', action='version', version=f'gimbal-friction {package_version()}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', parser_class=OneLineParser)
    sub.required = True
    for module in SUBCOMMANDS.values():
        mod = importlib.import_module(f'gimbal_friction.cli.{module}')
        mod.add_parser(sub)
    return parser


def _rewrite_negative_values(argv: list[str]) -> list[str]:
    out: list[str] = []
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg in NEGATIVE_VALUE_OPTIONS and i + 1 < len(argv) and argv[i + 1].startswith('-') \
                and len(argv[i + 1]) > 1 and (argv[i + 1][1].isdigit() or argv[i + 1][1] == '.'):
            out.append(f'{arg}={argv[i + 1]}')
            i += 2
            continue
        out.append(arg)
        i += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 refused input or failure, 2 bad arguments)."""
    args_list = _rewrite_negative_values(list(sys.argv[1:] if argv is None else argv))
    parser = build_parser()
    args = parser.parse_args(args_list)
    try:
        # a name in a --config file that no node or tool reads is refused (it would be silently ignored)
        from gimbal_friction.config.loader import check_config_files
        check_config_files([*(getattr(args, 'config', None) or []), *filter(None, [getattr(args, 'compare', None)])])
        return int(args.func(args))
    except GimbalFrictionError as err:
        print(f'gimbal-friction {args.command}: error: {err}', file=sys.stderr)
        return 1
    except OSError as err:  # a full or read-only disk, a vanished file: one line, never a traceback
        print(f'gimbal-friction {args.command}: error: {os_error_text(err)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'gimbal-friction {args.command}: interrupted', file=sys.stderr)
        return 130


def entry() -> None:
    """console_scripts entry point."""
    sys.exit(main())


if __name__ == '__main__':
    entry()
