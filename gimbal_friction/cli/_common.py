"""Helpers shared by the subcommands: temperature specs, configuration loading, JSON/CSV output."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import numpy as np

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.files import os_error_text, refuse_existing, write_bytes_atomic, write_text_atomic
from gimbal_friction.common.text import csv_text, format_table, json_finite
from gimbal_friction.config.loader import axis_names, axis_params, load_parameters
from gimbal_friction.physics.params import AxisParams

__all__ = ['add_common', 'add_common_noformat', 'csv_text', 'format_table', 'json_finite', 'load_axis', 'os_error_text',
           'parse_temperature_spec', 'print_json', 'print_read_note', 'progress', 'refuse_existing',
           'write_bytes_atomic', 'write_text_atomic']


def add_common_noformat(parser: argparse.ArgumentParser) -> None:
    """The repeatable ``--config`` option every subcommand has."""
    parser.add_argument('--config', action='append', default=[], metavar='PATH',
                        help='parameter file layered over the packaged defaults, key by key (repeatable)')


def add_common(parser: argparse.ArgumentParser) -> None:
    """``--config`` (repeatable) and ``--format table|json``."""
    add_common_noformat(parser)
    parser.add_argument('--format', choices=['table', 'json'], default='table',
                        help='output format; json prints one JSON document on stdout and nothing else')


def parse_temperature_spec(spec: str) -> np.ndarray:
    """``'-40,0,60'`` or ``'start:stop:step'`` (stop inclusive) to an array of temperatures [°C].

    >>> parse_temperature_spec('-40:60:20').tolist()
    [-40.0, -20.0, 0.0, 20.0, 40.0, 60.0]
    >>> parse_temperature_spec('-40, 25.5').tolist()
    [-40.0, 25.5]
    """
    text = spec.strip()
    try:
        if ':' in text:
            parts = [float(x) for x in text.split(':')]
            if len(parts) != 3:
                raise ValueError
            start, stop, step = parts
            if not all(math.isfinite(v) for v in parts) or step <= 0.0 or stop < start:
                raise ConfigError('--temperature', 'start:stop:step needs finite values, step > 0, stop >= start',
                                  spec)
            n = int(math.floor((stop - start) / step + 1e-9)) + 1
            if n > 100000:
                raise ConfigError('--temperature', 'more than 100000 temperatures', spec)
            return np.round(start + step * np.arange(n), 10)
        values = [float(x) for x in text.split(',') if x.strip()]
    except ValueError:
        raise ConfigError('--temperature', "expected '-40,0,60' or 'start:stop:step' in degC", spec) from None
    if not values or not all(math.isfinite(v) for v in values):
        raise ConfigError('--temperature', 'needs at least one finite temperature', spec)
    return np.asarray(values, dtype=float)


def load_axis(args: argparse.Namespace) -> tuple[str, AxisParams, dict[str, Any]]:
    """Merged configuration (packaged defaults + ``--config`` layers) and the validated params of ``--axis``."""
    cfg = load_parameters(args.config)
    names = axis_names(cfg)
    axis = getattr(args, 'axis', None) or names[0]
    return axis, axis_params(cfg, axis), cfg


def print_json(doc: Any) -> None:
    """One JSON document on stdout (non-finite numbers become null)."""
    print(json.dumps(json_finite(doc), indent=1))


def progress(done: int, total: int, label: str, *, stream: Any = None) -> None:
    """A one-line progress bar on stderr (only when it is a terminal or forced by passing ``stream``)."""
    out = stream if stream is not None else sys.stderr
    if stream is None and not out.isatty():
        return
    frac = done / total if total else 1.0
    bar = '#' * int(30 * frac)
    out.write(f'\r{label} [{bar:<30}] {100 * frac:5.1f}%')
    if done >= total:
        out.write('\n')
    out.flush()


def print_read_note(report: Any) -> None:
    """``note: residual logs: ...`` on stderr when a read of residual logs skipped data (a file cut short, damaged
    chunks, messages that are not rows): how much, from :meth:`ReadReport.summary`."""
    if report.skipped:
        print(f'note: residual logs: {report.summary()}', file=sys.stderr)
