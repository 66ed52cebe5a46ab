"""``gimbal-friction report``: the paper's figures from the model (Figs. 5, 7–11) as PNG files."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any, cast

from gimbal_friction.cli._common import (
    add_common,
    format_table,
    load_axis,
    os_error_text,
    print_json,
    print_read_note,
    refuse_existing,
)
from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.common.units import nmm_from_nm
from gimbal_friction.config.loader import load_parameters
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.refit.records import read_refit_offsets, read_refit_validity, validity_text


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('report', help='figures and tables: model components vs temperature (Fig. 11), '
                            'model vs measured by direction (Fig. 13)',
                            description='Draw the paper figures from the model into --out: free contact angle '
                            '(Fig. 5), axial force (Figs. 7-8), M_S+M_R (Figs. 9-10) and the components M_L, '
                            'M_S+M_R, M (Fig. 11).')
    add_common(parser)
    parser.add_argument('--axis', metavar='NAME', help='configured axis (default: the first in axes)')
    parser.add_argument('--out', type=Path, default=Path('report'), metavar='DIR',
                        help='output folder for the PNG files (default: ./report)')
    parser.add_argument('--residuals', nargs='+', type=Path, metavar='LOG_DIR',
                        help='residual logs (residual_logger or replay): adds Fig. 13, model vs measured by '
                        'direction, and its table')
    parser.add_argument('--compare', type=Path, metavar='FILE.yaml',
                        help='a parameter file (e.g. from refit) layered over --config: drawn as a second model '
                        'curve in Fig. 13 and tabulated as the refit model, with the torque offset refit wrote into '
                        "it (as in refit's own table)")
    parser.add_argument('--force', action='store_true',
                        help='replace figures of an earlier report in --out (refused otherwise)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except OSError as err:  # the figures' folder cannot be created or written (read-only, full, not a folder)
        raise GimbalFrictionError(f'cannot write the report into {args.out}: {os_error_text(err)}') from None


def _run(args: argparse.Namespace) -> int:
    from gimbal_friction.plots.figures import FIG13_FILE, MODEL_FIGURE_FILES, model_figures, plot_model_vs_measured
    axis, params, _ = load_axis(args)
    if args.compare is not None:  # refuse a bad --compare file (or refit section) before drawing anything
        load_parameters([*args.config, args.compare])
        read_refit_offsets(args.compare)
    names = [*MODEL_FIGURE_FILES, *([FIG13_FILE] if args.residuals else [])]
    for name in names:  # one rule for every command's outputs: nothing existing is overwritten without --force
        refuse_existing(args.out / name, '--out', force=args.force)
    summary = None
    read: dict[str, Any] = {}
    offsets: dict[str, float] = {}
    validity = read_refit_validity(args.compare).get(axis, {}) if args.compare is not None else {}
    good_for = validity_text(validity)
    if args.residuals:  # read (and refuse empty logs) before drawing anything
        summary, models, offsets, read = _fig13_data(args, axis, params)
    files = model_figures(params, args.out)
    temps = [-40.0, -20.0, 0.0, 20.0, 40.0, 60.0]
    res = friction_torque(params, temps)
    rows = res.records()
    if summary is not None:
        compare_label = next((k for k in models if k != 'configured'), '')
        side = str(validity.get('fitted_directions', 'both'))
        files.append(plot_model_vs_measured(
            summary, models, args.out / FIG13_FILE, offsets_nmm=offsets,
            title=f'{axis}: model vs measured by direction (paper Fig. 13)',
            fitted_direction={compare_label: side} if compare_label else None,
            notes=[f'{args.compare.name}: {good_for}'] if good_for and args.compare is not None else []))
    if args.format == 'json':
        doc: dict[str, Any] = {'axis': axis, 'figures': [str(f) for f in files], 'fig11': rows}
        if summary is not None:
            doc['fig13'] = summary
            doc['read'] = read
            if args.compare is not None:
                doc['compare'] = {'file': str(args.compare), 'torque_offset_nmm': next(iter(offsets.values())),
                                  'validity': validity, 'good_for': good_for}
        print_json(doc)
        return 0
    print(f'axis {axis}: figures written to {args.out}/')
    for f in files:
        print(f'  {f}')
    print()
    print(format_table([[f'{r["temperature_c"]:.0f}', f'{r["m_viscous_nmm"]:.3f}',
                         f'{r["m_sliding_nmm"] + r["m_rolling_nmm"]:.3f}', f'{r["m_total_nmm"]:.3f}']
                        for r in rows], ['t [degC]', 'M_L [N*mm]', 'M_S+M_R [N*mm]', 'M [N*mm]']))
    if summary is not None:
        print()
        print(summary_table(summary, good_for, str(validity.get('fitted_directions', 'both'))))
        note = model_mismatch_note(summary)
        if note is not None:
            print(note)
    return 0


#: the published feedforward and the model at a plateau's temperature differ notably beyond this fraction [-]
MODEL_MISMATCH = 0.01


def summary_table(summary: list[dict[str, Any]], compare_note: str = '', fitted_direction: str = 'both') -> str:
    """Model vs measured by temperature plateau and direction, N*mm (with the model at the plateau's temperature
    and the compared model when present), after a legend line saying what each model column is (``compare_note``:
    what the compared file is good for, from its refit section; ``fitted_direction`` 'cw' or 'ccw': the compared
    model of the other direction is marked ``*``, not fitted)."""
    at_t = any('model_at_t_nmm' in r for r in summary)
    extra = any('compare_nmm' in r for r in summary)
    header = ['joint', 't [degC]', 'dir', 'measured [N*mm]', 'model [N*mm]', 'residual [N*mm]', 'samples']
    legend = [('model:       the feedforward paired with each sample in the residual log, mean per plateau '
               '(live: as friction_feedforward published it; replay: its rule over the bag)')]
    if extra:
        header[5:5] = ['refit model [N*mm]']
        legend.append("refit model: the compared parameters with the torque offset refit wrote, over the plateau's "
                      "samples (refit's own 'model after')" + (f'; {compare_note}' if compare_note else ''))
    if at_t:
        header[5:5] = ['model at t [N*mm]']
        legend.insert(1, "model at t:  the configured model at the plateau's temperature")
    rows = []
    for r in summary:
        row = [str(r['joint']), f'{r["temperature_c"]:.1f}', str(r['direction']), f'{r["measured_mean_nmm"]:+.3f}',
               f'{r["predicted_nmm"]:+.3f}', f'{r["residual_nmm"]:+.3f}', str(r['samples'])]
        if extra:
            unfitted = fitted_direction in ('cw', 'ccw') and str(r['direction']) != fitted_direction
            row[5:5] = [f'{r["compare_nmm"]:+.3f}' + ('*' if unfitted else '')]
        if at_t:
            row[5:5] = [f'{r["model_at_t_nmm"]:+.3f}']
        rows.append(row)
    if extra and fitted_direction in ('cw', 'ccw'):
        other = 'CCW' if fitted_direction == 'cw' else 'CW'
        legend.append(f'*: {other}, which the compared refit was not fitted on (--direction {fitted_direction})')
    return '\n'.join([*legend, format_table(rows, header)])


def model_mismatch_note(summary: list[dict[str, Any]]) -> str | None:
    """A line naming the plateaus where the feedforward as published differs from the model at the plateau's
    temperature by more than :data:`MODEL_MISMATCH` (None: nowhere)."""
    off = [r for r in summary if 'model_at_t_nmm' in r and math.isfinite(r['predicted_nmm'])
           and abs(r['predicted_nmm'] - r['model_at_t_nmm']) > MODEL_MISMATCH * abs(r['model_at_t_nmm'])]
    if not off:
        return None
    where = ', '.join(f'{r["temperature_c"]:.1f} degC {r["direction"]} ({r["predicted_nmm"]:+.3f} vs '
                      f'{r["model_at_t_nmm"]:+.3f})' for r in off)
    return ("note: the feedforward as published differs from the model at the plateau's temperature by more than "
            f'{100 * MODEL_MISMATCH:g} % at {where}: the feedforward used other temperatures than the samples (a '
            'stale one: see what the live nodes counted) or a learned correction')


def _fig13_data(args: argparse.Namespace, axis: str,
                params: Any) -> tuple[list[dict[str, Any]], dict[str, Any], dict[str, float], dict[str, Any]]:
    """Fig. 13's plateau summary of the residual logs, the models to draw and their offsets [N*mm], what was read.

    Raises:
        GimbalFrictionError: the logs hold no samples of ``axis``, or no temperature plateau (named, with why).
    """
    from gimbal_friction.chamber.summary import log_summary
    res = log_summary(args.residuals, axis, args.config, compare=args.compare)
    print_read_note(res.read)
    own = ("judged on the samples' own temperatures: the logs hold no temperature stream (replay --no-inputs, "
           'or residual_logger with log_inputs false)' if not res.stream_logged else '')
    if not res.summary:
        where = ', '.join(str(p) for p in args.residuals)
        msg = (f'{where}: no temperature plateau of axis {axis!r} to compare with ({res.rows} rows; a plateau '
               'needs 10 samples taken while the bearing temperature held within 1 degC/min over the 30 s before '
               f'them, and 10 samples per direction{"; " + own if own else ""})')
        raise GimbalFrictionError(msg)
    if own:
        print(f'note: plateaus {own}', file=sys.stderr)
    from gimbal_friction.physics.direction import SCALAR, direction_factor

    def model_at(p: Any, r: dict[str, Any]) -> float:
        """The model of ``p`` at a plateau's temperature, signed like the measurement, at the model speed [N*mm]."""
        sign = float(cast('float', r['sign']))
        t_c = float(cast('float', r['temperature_c']))
        return sign * direction_factor(p, t_c, sign, SCALAR) * float(friction_torque(p, t_c).m_total_nmm)

    summary = res.summary
    for r in summary:
        r['model_at_t_nmm'] = model_at(params, r)
    models: dict[str, Any] = {'configured': params}
    offsets: dict[str, float] = {}
    if res.compared is not None:
        label = f'with {args.compare.name}'
        models[label] = res.compared
        offsets[label] = nmm_from_nm(res.compare_offset_nm)
    return summary, models, offsets, res.read.as_dict()
