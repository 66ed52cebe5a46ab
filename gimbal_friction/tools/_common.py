"""Helpers shared by the subcommands: temperature specs, configuration loading, JSON/CSV output."""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import sys
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.config import axis_names, axis_params, load_parameters
from gimbal_friction.core.errors import ConfigError, GimbalFrictionError
from gimbal_friction.core.params import AxisParams


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


def json_finite(obj: Any) -> Any:
    """``obj`` with every non-finite float (nested in mappings and sequences) replaced by None (JSON null)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: json_finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_finite(v) for v in obj]
    return obj


def csv_text(records: Iterable[Mapping[str, Any]], fields: list[str]) -> str:
    """CSV with a header row."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator='\n')
    writer.writeheader()
    for rec in records:
        writer.writerow({k: rec[k] for k in fields})
    return buf.getvalue()


def format_table(rows: list[list[str]], header: list[str]) -> str:
    """Right-aligned plain-text table."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    line = '  '.join(h.rjust(w) for h, w in zip(header, widths, strict=True))
    out = [line, '  '.join('-' * w for w in widths)]
    out += ['  '.join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return '\n'.join(out)


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


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: :func:`write_bytes_atomic`.

    Raises:
        GimbalFrictionError: ``path`` is a directory or cannot be written.
    """
    write_bytes_atomic(path, text.encode('utf-8'))


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename: an existing file is
    replaced whole or not at all, and a failed write (full disk, read-only) leaves no partial file behind.

    Raises:
        GimbalFrictionError: ``path`` is a directory or cannot be written.
    """
    if path.is_dir():
        msg = f'--out {path} is a directory; give a file name such as params.yaml'
        raise GimbalFrictionError(msg)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
        try:
            with os.fdopen(fd, 'wb') as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as err:
        msg = f'cannot write {path}: {os_error_text(err)}'
        raise GimbalFrictionError(msg) from None


def refuse_existing(path: Path, option: str = '--out', *, force: bool | None = None, what: str = 'files') -> None:
    """The one rule of every command's outputs: an existing file, or a folder that is not empty, is not
    overwritten. ``force`` None: the command has no ``--force`` (choose another path); False: refused, naming
    ``--force``; True: allowed.

    Raises:
        ConfigError: ``path`` exists (one line: the path, that nothing was written, the fix).
    """
    if force:
        return
    if path.is_dir():
        if not any(path.iterdir()):
            return
        held = f'already holds {what}'
    elif path.exists() or path.is_symlink():
        held = 'already exists'
    else:
        return
    fix = f'choose another {option}' + ('' if force is None else ', or pass --force to replace it')
    raise ConfigError(option, f'{path} {held}; nothing written ({fix})')


def print_read_note(report: Any) -> None:
    """``note: residual logs: ...`` on stderr when a read of residual logs skipped data (a file cut short, damaged
    chunks, messages that are not rows): how much, from :meth:`ReadReport.summary`."""
    if report.skipped:
        print(f'note: residual logs: {report.summary()}', file=sys.stderr)


def os_error_text(err: OSError) -> str:
    """An OSError as one line: the reason and the file it names (``Read-only file system: 'out/fig.png'``).

    >>> import errno
    >>> os_error_text(OSError(errno.EROFS, 'Read-only file system', 'out/fig.png'))
    "Read-only file system: 'out/fig.png'"
    """
    reason = err.strerror or ' '.join(str(err).split()) or type(err).__name__
    return f'{reason}: {err.filename!r}' if err.filename else reason
