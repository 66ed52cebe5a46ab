"""``gimbal-friction refit``: refit the lubricant viscosity (and optionally other) parameters from residual logs.

Reads one or more residual-log folders (``residual_logger`` or ``replay`` output) with
:func:`~gimbal_friction.recording.residual_log.read_residual_log` and uses each ``residual_detail`` row's
``temperature_c``, ``velocity_rad_s`` (speed and direction) and ``measured_nm`` (signed; friction along the motion
is ``measured_nm · sign(velocity)``). Rows with a non-finite value or zero velocity are skipped and counted. The
fit is :func:`gimbal_friction.core.refit.refit_model` per axis (every axis present in the logs that is configured,
or ``--axis``); it says which parameters the data can determine and holds the others at their configured values.

Output file: a layerable parameter file holding **only the refitted parameters**, always under
``axis.<name>.<parameter>`` (also for a single axis): an ``axis.*`` entry overrides ``model.*`` whatever the file
order, so the refit takes effect even over a user file with per-axis lubricant values, and an axis without data
(e.g. a newly configured one) keeps its own values. The header records the logs, the date, the samples and the
RMS residual before and after. The file is written (atomically) only after every axis was refitted; on any
refusal nothing is written and an existing file is left untouched.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from gimbal_friction.config import axis_names, axis_params, load_parameters, render_parameter_file
from gimbal_friction.core.errors import ConfigError, FitError, GimbalFrictionError
from gimbal_friction.core.model import friction_torque
from gimbal_friction.core.params import AxisParams
from gimbal_friction.core.refit import FIT_PARAMETERS, PALMGREN_THRESHOLD, RefitResult, \
    palmgren_threshold_temperature, refit_model
from gimbal_friction.recording.residual_log import read_residual_log
from gimbal_friction.recording.topics import RESIDUAL_DETAIL
from gimbal_friction.core.table import RPM_PER_RAD_S
from gimbal_friction.tools._common import add_common, format_table, print_json, write_text_atomic

DEFAULT_FIT = 'walther_a'


class AxisData(NamedTuple):
    """Samples of one axis taken from the logs, and what was skipped."""

    temperature_c: np.ndarray
    speed_rpm: np.ndarray
    measured_abs_nm: np.ndarray
    direction: np.ndarray
    rows: int
    skipped_nonfinite: int
    skipped_standstill: int


class AxisRefit(NamedTuple):
    axis: str
    base: AxisParams
    data: AxisData
    result: RefitResult


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('refit', help='refit the lubricant viscosity parameters (and optionally others) from '
                            'residual logs',
                            description='Refit the Walther viscosity constants (and with --fit the Palmgren factor, '
                            'the sliding coefficient and the per-direction factors) to the measured friction in '
                            'residual logs by weighted least squares on the full model; report the fitted values '
                            'with 95 % confidence intervals, which parameters the data can determine, and the RMS '
                            'residual before and after per temperature bin and direction; write a parameter file '
                            'layerable with --config / --params-file (refitted values under axis.<name>).')
    parser.add_argument('logs', nargs='+', type=Path, metavar='LOG_DIR',
                        help='residual-log folder (or .mcap file) written by residual_logger or replay')
    parser.add_argument('--out', type=Path, required=True, metavar='FILE.yaml',
                        help='parameter file to write (only after a successful fit)')
    add_common(parser)
    parser.add_argument('--axis', action='append', metavar='NAME',
                        help='axis to refit (repeatable; default: every configured axis present in the logs)')
    parser.add_argument('--fit', default=DEFAULT_FIT, metavar='NAMES',
                        help=f'comma-separated parameters to fit, from {",".join(FIT_PARAMETERS)} '
                        f'(default {DEFAULT_FIT})')
    parser.add_argument('--loss', choices=['linear', 'soft_l1'], default='linear',
                        help='least-squares loss on the weighted plateau means (soft_l1: robust to outlier bins)')
    parser.add_argument('--bin-width', type=float, default=5.0, metavar='DEGC',
                        help='temperature bin width [degC] (default 5)')
    parser.add_argument('--direction', choices=['both', 'cw', 'ccw'], default='both',
                        help='use samples of one direction only: the paper found CW and CCW alike at 20 degC but '
                        'apart in the cold (grease distribution, not viscosity); cw = positive motion')
    parser.add_argument('--plot', type=Path, metavar='PNG',
                        help='draw measured vs model before/after by direction over temperature (paper Fig. 13)')
    parser.set_defaults(func=run)


def parse_fit(text: str) -> tuple[str, ...]:
    """``'walther_a,walther_b'`` to a tuple of fit parameter names.

    >>> parse_fit('walther_a, scale_negative')
    ('walther_a', 'scale_negative')
    """
    names = tuple(x.strip() for x in text.split(',') if x.strip())
    if not names:
        raise ConfigError('--fit', f'give at least one of {", ".join(FIT_PARAMETERS)}', text)
    bad = [x for x in names if x not in FIT_PARAMETERS]
    if bad:
        raise ConfigError('--fit', f'unknown {", ".join(bad)}; choose from {", ".join(FIT_PARAMETERS)}', text)
    if len(set(names)) != len(names):
        raise ConfigError('--fit', 'a parameter is listed twice', text)
    return names


def axis_samples(detail: Any, axis: str, direction: str = 'both') -> AxisData:
    """Samples of ``axis`` from the residual-detail arrays: temperature, speed [rpm], |friction| along the motion
    [N*m] and direction, with rows having a non-finite value or zero velocity skipped; ``direction`` 'cw' or
    'ccw' keeps positive or negative motion only."""
    sel = detail.joint == axis
    if direction != 'both':
        sel = sel & ((detail.velocity_rad_s > 0.0) if direction == 'cw' else (detail.velocity_rad_s < 0.0))
    t = detail.temperature_c[sel]
    v = detail.velocity_rad_s[sel]
    m = detail.measured_nm[sel]
    finite = np.isfinite(t) & np.isfinite(v) & np.isfinite(m)
    moving = finite & (v != 0.0)
    direction = np.sign(v[moving])
    return AxisData(t[moving], np.abs(v[moving]) * RPM_PER_RAD_S, m[moving] * direction, direction,
                    int(sel.sum()), int((~finite).sum()), int((finite & ~moving).sum()))


def _select_axes(args: argparse.Namespace, cfg: dict[str, Any], present: list[str]) -> tuple[list[str], list[str]]:
    configured = axis_names(cfg)
    if args.axis:
        for name in args.axis:
            axis_params(cfg, name)  # refuses an axis that is not configured
            if name not in present:
                msg = (f'no {RESIDUAL_DETAIL} samples for axis {name!r} in the logs (joints present: '
                       f'{", ".join(present) or "none"})')
                raise FitError(msg)
        return list(dict.fromkeys(args.axis)), []
    axes = [name for name in present if name in configured]
    if not axes:
        msg = (f'the logs hold joints {", ".join(repr(p) for p in present)}, none of them configured '
               f'(axes: {", ".join(configured)}); pass --config with those axes')
        raise FitError(msg)
    return axes, [name for name in present if name not in configured]


def _fmt(value: float, digits: int = 6) -> str:
    return '-' if not math.isfinite(value) else f'{value:.{digits}g}'


def provenance_header(fits: list[AxisRefit], logs: list[Path], files: int, fit: tuple[str, ...],
                      config: list[Path]) -> str:
    """Comment header of the written file: logs, date, base configuration, and per axis the samples, the RMS
    residual before and after, and every requested parameter (refitted with its 95 % interval, or why not)."""
    now = dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat()
    layers = ' + '.join(['packaged defaults', *(str(Path(c).resolve()) for c in config)])
    lines = [
        'gimbal-friction refit: lubricant (and other) parameters refitted to measured friction',
        'logs: ' + ', '.join(str(p.resolve()) for p in logs) + f' ({files} file(s))',
        f'date: {now}',
        f'base parameters: {layers} (layer this file over the same ones)',
        f'fit requested: {", ".join(fit)}',
    ]
    for f in fits:
        r = f.result
        lines.append(f"axis '{f.axis}': {r.n_samples} samples; RMS residual {1e3 * r.rms_before_nm:.4g} -> "
                     f'{1e3 * r.rms_after_nm:.4g} N*mm')
        for name in r.fitted:
            ident = r.identifiability[name]
            if ident.identifiable:
                lo, hi = r.confidence_intervals[name]
                lines.append(f'  {name} = {r.fitted[name]:.8g} (was {r.base[name]:.8g}; 95% CI '
                             f'[{lo:.8g}, {hi:.8g}])')
            else:
                lines.append(f'  {name}: not identifiable, not written ({ident.reason})')
        for vi in r.viscosity:
            lines.append(f'  viscosity at {vi.temperature_c:.1f} degC: {vi.before_cst:.6g} -> {vi.after_cst:.6g} cSt '
                         f'(95% [{vi.low_cst:.6g}, {vi.high_cst:.6g}])')
    lines.append('layer with: gimbal-friction ... --config FILE, or ros2 run ... --ros-args --params-file FILE')
    return '\n'.join(lines)


def plot_refit(fits: list[AxisRefit], path: Path) -> Path:
    """Paper Fig. 13 per axis: measured plateau means by direction (CW positive, CCW as |.|) with error bars and
    the model before (dashed) and after (solid) the refit over temperature, [N*mm]; PNG via matplotlib Agg."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(fits), figsize=(7.5 * len(fits), 5.0), squeeze=False)
    for ax, f in zip(axes[0], fits):
        r = f.result
        used = [b for b in r.bins if b.used]
        t_lo = min(b.temperature_c for b in used) - 5.0
        t_hi = max(b.temperature_c for b in used) + 5.0
        grid = np.linspace(t_lo, t_hi, 241)
        speeds = []
        for sign, label, color in ((1, 'CW (+)', 'C0'), (-1, '|CCW| (-)', 'C3')):
            pts = [b for b in used if b.direction == sign]
            if not pts:
                continue
            # CW and CCW markers side by side (0.4 degC apart) so neither hides the other
            ax.errorbar([b.temperature_c - 0.2 * sign for b in pts], [1e3 * b.measured_mean_nm for b in pts],
                        yerr=[1.96e3 * b.measured_se_nm for b in pts], fmt='o' if sign > 0 else 's', color=color,
                        mfc=color if sign > 0 else 'none', capsize=3, label=f'measured {label}, mean +/- 95 %')
            speed = float(np.median([b.speed_rpm for b in pts]))
            speeds.append(speed)
            for params, style, when in ((f.base, '--', 'before'), (r.params, '-', 'after')):
                k = params.scale_positive if sign > 0 else params.scale_negative
                model = k * friction_torque(params, grid, speed).m_total_nmm
                ax.plot(grid, model, style, color=color, lw=1.6 if when == 'after' else 1.1,
                        label=f'model {when}, {label}, {speed:.3g} rpm')
        t_thr = palmgren_threshold_temperature(r.params, min(speeds)) if speeds else math.nan
        if math.isfinite(t_thr) and t_thr > t_lo:
            ax.axvspan(t_lo, min(t_thr, t_hi), color='0.9', lw=0, zorder=0,
                       label=f'nu*n >= {PALMGREN_THRESHOLD:g} (refitted, {min(speeds):.3g} rpm): M_L depends on nu')
        ax.set_xlabel('temperature [°C]')
        ax.set_ylabel('friction torque |M| of the axis [N·mm]')
        ax.set_title(f'{f.axis}: measured vs model by direction (paper Fig. 13)\nRMS residual '
                     f'{1e3 * r.rms_before_nm:.3g} -> {1e3 * r.rms_after_nm:.3g} N·mm', fontsize=9)
        ax.grid(True, alpha=0.4)
        ax.legend(fontsize=7)
    fig.tight_layout()
    from gimbal_friction.plots import save_figure
    return save_figure(fig, path)


def _axis_record(f: AxisRefit) -> dict[str, Any]:
    r = f.result
    return {
        'rows': f.data.rows,
        'skipped_nonfinite': f.data.skipped_nonfinite,
        'skipped_standstill': f.data.skipped_standstill,
        'samples': r.n_samples,
        'samples_dropped': r.n_dropped,
        'fitted': r.fitted,
        'base': r.base,
        'standard_errors': r.standard_errors,
        'confidence_intervals_95': {k: list(v) for k, v in r.confidence_intervals.items()},
        'identifiability': {k: {'identifiable': v.identifiable, 'reason': v.reason}
                            for k, v in r.identifiability.items()},
        'written': r.refitted,
        'rms_before_nmm': 1e3 * r.rms_before_nm,
        'rms_after_nmm': 1e3 * r.rms_after_nm,
        'viscous_temperatures_c': list(r.viscous_temperatures_c),
        'viscosity': [{'temperature_c': vi.temperature_c, 'before_cst': vi.before_cst, 'after_cst': vi.after_cst,
                       'ci95_cst': [vi.low_cst, vi.high_cst]} for vi in r.viscosity],
        'bins': [{
            'temperature_c': b.temperature_c, 'temperature_bin_c': b.temperature_bin_c,
            'direction': 'cw' if b.direction > 0 else 'ccw', 'sign': b.direction, 'speed_rpm': b.speed_rpm,
            'samples': b.n, 'used': b.used, 'viscous': b.viscous,
            'measured_mean_nmm': 1e3 * b.measured_mean_nm, 'measured_se_nmm': 1e3 * b.measured_se_nm,
            'model_before_nmm': 1e3 * b.model_before_nm, 'model_after_nmm': 1e3 * b.model_after_nm,
            'rms_before_nmm': 1e3 * b.rms_before_nm, 'rms_after_nmm': 1e3 * b.rms_after_nm,
            'viscosity_before_cst': b.viscosity_before_cst, 'viscosity_after_cst': b.viscosity_after_cst,
        } for b in r.bins],
        'cost': r.cost,
        'message': r.message,
    }


def _print_axis(f: AxisRefit) -> None:
    r, d = f.result, f.data
    skipped = d.skipped_nonfinite + d.skipped_standstill
    print(f'axis {f.axis}: {r.n_samples} samples used of {d.rows} rows'
          + (f' ({d.skipped_nonfinite} non-finite, {d.skipped_standstill} at standstill skipped)' if skipped else '')
          + (f', {r.n_dropped} in groups too small to use' if r.n_dropped else ''))
    rows = []
    for name in r.fitted:
        ident = r.identifiability[name]
        if ident.identifiable:
            lo, hi = r.confidence_intervals[name]
            rows.append([name, _fmt(r.base[name]), _fmt(r.fitted[name], 8), _fmt(r.standard_errors[name], 3),
                         f'[{_fmt(lo, 8)}, {_fmt(hi, 8)}]', 'yes'])
        else:
            rows.append([name, _fmt(r.base[name]), _fmt(r.fitted[name], 8), '-', '-', 'NO (held)'])
    print(format_table(rows, ['parameter', 'base', 'fitted', 'std. error', '95% CI', 'identifiable']))
    for name, ident in r.identifiability.items():
        if not ident.identifiable:
            print(f'  {name}: not identifiable: {ident.reason}')
    print(f'RMS residual: {1e3 * r.rms_before_nm:.4g} -> {1e3 * r.rms_after_nm:.4g} N*mm ({r.message})')
    brows = []
    for b in r.bins:
        brows.append([f'{b.temperature_c:.1f}', 'CW' if b.direction > 0 else 'CCW', f'{b.speed_rpm:.3g}',
                      f'{b.n}' + ('' if b.used else ' (unused)'), f'{1e3 * b.measured_mean_nm:.4f}',
                      _fmt(1e3 * b.measured_se_nm, 2), f'{1e3 * b.model_before_nm:.4f}',
                      f'{1e3 * b.model_after_nm:.4f}', f'{1e3 * b.rms_before_nm:.4f}', f'{1e3 * b.rms_after_nm:.4f}',
                      f'{b.viscosity_before_cst:.5g}', f'{b.viscosity_after_cst:.5g}', 'yes' if b.viscous else ''])
    print(format_table(brows, ['t [degC]', 'dir', 'n [rpm]', 'samples', '|M| meas [N*mm]', 'se', 'model before',
                               'model after', 'RMS before', 'RMS after', 'nu before [cSt]', 'nu after',
                               'nu*n>=2000']))
    for vi in r.viscosity:
        print(f'viscosity at {vi.temperature_c:.1f} degC: {vi.before_cst:.5g} -> {vi.after_cst:.5g} cSt '
              f'(95% interval {vi.low_cst:.5g} .. {vi.high_cst:.5g})')
    if r.viscous_temperatures_c:
        temps = ', '.join(f'{x:g}' for x in r.viscous_temperatures_c)
        print(f'viscosity determined by the data at {temps} degC only (nu*n >= {PALMGREN_THRESHOLD:g}); elsewhere '
              'the viscous torque does not depend on viscosity at these speeds')


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    if out.is_dir():
        msg = f'--out {out} is a directory; give a file name such as refit.yaml'
        raise GimbalFrictionError(msg)
    if not (math.isfinite(args.bin_width) and args.bin_width > 0.0):
        raise ConfigError('--bin-width', 'must be > 0 [degC]', args.bin_width)
    fit = parse_fit(args.fit)
    cfg = load_parameters(args.config)
    log = read_residual_log(args.logs)  # refuses empty and foreign folders
    detail = log.detail
    where = ', '.join(str(p) for p in args.logs)
    if len(detail) == 0:
        msg = f'{where}: the residual log holds no {RESIDUAL_DETAIL} samples'
        raise FitError(msg)
    present = sorted({str(j) for j in detail.joint.tolist()})
    axes, ignored = _select_axes(args, cfg, present)
    fits: list[AxisRefit] = []
    for axis in axes:
        base = axis_params(cfg, axis)
        data = axis_samples(detail, axis, args.direction)
        try:
            result = refit_model(base, data.temperature_c, data.speed_rpm, data.measured_abs_nm, data.direction,
                                 fit=fit, loss=args.loss, bin_width_c=args.bin_width)
        except FitError as err:
            hint = ' (pass --axis to refit only the others)' if len(axes) > 1 else ''
            msg = f'axis {axis}: {err}{hint}'
            raise FitError(msg) from None
        fits.append(AxisRefit(axis, base, data, result))
    if args.plot is not None:
        plot_refit(fits, args.plot)
    text = render_parameter_file(axes_overrides={f.axis: f.result.refitted for f in fits},
                                 header=provenance_header(fits, list(args.logs), len(log.files), fit,
                                                          list(args.config)))
    write_text_atomic(out, text)

    if args.format == 'json':
        print_json({'logs': [str(p) for p in args.logs], 'files': [str(p) for p in log.files],
                    'truncated_files': [str(p) for p in log.truncated_files], 'out': str(out),
                    'plot': None if args.plot is None else str(args.plot), 'fit': list(fit),
                    'config': [str(c) for c in args.config],
                    'ignored_joints': ignored, 'axes': {f.axis: _axis_record(f) for f in fits}})
        print(f'wrote {out}' + ('' if args.plot is None else f', plot: {args.plot}'), file=sys.stderr)
        return 0
    print(f'refit of {", ".join(fit)} from {len(log.files)} file(s) in {where}'
          + (f' ({len(log.truncated_files)} truncated)' if log.truncated_files else ''))
    if ignored:
        print(f'joints not configured, ignored: {", ".join(ignored)}')
    for f in fits:
        print()
        _print_axis(f)
    written = [f'axis.{f.axis}.{name}' for f in fits for name in f.result.refitted]
    print()
    print(f'wrote {out} ({", ".join(written)})')
    if args.plot is not None:
        print(f'plot: {args.plot}')
    return 0
