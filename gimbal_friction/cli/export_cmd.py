"""``gimbal-friction export``: the model as an interpolation table with a stated error bound, for a controller.

For every configured axis (or each ``--axis``) writes into ``--out DIR``:

- ``gimbal_friction_<axis>.csv``: ``#`` comment lines (generator, date, parameters, parameter-file hashes, error
  bound requested and achieved, lookup rule), a header row with units, one row per table node;
- ``gimbal_friction_<axis>.h``: a self-contained C99 header (``static const double`` arrays,
  ``gf_<axis>_friction_nm``, ``gf_<axis>_direction_factor``, ``gf_<axis>_feedforward_nm``; ``<math.h>`` only);
- ``gimbal_friction_<axis>.yaml``: a ROS 2 parameter file, ``friction_compensation: ros__parameters: <axis>: ...``.

The table and its check live in :mod:`gimbal_friction.export.table`; the model parameters and the feedforward
settings come from the packaged defaults layered with ``--config`` (as for the nodes: ``/**`` then
``friction_feedforward``), so a refit's parameter file in gives the refitted table out.

With ``--correction FILE`` (a learned correction, ``refit --correction-out``; learned against the same
configuration, else refused with one line) every file also carries the correction of its axis as the feedforward
looks it up without a joint position: its part along the motion and its part independent of the direction per
temperature bin and speed octave, with each cell's samples and error bound (its standard error), and the C
feedforward adds it as the node does, ``clamp(tanh(v/v_th) (k_dir M + odd) + even, ±τ_max)``
(:class:`~gimbal_friction.export.table.TableCorrection`). Its terms in the joint angle (a ripple, a trend) are not
exported; the files say so.

The files are written into a temporary directory next to ``DIR`` and renamed into place when all are complete, so a
failed run leaves nothing half-written. An existing non-empty ``DIR`` is refused unless ``--force``, and even then
only a directory holding nothing but export files (``gimbal_friction_*.csv|.h|.yaml``) is replaced.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import re
import sys
import time
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction import __version__
from gimbal_friction.cli._common import add_common, format_table, print_json
from gimbal_friction.common.errors import ConfigError, ConfigFileError, GimbalFrictionError
from gimbal_friction.common.files import os_error_text, staged
from gimbal_friction.common.settings import settings_from_parameters
from gimbal_friction.config.loader import all_axis_params, load_parameters, packaged_defaults_text
from gimbal_friction.export.formats import render_c_header, render_csv, render_ros_yaml
from gimbal_friction.export.table import (
    DEFAULT_MAX_SPEED_RAD_S,
    DEFAULT_RELATIVE_ERROR,
    ExportOptions,
    ExportTable,
    Provenance,
    TableCorrection,
    build_table,
    c_identifier,
    check_in_validity,
    table_correction,
)
from gimbal_friction.feedforward.correction import load_file, model_identity
from gimbal_friction.feedforward.rule import FeedforwardSettings, model_range
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.validity import VALID_T_MAX_C, VALID_T_MIN_C, ValidityRange, validity_range

#: files an export directory may hold (what --force may replace)
EXPORT_FILE = re.compile(r'gimbal_friction_[0-9A-Za-z_]+\.(csv|h|yaml)')
_DEFAULTS = ExportOptions()
#: the feedforward node's table range with the packaged defaults [°C]
_NODE_RANGE = model_range(FeedforwardSettings(), ValidityRange(VALID_T_MIN_C, VALID_T_MAX_C, ''))


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        'export', help='the model as an interpolation table with a stated error bound: CSV, C header, ROS YAML',
        description='Tabulate the friction model of each axis over temperature (and speed where it matters, '
        'nu*n >= 2000) so that linear interpolation stays within a relative error bound of the full model, checked '
        'at every grid midpoint and at seeded random points. Writes per axis a CSV, a C99 header (table, '
        'interpolation function and the feedforward rule of friction_feedforward) and a ROS 2 parameter file, each '
        'recording the parameters, the parameter-file hashes and the bound.')
    parser.add_argument('--out', type=Path, required=True, metavar='DIR',
                        help='directory to create (refused if it exists and is not empty, unless --force)')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing export directory at DIR (one holding only export files)')
    parser.add_argument('--axis', action='append', default=[], metavar='NAME',
                        help='configured axis to export (repeatable; default: every configured axis)')
    parser.add_argument('--relative-error', type=float, default=DEFAULT_RELATIVE_ERROR, metavar='X',
                        help='bound on |table - model|/model [-] (default %(default)g)')
    parser.add_argument('--max-speed-rad-s', type=float, default=DEFAULT_MAX_SPEED_RAD_S, metavar='X',
                        help='largest |velocity| the table covers [rad/s]; faster is clamped (default %(default)g = '
                        '573 deg/s, above the slew rates of seeker gimbals)')
    parser.add_argument('--temperature-min-c', type=float, default=None, metavar='X',
                        help="lowest table temperature [degC], within the model's validity range "
                        f"{VALID_T_MIN_C:g}..{VALID_T_MAX_C:g} degC (default: the feedforward node's table range, "
                        'temperature_min_c of friction_feedforward within the validity range: '
                        f'{_NODE_RANGE[0]:g})')
    parser.add_argument('--temperature-max-c', type=float, default=None, metavar='X',
                        help="highest table temperature [degC], within the validity range (default: the node's, "
                        f'{_NODE_RANGE[1]:g})')
    parser.add_argument('--random-points', type=int, default=_DEFAULTS.random_points, metavar='N',
                        help='seeded random points at which the table is checked against the model (default '
                        '%(default)d)')
    parser.add_argument('--seed', type=int, default=_DEFAULTS.seed, metavar='N',
                        help='seed of the random check points (default %(default)d)')
    parser.add_argument('--correction', type=Path, metavar='FILE',
                        help='learned correction file (refit --correction-out) to carry in every table (its speed '
                        'profile per temperature bin, split into the parts along and independent of the motion, with '
                        'error bounds; the C feedforward adds it; position terms are left out); refused if corrupt or '
                        'learned against other parameters')
    add_common(parser)
    parser.set_defaults(func=run)


# ---------------------------------------------------------------------------------------------- inputs
def _option_flag(name: str) -> str:
    return '--' + name.replace('_', '-')


def build_options(args: argparse.Namespace, settings: FeedforwardSettings,
                  params: Sequence[AxisParams] = ()) -> ExportOptions:
    """The :class:`ExportOptions` of the command line; the temperature range defaults to the feedforward node's
    table range for the axes ``params`` (its credible range within the model's validity range, :func:`~gimbal_friction.
    feedforward.rule.model_range`), and must lie within the validity range of each."""
    common = ValidityRange(max([VALID_T_MIN_C, *(validity_range(p).low_c for p in params)]),
                           min([VALID_T_MAX_C, *(validity_range(p).high_c for p in params)]), '')
    low, high = model_range(settings, common) if common.low_c < common.high_c else (common.low_c, common.high_c)
    options = ExportOptions(
        temperature_min_c=low if args.temperature_min_c is None else args.temperature_min_c,
        temperature_max_c=high if args.temperature_max_c is None else args.temperature_max_c,
        max_speed_rad_s=args.max_speed_rad_s, relative_error=args.relative_error,
        random_points=args.random_points, seed=args.seed)
    try:
        options.validate()
        for p in params:
            check_in_validity(p, options)
    except ConfigError as err:
        raise ConfigError(_option_flag(err.parameter), err.rule, err.value) from None
    return options


def select_axes(configured: list[str], wanted: list[str]) -> list[str]:
    """``wanted`` (order kept, duplicates dropped) or every configured axis; refuses unknown names and axes whose
    file names would collide."""
    names = list(dict.fromkeys(wanted)) or configured
    for name in names:
        if name not in configured:
            raise ConfigError('--axis', f'axis {name!r} is not configured (configured: {", ".join(configured)})')
    seen: dict[str, str] = {}
    for name in names:
        ident = c_identifier(name)
        if ident in seen:
            raise ConfigError('axes', f'joints {seen[ident]!r} and {name!r} give the same file and C name '
                              f'{ident!r}; export them separately with --axis')
        seen[ident] = name
    return names


def sources(config: list[Path]) -> tuple[tuple[str, str], ...]:
    """(label, SHA-256) of the packaged defaults and of every ``--config`` file, in layering order."""
    out = [('packaged defaults', hashlib.sha256(packaged_defaults_text().encode('utf-8')).hexdigest())]
    for path in config:
        try:
            out.append((str(path), hashlib.sha256(Path(path).read_bytes()).hexdigest()))
        except OSError as err:
            raise ConfigFileError(str(path), f'cannot read: {err.strerror}') from None
    return tuple(out)


# ---------------------------------------------------------------------------------------------- output
def _check_out(out: Path, force: bool) -> bool:
    """True when ``out`` exists and will be replaced. Raises when it must not be touched."""
    if not out.exists() and not out.is_symlink():
        return False
    if not out.is_dir() or out.is_symlink():
        raise GimbalFrictionError(f'{out}: exists and is not a directory; refusing to overwrite it')
    entries = list(out.iterdir())
    if not entries:
        return True
    if not force:
        raise GimbalFrictionError(f'{out}: directory exists and is not empty; nothing written (use --force to '
                                  'replace an earlier export)')
    foreign = [e.name for e in entries if not (e.is_file() and not e.is_symlink() and EXPORT_FILE.fullmatch(e.name))]
    if foreign:
        raise GimbalFrictionError(f'{out}: not an export directory (holds {foreign[0]!r}); refusing to delete it '
                                  'even with --force')
    return True


def write_export(out: Path, files: dict[str, str], replace: bool) -> None:
    """Write ``files`` (name -> text) as the directory ``out``, atomically (:func:`~gimbal_friction.common.files.
    staged`: a temporary sibling, then a rename)."""
    try:
        with staged(out, folder=True, replace=replace, what='export') as folder:
            for name, text in files.items():
                (folder / name).write_text(text, encoding='utf-8')
    except OSError as err:
        raise GimbalFrictionError(f'{out}: cannot write the export: {os_error_text(err)}') from None


def file_names(axis: str) -> dict[str, str]:
    """The three file names of ``axis``."""
    stem = f'gimbal_friction_{c_identifier(axis)}'
    return {'csv': f'{stem}.csv', 'c_header': f'{stem}.h', 'ros_parameters': f'{stem}.yaml'}


def _summary(out: Path, table: ExportTable) -> dict[str, Any]:
    o = table.options
    return {
        'axis': table.axis,
        'files': {kind: str(out / name) for kind, name in file_names(table.axis).items()},
        'temperature_range_c': [o.temperature_min_c, o.temperature_max_c],
        'validity_range_c': list(validity_range(table.params)[:2]),
        'max_speed_rad_s': o.max_speed_rad_s,
        'eta_breakpoints': [float(x) for x in table.grid.eta],
        'feedforward': {'velocity_threshold_rad_s': table.settings.velocity_threshold_rad_s,
                        'max_torque_nm': table.settings.max_torque_nm,
                        'scale_positive': table.params.scale_positive,
                        'scale_negative': table.params.scale_negative},
        'report': table.report.as_dict(),
        'correction': None if table.correction is None else _correction_summary(table.correction),
    }


def _correction_summary(c: TableCorrection) -> dict[str, Any]:
    """The JSON summary of an exported correction: source, samples, cells (with data, applied), the layout, the
    largest |odd|, |even| and |odd ± even| (along the motion, before the bound) [N*m], the position terms left out."""
    return {'source': c.source, 'samples': int(c.samples.sum()), 'cells': int((c.samples > 0).sum()),
            'cells_applied': int(c.applied.sum()), 'temperature_bins': int(c.centres_c.shape[0]),
            'speed_octaves': c.octaves, 'min_speed_rad_s': c.min_speed_rad_s,
            'max_abs_odd_nm': float(np.abs(c.odd_nm).max()), 'max_abs_even_nm': float(np.abs(c.even_nm).max()),
            'max_abs_nm': float((np.abs(c.odd_nm) + np.abs(c.even_nm)).max()),
            'left_out': {'ripple_periods_rad': list(c.ripple_periods_rad), 'ripple_max_relative': c.ripple_max_relative,
                         'trend_max_nm': c.trend_max_nm}}


def run(args: argparse.Namespace) -> int:
    config = [Path(p) for p in args.config]
    merged = load_parameters(config)
    axes = all_axis_params(merged)
    settings = settings_from_parameters(FeedforwardSettings,
                                        load_parameters(config, node_name='friction_feedforward'))
    names = select_axes(list(axes), args.axis)
    options = build_options(args, settings, [axes[n] for n in names])
    correction = None
    if args.correction is not None:   # refused (one line) before anything is built
        loaded = load_file(args.correction, expected=model_identity(axes), model=axes)
        correction = loaded.correction
        digest = hashlib.sha256(Path(args.correction).read_bytes()).hexdigest()
        correction_source = f'{args.correction} (SHA-256 {digest})' + (f'; {loaded.note}' if loaded.note else '')
    replace = _check_out(args.out, args.force)
    prov = Provenance(f'gimbal-friction export {__version__}',
                      datetime.now(timezone.utc).isoformat(timespec='seconds'), sources(config))
    show = sys.stderr.isatty()
    status = (lambda line: print(f'export: {line}', file=sys.stderr)) if show else None
    t0 = time.perf_counter()
    tables = [build_table(name, axes[name], settings, options, progress=status) for name in names]
    if correction is not None:
        tables = [t._replace(correction=table_correction(correction, t.axis, correction_source)) for t in tables]
    files: dict[str, str] = {}
    for table in tables:
        fn = file_names(table.axis)
        files[fn['csv']] = render_csv(table, prov)
        files[fn['c_header']] = render_c_header(table, prov)
        files[fn['ros_parameters']] = render_ros_yaml(table, prov)
    write_export(args.out, files, replace)
    elapsed = time.perf_counter() - t0
    doc = {
        'out': str(args.out), 'generator': prov.generator, 'created': prov.created,
        'sources': [{'file': label, 'sha256': digest} for label, digest in prov.sources],
        'options': dataclasses.asdict(options), 'elapsed_s': elapsed,
        'axes': [_summary(args.out, t) for t in tables],
    }
    if args.format == 'json':
        print_json(doc)
        return 0
    axes_txt = '1 axis' if len(tables) == 1 else f'{len(tables)} axes'
    print(f'wrote {args.out}: {axes_txt} x (CSV, C header, ROS parameters) in {elapsed:.1f} s; '
          f'relative error bound {options.relative_error:g} vs the full model, temperature '
          f'{options.temperature_min_c:g}..{options.temperature_max_c:g} degC, |v| <= {options.max_speed_rad_s:g} '
          'rad/s')
    rows = []
    for t in tables:
        r = t.report
        below = '-' if r.speed_matters_below_c is None else f'{r.speed_matters_below_c:.1f}'
        rows.append([t.axis, str(r.temperatures), str(r.upper_rows), f'{r.midpoint_max_relative_error:.2e}',
                     f'{r.random_max_relative_error:.2e}', f'{r.switch_band:.1e}', below])
    print(format_table(rows, ['axis', 'breakpoints', 'speed rows', 'max err (midpoints)', 'max err (random)',
                              'switch band', 'speed matters below [degC]']))
    for name in files:
        print(f'  {args.out / name}')
    return 0
