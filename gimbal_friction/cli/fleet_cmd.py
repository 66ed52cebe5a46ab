"""``gimbal-friction fleet``: many units' chamber tests at once; per-unit refits, the population, the outliers.

Each positional path is a unit (a residual-log folder or ``.mcap`` file, a ``replay``/``residual_logger`` output
folder holding ``residuals/``, or a chamber-test bag, which is replayed first) or a folder whose entries are
units. The work runs on Dask (:mod:`gimbal_friction.chamber.fleet`): an embedded local cluster by default
(``--workers``),
or the scheduler at ``--scheduler ADDRESS`` (its workers must see the same paths and have gimbal_friction
installed). Writes ``DIR/fleet.json`` (every unit's fit with intervals, the population's median and spread per
parameter, the outliers with their reason), ``DIR/fleet.csv`` (one row per unit and axis) and ``DIR/fleet.png``;
prints the table (or, with ``--format json``, the JSON document). Progress on stderr, one line per unit.
Exit 0 when at least one unit was refitted (units that could not be are listed with their error), else 1.
What a unit's read skipped (damaged chunks, lost messages, files cut short) is in its record (``units[].read``),
its progress line and a note under the table. An earlier run's files in ``--out`` are refused unless ``--force``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from gimbal_friction.chamber.fleet import (
    DEFAULT_FLEET_FIT,
    Z_MAX,
    FitSettings,
    FleetRun,
    discover_units,
    plot_fleet,
    progress_line,
    require_dask,
    run_fleet,
)
from gimbal_friction.cli._common import (
    add_common,
    csv_text,
    format_table,
    json_finite,
    print_json,
    refuse_existing,
    write_text_atomic,
)
from gimbal_friction.cli.refit_cmd import parse_fit
from gimbal_friction.common.errors import ConfigError, GimbalFrictionError
from gimbal_friction.config.loader import all_axis_params, load_parameters
from gimbal_friction.refit.fit import OFFSET_MODES

#: the files a fleet run writes into --out
OUT_FILES = ('fleet.json', 'fleet.csv', 'fleet.png')


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('fleet', help="many units' residual logs (or chamber bags) at once: per-unit refits, "
                            'population, outliers; runs on Dask',
                            description='Refit every unit (streaming its log into per-bin statistics) on a Dask '
                            'cluster, summarise the population (median and MAD-based spread per parameter) and flag '
                            'the units outside it with the reason; writes DIR/fleet.json, DIR/fleet.csv and '
                            'DIR/fleet.png.')
    parser.add_argument('paths', nargs='+', type=Path, metavar='LOG_DIR_OR_BAG',
                        help='a unit (residual log, replay output folder, chamber bag) or a folder of units')
    parser.add_argument('--out', type=Path, required=True, metavar='DIR', help='folder for fleet.json/.csv/.png')
    parser.add_argument('--force', action='store_true',
                        help='replace the fleet.json/.csv/.png of an earlier run in --out (refused otherwise)')
    add_common(parser)
    parser.add_argument('--scheduler', metavar='ADDRESS',
                        help='Dask scheduler address (e.g. tcp://10.0.0.5:8786); default: an embedded local cluster')
    parser.add_argument('--workers', type=int, metavar='N',
                        help='workers of the local cluster (default: CPU count, at most the number of units)')
    parser.add_argument('--threads', action='store_true',
                        help='local workers as threads in this process instead of processes (lighter, slower)')
    parser.add_argument('--memory-limit', default='auto', metavar='SIZE',
                        help="memory limit per local worker, e.g. 2GiB (default 'auto': the machine's shared)")
    parser.add_argument('--fit', default=','.join(DEFAULT_FLEET_FIT), metavar='NAMES',
                        help=f'parameters refitted per unit (default {",".join(DEFAULT_FLEET_FIT)}, as refit: the '
                        'lubricant, with the calibration offset beside it; the contact friction/preload as well: '
                        'walther_a,sliding_friction_coefficient with --offset off)')
    parser.add_argument('--offset', choices=OFFSET_MODES, default='auto',
                        help='calibration torque offset as a nuisance (see refit; default auto)')
    parser.add_argument('--calibration-se', type=float, metavar='N*M',
                        help="1-sigma uncertainty of the no-load torque T_0 [N*m], to judge each unit's offset")
    parser.add_argument('--bin-width', type=float, default=5.0, metavar='DEGC',
                        help='temperature bin width [degC] (default 5)')
    parser.add_argument('--correction-out', type=Path, metavar='DIR',
                        help='also write, per unit with a residual log, DIR/<unit>.refit.yaml (its refitted '
                        'parameters) and DIR/<unit>.correction.yaml (the correction learned against them, as refit '
                        '--correction-out); named in fleet.json units[].correction. Existing files are refused '
                        'unless --force')
    parser.add_argument('--z-max', type=float, default=Z_MAX, metavar='Z',
                        help=f'a unit is outside when |x - median| > Z robust spreads (default {Z_MAX:g})')
    parser.set_defaults(func=run)


def _fmt(x: Any, digits: int = 5) -> str:
    return '-' if x is None or (isinstance(x, float) and not math.isfinite(x)) else f'{x:.{digits}g}'


def table_rows(run: FleetRun) -> tuple[list[dict[str, Any]], list[str]]:
    """One row per unit and axis (a unit that failed: one row with its error)."""
    names = sorted({n for a in run.population['axes'].values() for n in a} - {'viscosity_m40_cst'})
    fields = ['unit', 'axis', 'kind', 'samples', *names, 'viscosity_m40_cst', 'm_total_m40_nmm', 'm_total_20_nmm',
              'rms_after_nmm', 'model_fits', 'outlier', 'reason', 'error']
    flags: dict[tuple[str, str], list[str]] = {}
    for o in run.population['outliers']:
        flags.setdefault((o['unit'], o['axis']), []).append(o['reason'])
    rows = []
    for rec in run.records:
        if rec['error'] or not rec['axes']:
            rows.append(dict.fromkeys(fields, '') | {'unit': rec['unit'], 'kind': rec['kind'], 'error': rec['error']})
            continue
        for axis, a in rec['axes'].items():
            row: dict[str, Any] = dict.fromkeys(fields, '') | {'unit': rec['unit'], 'axis': axis, 'kind': rec['kind']}
            if 'error' in a:
                row['error'] = a['error']
                rows.append(row)
                continue
            row['samples'] = a['samples']
            for n in names:
                if n == 'torque_offset_nmm':
                    row[n] = a['offset']['value_nmm'] if a['offset']['estimated'] else ''
                elif a['identifiable'].get(n):
                    row[n] = a['fitted'][n]
            row['viscosity_m40_cst'] = a['viscosity_m40_cst']
            row['m_total_m40_nmm'] = a['friction_nmm'].get('-40', '')
            row['m_total_20_nmm'] = a['friction_nmm'].get('20', '')
            row['rms_after_nmm'] = a['rms_after_nmm']
            check = a.get('fit_check') or {}
            row['model_fits'] = ('yes' if check.get('fits') else
                                 f'NO (max |z| {check.get("max_abs_z") or 0.0:.1f})') if check.get('checked') else ''
            reasons = flags.get((rec['unit'], axis), [])
            row['outlier'] = 'yes' if reasons else ''
            row['reason'] = '; '.join(reasons)
            rows.append(row)
    return rows, fields


def instead_hint(fit: tuple[str, ...], offset: str) -> str:
    """What to run instead when no unit could be refitted with ``fit`` (empty for the default fit: its refusals
    name their own reason).

    >>> print(instead_hint(('walther_a', 'sliding_friction_coefficient'), 'auto'))
    ; run the default fit (leave out --fit), or add --offset off to fit sliding_friction_coefficient without the \
calibration offset
    """
    if tuple(fit) == tuple(DEFAULT_FLEET_FIT):
        return ''
    hint = '; run the default fit (leave out --fit)'
    if 'sliding_friction_coefficient' in fit and offset != 'off':
        hint += ', or add --offset off to fit sliding_friction_coefficient without the calibration offset'
    return hint


def run(args: argparse.Namespace) -> int:
    require_dask()  # before any work: without Dask, one line that says how to install it
    out: Path = args.out
    if out.exists() and not out.is_dir():
        msg = f'--out {out} exists and is not a directory'
        raise GimbalFrictionError(msg)
    if args.workers is not None and args.workers < 1:
        raise ConfigError('--workers', 'must be >= 1', args.workers)
    if not (math.isfinite(args.bin_width) and args.bin_width > 0.0):
        raise ConfigError('--bin-width', 'must be > 0 [degC]', args.bin_width)
    if not (math.isfinite(args.z_max) and args.z_max > 0.0):
        raise ConfigError('--z-max', 'must be > 0', args.z_max)
    if args.calibration_se is not None and not (math.isfinite(args.calibration_se) and args.calibration_se >= 0.0):
        raise ConfigError('--calibration-se', 'must be a finite torque >= 0 [N*m]', args.calibration_se)
    for name in OUT_FILES:  # the one rule of every command's outputs
        refuse_existing(out / name, '--out', force=args.force)
    fit = parse_fit(args.fit)
    axes = all_axis_params(load_parameters(args.config))
    units = discover_units(list(args.paths))
    correction_dir: Path | None = args.correction_out
    if correction_dir is not None:
        from gimbal_friction.chamber.fleet import correction_paths
        from gimbal_friction.chamber.learned import correction_settings
        if correction_dir.exists() and not correction_dir.is_dir():
            msg = f'--correction-out {correction_dir} exists and is not a directory'
            raise GimbalFrictionError(msg)
        correction_settings(load_parameters(args.config, node_name='friction_feedforward'))   # refuse bad ones now
        for unit in units:
            for path in correction_paths(correction_dir, unit.name):
                refuse_existing(path, '--correction-out', force=args.force)
        correction_dir.mkdir(parents=True, exist_ok=True)
    settings = FitSettings(axes=axes, config_paths=tuple(str(Path(c).resolve()) for c in args.config), fit=fit,
                           offset=args.offset, bin_width_c=args.bin_width, calibration_se_nm=args.calibration_se,
                           correction_dir=None if correction_dir is None else str(correction_dir.resolve()))
    print(f'fleet: {len(units)} unit(s) on ' + (f'Dask scheduler {args.scheduler}' if args.scheduler else
                                                'an embedded local Dask cluster'), file=sys.stderr)
    result = run_fleet(units, settings, scheduler=args.scheduler, workers=args.workers, processes=not args.threads,
                       memory_limit=args.memory_limit, on_done=progress_line)
    if args.z_max != Z_MAX:
        from gimbal_friction.chamber.fleet import population
        result = result._replace(population=population(result.records, args.z_max))
    ok = [r for r in result.records if not r['error'] and any('error' not in a for a in r['axes'].values())]
    rows, fields = table_rows(result)
    doc = {'units': result.records, 'population': result.population, 'scheduler': result.scheduler,
           'workers': result.workers, 'seconds': result.seconds,
           'units_per_minute': 60.0 * len(units) / result.seconds if result.seconds > 0 else None,
           'fit': list(fit), 'offset_mode': args.offset, 'config': [str(c) for c in args.config]}
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / 'fleet.json', json.dumps(json_finite(doc), indent=1) + '\n')
    write_text_atomic(out / 'fleet.csv', csv_text(rows, fields))
    if ok:
        plot_fleet(result, out / 'fleet.png')
    if not ok:
        errors = '; '.join(f'{r["unit"]}: {r["error"] or next(iter(r["axes"].values()))["error"]}'
                           for r in result.records)
        msg = f'no unit could be refitted ({errors}){instead_hint(fit, args.offset)}'
        raise GimbalFrictionError(msg)
    if args.format == 'json':
        print_json(doc)
        return 0
    for r in result.records:  # what was skipped, per unit (also in fleet.json: units[].read)
        if (r.get('read') or {}).get('skipped'):
            print(f'note: unit {r["unit"]}: residual log: {r["read"]["summary"]}')
    shown = [f for f in fields if f not in ('reason', 'kind')]
    print(format_table([[_fmt(r[f]) if isinstance(r[f], float) else str(r[f]) for f in shown] for r in rows],
                       shown))
    misfit = sorted({r['unit'] for r in rows if str(r.get('model_fits', '')).startswith('NO')})
    if misfit:
        print(f'the model does NOT fit the bins of {len(misfit)} unit(s) ({", ".join(misfit)}): their intervals are '
              'not confidence intervals; refit one with gimbal-friction refit to see which bins and what to try')
    print()
    for axis, params in result.population['axes'].items():
        for name, st in params.items():
            print(f'population {axis} {name}: median {_fmt(st["median"], 6)}, spread (1.4826 MAD) '
                  f'{_fmt(st["spread"], 3)}, {st["n"]} unit(s)')
    print()
    if result.population['outliers']:
        for o in result.population['outliers']:
            print(f'OUTLIER {o["unit"]} ({o["axis"]}): {o["reason"]}')
    else:
        print('no unit outside the population')
    written = [r['correction'] for r in result.records if 'out' in (r.get('correction') or {})]
    if written:
        print(f'learned corrections: {len(written)} unit(s), '
              + ', '.join(f'{Path(c["out"]).name} ({c["samples"]} samples)' for c in written))
    print(f'{len(units)} unit(s) in {result.seconds:.1f} s ({doc["units_per_minute"]:.1f} units/min) on '
          f'{result.workers} worker(s); wrote {out / "fleet.json"}, {out / "fleet.csv"}'
          + (f', {out / "fleet.png"}' if ok else ''))
    return 0
