"""``gimbal-friction refit``: refit the lubricant viscosity (and optionally other) parameters from residual logs.

Streams one or more residual-log folders (``residual_logger`` or ``replay`` output) chunk by chunk
(:func:`~gimbal_friction.recording.residual_read.iter_residual_rows`, bounded memory) and uses each
``residual_detail`` row's ``temperature_c``, ``velocity_rad_s``
(speed and direction) and ``measured_nm`` (signed; friction along the motion is ``measured_nm · sign(velocity)``),
accumulated into per-bin sufficient statistics (:mod:`gimbal_friction.refit.sufficient`). Rows with a non-finite
value or zero velocity are skipped and counted. The fit is :func:`gimbal_friction.refit.fit.refit_stats` per axis
(every axis present in the logs that is configured, or ``--axis``); it says which parameters the data can
determine and holds the others at their configured values.

Calibration offset: with ``--offset auto`` (default) a constant torque offset (an error of the no-load current
I_0) is fitted as a nuisance when the logs hold both a cold (viscous-regime) and a warm plateau; it is reported
with its interval and the I_0 that would remove it, and a warning is printed (stderr) when it exceeds the
calibration's uncertainty, read from the ``calibrate-kt`` output file (``--calibration FILE.yaml``: its
``gimbal_friction_calibration`` section, format version 1; a file from before it by its comment line
``T_0 = ... +/- SE N*m``, with a note) or given as ``--calibration-se`` [N*m]. The offset is never written as a
parameter (the nodes must not add it); the file carries it as data in its ``gimbal_friction_refit`` section
(:mod:`gimbal_friction.refit.records`), which ``report --compare`` adds to the refitted model as this table does.

Output file: a layerable parameter file holding **only the refitted parameters**, always under
``axis.<name>.<parameter>`` (also for a single axis): an ``axis.*`` entry overrides ``model.*`` whatever the file
order, so the refit takes effect even over a user file with per-axis lubricant values, and an axis without data
(e.g. a newly configured one) keeps its own values. The header records the logs, the date, the samples and the
RMS residual before and after. The file is written (atomically) only after every axis was refitted; on any
refusal nothing is written. An existing ``--out`` (or ``--plot``) is refused unless ``--force`` (the rule of
every command's outputs, :func:`~gimbal_friction.cli._common.refuse_existing`).

What the read skipped (damaged chunks and the messages lost with them, files cut short, messages that are not
rows) is said on stderr and in the header line, and counted in the JSON ``read`` record; an axis without usable
samples is refused naming the logs, the direction filter and the rows skipped.

Learned correction (``--correction-out FILE.yaml``): after the refit, a second pass over the same logs learns the
correction of the feedforward (:mod:`gimbal_friction.feedforward.correction`) from each row's residual against the
*refitted* model (measured friction − the model of the configuration with the refitted file layered over it, both
signed like the motion; :func:`~gimbal_friction.refit.logs.read_correction`), per temperature bin × direction (and
ripple at the periods found in the residuals and a trend), with the layout and shrinkage of the
``correction_*`` parameters of ``friction_feedforward`` (defaults otherwise). It is written atomically next to the
parameter file, refused if it exists unless ``--force``; the learned cells are printed (and in the JSON
``correction`` record). Load both: ``--config refit.yaml`` + ``correction_file`` (node), ``load_feedforward(...,
correction=...)``, ``replay --correction``, ``export --correction``.

A fit set that cannot separate its parameters from the calibration offset (``palmgren_factor`` switches it off)
is checked: the JSON ``offset_confounding`` record and a warning say which parameters a 1-sigma offset (the
calibration's, else K_T × 1 mA) moves by more than their standard error, by how much, and the viscosity at the
coldest plateau.

The run itself (read, choose axes, refit) is :func:`gimbal_friction.refit.run.refit_logs`; this module parses the
options, writes the file, prints and draws.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.chamber.learned import correction_record, correction_settings, learn_correction
from gimbal_friction.cli._common import (
    add_common,
    format_table,
    print_json,
    print_read_note,
    refuse_existing,
    write_text_atomic,
)
from gimbal_friction.common.errors import ConfigError, GimbalFrictionError
from gimbal_friction.config.loader import axis_names, axis_params, load_parameters, render_parameter_file
from gimbal_friction.feedforward.correction import save as save_correction
from gimbal_friction.physics.direction import ARRAY, direction_factor
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.refit.fit import (
    ASYMMETRY_PARAMETERS,
    DEFAULT_FIT,
    FIT_PARAMETERS,
    OFFSET_MODES,
    PALMGREN_THRESHOLD,
    RefitResult,
    palmgren_threshold_temperature,
)
from gimbal_friction.refit.fit_check import FitCheck, describe_bin, direction_name, interval_label, summary_line
from gimbal_friction.refit.logs import LearnedCorrection, correction_table
from gimbal_friction.refit.records import (
    REFIT_SECTION,
    fit_check_record,
    offset_values,
    refit_record,
    refit_section_text,
    validity_values,
)
from gimbal_friction.refit.run import Alternative, AxisRefit, refit_logs

#: ``--fit`` shorthand for both anchors of the direction asymmetry
FIT_ALIASES = {'direction_asymmetry': ASYMMETRY_PARAMETERS}


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('refit', help='refit the lubricant viscosity parameters (and optionally others) from '
                            'residual logs',
                            description='Refit the Walther viscosity constants (and with --fit the Palmgren factor, '
                            'the sliding coefficient and the per-direction factors) to the measured friction in '
                            'residual logs by weighted least squares on the full model; report the fitted values '
                            'with their intervals, which parameters the data can determine, the RMS residual before '
                            'and after per temperature bin and direction, and whether the model fits every bin (a '
                            'lack-of-fit check against batch-means standard errors: only then are the intervals 95 '
                            '% confidence intervals; otherwise the bins off are named, with what to try); write a '
                            'parameter file layerable with --config / --params-file (refitted values under '
                            'axis.<name>).')
    parser.add_argument('logs', nargs='+', type=Path, metavar='LOG_DIR',
                        help='residual-log folder (or .mcap file) written by residual_logger or replay')
    parser.add_argument('--out', type=Path, required=True, metavar='FILE.yaml',
                        help='parameter file to write (only after a successful fit; an existing file is refused '
                        'unless --force)')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing --out file (and --plot figure, --correction-out file)')
    parser.add_argument('--correction-out', type=Path, metavar='FILE.yaml',
                        help='also write the learned correction (residuals against the refitted model, per '
                        'temperature bin and direction, with sample counts and standard errors) to this file; an '
                        'existing file is refused unless --force')
    add_common(parser)
    parser.add_argument('--axis', action='append', metavar='NAME',
                        help='axis to refit (repeatable; default: every configured axis present in the logs)')
    parser.add_argument('--fit', default=','.join(DEFAULT_FIT), metavar='NAMES',
                        help=f'comma-separated parameters to fit, from {",".join(FIT_PARAMETERS)} '
                        f'(default {",".join(DEFAULT_FIT)})')
    parser.add_argument('--loss', choices=['linear', 'soft_l1'], default='linear',
                        help='least-squares loss on the weighted plateau means (soft_l1: robust to outlier bins)')
    parser.add_argument('--bin-width', type=float, default=5.0, metavar='DEGC',
                        help='temperature bin width [degC] (default 5)')
    parser.add_argument('--direction', choices=['both', 'cw', 'ccw'], default='both',
                        help='use samples of one direction only: the paper found CW and CCW alike at 20 degC but '
                        'apart in the cold (grease distribution, not viscosity); cw = positive motion')
    parser.add_argument('--plot', type=Path, metavar='PNG',
                        help='draw measured vs model before/after by direction over temperature (paper Fig. 13)')
    parser.add_argument('--offset', choices=OFFSET_MODES, default='auto',
                        help='constant torque offset of the measurement (an I_0 calibration error) fitted as a '
                        'nuisance: auto (default) = when the logs hold a cold (nu*n >= 2000) and a warm plateau')
    parser.add_argument('--calibration', type=Path, metavar='FILE.yaml',
                        help='calibrate-kt output the logs were measured with: its T_0 uncertainty is what the '
                        'offset is compared with (values not applied; layer it with --config for that)')
    parser.add_argument('--calibration-se', type=float, metavar='N*M',
                        help='1-sigma uncertainty of the no-load torque T_0 = K_T*I_0 [N*m], instead of --calibration')
    parser.set_defaults(func=run)


def parse_fit(text: str) -> tuple[str, ...]:
    """``'walther_a,walther_b'`` to a tuple of fit parameter names.

    >>> parse_fit('walther_a, scale_negative')
    ('walther_a', 'scale_negative')
    >>> parse_fit('walther_a,direction_asymmetry')
    ('walther_a', 'direction_asymmetry_cold', 'direction_asymmetry_warm')
    """
    names = tuple(y for x in text.split(',') if x.strip() for y in FIT_ALIASES.get(x.strip(), (x.strip(),)))
    if not names:
        raise ConfigError('--fit', f'give at least one of {", ".join(FIT_PARAMETERS)}', text)
    bad = [x for x in names if x not in FIT_PARAMETERS]
    if bad:
        raise ConfigError('--fit', f'unknown {", ".join(bad)}; choose from {", ".join(FIT_PARAMETERS)} (or '
                          f'{", ".join(FIT_ALIASES)})', text)
    if len(set(names)) != len(names):
        raise ConfigError('--fit', 'a parameter is listed twice', text)
    return names


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
        label = interval_label(r.fit_check)
        for name in r.fitted:
            ident = r.identifiability[name]
            if ident.identifiable:
                lo, hi = r.confidence_intervals[name]
                lines.append(f'  {name} = {r.fitted[name]:.8g} (was {r.base[name]:.8g}; {label} '
                             f'[{lo:.8g}, {hi:.8g}])')
            else:
                lines.append(f'  {name}: not identifiable, not written ({ident.reason})')
        for vi in r.viscosity:
            lines.append(f'  viscosity at {vi.temperature_c:.1f} degC: {vi.before_cst:.6g} -> {vi.after_cst:.6g} cSt '
                         f'({label} [{vi.low_cst:.6g}, {vi.high_cst:.6g}])')
        lines.append(f'  {offset_text(r)} (no parameter: in the {REFIT_SECTION} section, for report --compare)')
        lines.append(f'  {summary_line(r.fit_check)}')
        lines.append(f'  good for: {good_for(f)}')
    lines.append('layer with: gimbal-friction ... --config FILE, or ros2 run ... --ros-args --params-file FILE')
    return '\n'.join(lines)


def good_for(f: AxisRefit) -> str:
    """What the refitted file of one axis is good for: the directions it was fitted on, whether its model fits
    them, and how it does on the direction a one-direction refit left out."""
    r = f.result
    if r.direction == 'both':
        what = 'both directions'
    else:
        what = f'{r.direction.upper()} motion only (fitted on --direction {r.direction})'
    if not r.fit_check.fits:
        what += ', but its model does not fit them (see the fit check)'
    held = f.held_out
    if held.checked:
        other = direction_name(-1 if r.direction == 'cw' else 1)
        if held.fits:
            what += f'; it also fits the {other} samples of the logs (worst |z| {abs(held.worst.z):.1f})' \
                if held.worst is not None else ''
        else:
            worst = held.misfits[0]
            what += (f'; NOT for {other}: {len(held.misfits)} of {len(held.bins)} {other} bins of the logs do not fit '
                     f'it, worst {describe_bin(worst)}')
    return what


def plot_refit(fits: list[AxisRefit], path: Path) -> Path:
    """Paper Fig. 13 per axis: measured plateau means by direction (CW positive, CCW as |.|) with error bars and
    the model before (dashed) and after (solid) the refit over temperature, [N*mm]; PNG via matplotlib Agg."""
    from gimbal_friction.plots.figures import pyplot

    plt = pyplot()

    fig, axes = plt.subplots(1, len(fits), figsize=(7.5 * len(fits), 5.0), squeeze=False)
    for ax, f in zip(axes[0], fits, strict=False):
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
                k = direction_factor(params, grid, float(sign), ARRAY)
                shift = 1e3 * r.offset.value_nm if when == 'after' and r.offset.estimated else 0.0
                model = k * friction_torque(params, grid, speed).m_total_nmm + shift
                ax.plot(grid, model, style, color=color, lw=1.6 if when == 'after' else 1.1,
                        label=f'model {when}, {label}, {speed:.3g} rpm')
        t_thr = palmgren_threshold_temperature(r.params, min(speeds)) if speeds else math.nan
        if math.isfinite(t_thr) and t_thr > t_lo:
            ax.axvspan(t_lo, min(t_thr, t_hi), color='0.9', lw=0, zorder=0,
                       label=f'nu*n >= {PALMGREN_THRESHOLD:g} (refitted, {min(speeds):.3g} rpm): M_L depends on nu')
        ax.set_xlabel('temperature [°C]')
        ax.set_ylabel('friction torque |M| of the axis [N·mm]')
        notes = []
        if r.direction != 'both':
            other = 'CCW' if r.direction == 'cw' else 'CW'
            notes.append(f'fitted on {r.direction.upper()} samples only: a model of {r.direction.upper()} motion'
                         + (f', NOT of {other} (its samples do not fit it)' if f.held_out.checked
                            and not f.held_out.fits else ''))
        if r.fit_check.checked and not r.fit_check.fits:
            notes.append(f'the model does NOT fit {len(r.fit_check.misfits)} of {len(r.fit_check.bins)} bins: its '
                         'intervals are not confidence intervals')
        rms = f'RMS residual {1e3 * r.rms_before_nm:.3g} -> {1e3 * r.rms_after_nm:.3g} N·mm'
        ax.set_title('\n'.join([f'{f.axis}: measured vs model by direction (paper Fig. 13)', rms, *notes]),
                     fontsize=9)
        ax.grid(True, alpha=0.4)
        ax.legend(fontsize=7)
    fig.tight_layout()
    from gimbal_friction.plots.figures import save_figure
    return save_figure(fig, path)


def _axis_record(f: AxisRefit) -> dict[str, Any]:
    """The JSON record of one axis: the rows read and :func:`~gimbal_friction.refit.records.refit_record`."""
    return {'rows': f.data.rows, 'skipped_nonfinite': f.data.skipped_nonfinite,
            'skipped_standstill': f.data.skipped_standstill, **refit_record(f.result),
            'held_out_direction': fit_check_record(f.held_out) if f.held_out.checked else None,
            'good_for': good_for(f),
            'alternatives': [{'options': a.options, 'fit': list(a.fit), 'direction': a.direction, 'error': a.error,
                              'fits': None if a.result is None else a.result.fit_check.fits,
                              'fitted': None if a.result is None else a.result.refitted,
                              'confidence_intervals_95': None if a.result is None else
                              {k: list(v) for k, v in a.result.confidence_intervals.items()},
                              'fit_check': None if a.result is None else fit_check_record(a.result.fit_check)}
                             for a in f.alternatives]}


def offset_text(r: RefitResult) -> str:
    """One line on the calibration offset of a refit."""
    o = r.offset
    if not o.estimated:
        return f'torque offset: not estimated ({o.reason})'
    lo, hi = o.confidence_interval_nm
    cal = (f'; calibration T_0 1-sigma {1e3 * o.calibration_se_nm:.3g} N*mm: '
           + ('EXCEEDS it' if o.exceeds_calibration else 'within it')) if o.exceeds_calibration is not None else \
        '; no calibration uncertainty given (--calibration / --calibration-se)'
    label = '95%' if r.fit_check.fits else 'interval, NOT a 95% CI'
    return (f'torque offset {1e3 * o.value_nm:+.4g} N*mm ({label} [{1e3 * lo:+.4g}, {1e3 * hi:+.4g}]), as if I_0 were '
            f'{o.implied_no_load_current_a:.6g} A instead of {o.no_load_current_a:.6g} A{cal}')


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
    print(format_table(rows, ['parameter', 'base', 'fitted', 'std. error', interval_label(r.fit_check),
                              'identifiable']))
    for name, ident in r.identifiability.items():
        if not ident.identifiable:
            print(f'  {name}: not identifiable: {ident.reason}')
    print(f'RMS residual: {1e3 * r.rms_before_nm:.4g} -> {1e3 * r.rms_after_nm:.4g} N*mm ({r.message})')
    print(offset_text(r))
    for warning in r.warnings:
        print(f'WARNING: {warning}')
    print_fit_check(f)
    z = {(b.temperature_bin_c, b.direction, b.speed_rpm): b.z for b in r.fit_check.bins}
    brows = []
    for b in r.bins:
        brows.append([f'{b.temperature_c:.1f}', 'CW' if b.direction > 0 else 'CCW', f'{b.speed_rpm:.3g}',
                      f'{b.n}' + ('' if b.used else ' (unused)'), f'{1e3 * b.measured_mean_nm:.4f}',
                      _fmt(1e3 * b.measured_se_nm, 2), f'{1e3 * b.model_before_nm:.4f}',
                      f'{1e3 * b.model_after_nm:.4f}', f'{1e3 * b.rms_before_nm:.4f}', f'{1e3 * b.rms_after_nm:.4f}',
                      f'{b.viscosity_before_cst:.5g}', f'{b.viscosity_after_cst:.5g}', 'yes' if b.viscous else '',
                      _z_text(z.get((b.temperature_bin_c, b.direction, b.speed_rpm)), r.fit_check)])
    print(format_table(brows, ['t [degC]', 'dir', 'n [rpm]', 'samples', '|M| meas [N*mm]', 'se', 'model before',
                               'model after', 'RMS before', 'RMS after', 'nu before [cSt]', 'nu after',
                               'nu*n>=2000', 'z after']))
    label = '95% interval' if r.fit_check.fits else 'interval, NOT a 95% CI (the model does not fit)'
    for vi in r.viscosity:
        print(f'viscosity at {vi.temperature_c:.1f} degC: {vi.before_cst:.5g} -> {vi.after_cst:.5g} cSt '
              f'({label} {vi.low_cst:.5g} .. {vi.high_cst:.5g})')
    if r.viscous_temperatures_c:
        temps = ', '.join(f'{x:g}' for x in r.viscous_temperatures_c)
        print(f'viscosity determined by the data at {temps} degC only (nu*n >= {PALMGREN_THRESHOLD:g}); elsewhere '
              'the viscous torque does not depend on viscosity at these speeds')


def _z_text(z: float | None, check: FitCheck) -> str:
    """A bin's z after the fit, marked when beyond what the check allows ('' for a bin not in the fit)."""
    if z is None:
        return ''
    return f'{z:+.1f}' + (' OFF' if abs(z) > check.z_critical else '')


def _alternative_text(a: Alternative) -> str:
    """One line on a fit tried instead: does its model fit, and its first parameter with the interval."""
    r = a.result
    if r is None:
        return f'{a.options}: refused ({a.error})'
    c = r.fit_check
    name = next((n for n in r.fitted if r.identifiability[n].identifiable), '')
    value = ''
    if name:
        lo, hi = r.confidence_intervals[name]
        value = (f'; {name} {_fmt(r.fitted[name], 8)} ({"95% CI" if c.fits else "interval, not a CI"} '
                 f'[{_fmt(lo, 8)}, {_fmt(hi, 8)}])')
    if c.fits:
        verdict = f'fits every bin (worst |z| {abs(c.worst.z):.1f}, allowed {c.z_critical:.2f})' if c.worst else 'fits'
    else:
        worst = c.misfits[0]
        verdict = (f'does NOT fit {len(c.misfits)} of {len(c.bins)} bins (worst {worst.temperature_c:.1f} degC '
                   f'{direction_name(worst.direction)}, z {worst.z:+.1f})')
    return f'{a.options}: {verdict}{value}'


def print_fit_check(f: AxisRefit) -> None:
    """The lack-of-fit check of one axis: the verdict, the bins that do not fit with their numbers, what they have
    in common, what to try (with the fits tried on the same data) and, for a one-direction refit, how the other
    direction of the logs fares."""
    c = f.result.fit_check
    print(summary_line(c) if c.fits or not c.checked else
          f'fit check: the model does NOT fit {len(c.misfits)} of {len(c.bins)} bins: |z| = |measured - model| / '
          f'standard error above {c.z_critical:.2f} (the 5 % family-wise limit; standard errors from batch means: '
          f'the samples are correlated); chi2 {c.chi2:.4g}, dof {c.dof}')
    if c.checked and not c.fits:
        rows = [[f'{b.temperature_c:.1f}', direction_name(b.direction), f'{1e3 * b.measured_mean_nm:.4f}',
                 f'{1e3 * b.model_nm:.4f}', f'{1e3 * b.residual_nm:+.4f}', f'{1e3 * b.standard_error_nm:.4f}',
                 f'{b.z:+.1f}'] for b in c.misfits]
        print(format_table(rows, ['t [degC]', 'dir', 'measured [N*mm]', 'model [N*mm]', 'residual [N*mm]',
                                  'se [N*mm]', 'z']))
        print(f'  {c.pattern}')
        print('  so the intervals above are NOT 95 % confidence intervals: they assume a model that fits, and the '
              'truth may lie outside them')
        print('  what to try: ' + '; '.join(c.advice))
        if f.alternatives:
            print('  tried on the same data:')
            for a in f.alternatives:
                print(f'    {_alternative_text(a)}')
    held = f.held_out
    if held.checked:
        other = direction_name(-1 if f.result.direction == 'cw' else 1)
        if held.fits:
            print(f'the {other} samples left out (--direction {f.result.direction}) fit the refitted model too '
                  f'({len(held.bins)} bins, worst |z| {abs(held.worst.z) if held.worst else 0.0:.1f})')
        else:
            print(f'the {other} samples left out (--direction {f.result.direction}): {len(held.misfits)} of '
                  f'{len(held.bins)} bins do not fit the refitted model, worst {describe_bin(held.misfits[0])}: '
                  f'the file describes {f.result.direction.upper()} motion, not {other}')


def print_correction(learned: LearnedCorrection, path: Path) -> None:
    """The learned cells of a correction as a table (N*mm)."""
    table, _ = correction_table(learned.correction)
    n = sum(int(r[5]) for r in table)
    print(f'learned correction (residual against the refitted model, along the motion; {n} samples in '
          f'{len(table)} cells):')
    if table:
        print(format_table(table, ['joint', 't bin [degC]', 'dir', 'value [N*mm]', 'std. error', 'samples',
                                   'applied (the guard: scored out of sample)', 'saturated']))
    for joint, reasons in learned.refused.items():
        if reasons:
            print(f'  {joint}: samples not learned: ' + ', '.join(f'{k} {v}' for k, v in sorted(reasons.items())))
    print(f'wrote {path}')


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    if out.is_dir():
        msg = f'--out {out} is a directory; give a file name such as refit.yaml'
        raise GimbalFrictionError(msg)
    refuse_existing(out, '--out', force=args.force)
    correction_out: Path | None = args.correction_out
    if correction_out is not None:
        if correction_out.is_dir() or correction_out.resolve() == out.resolve():
            msg = f'--correction-out {correction_out}: give a file name other than --out, such as refit.correction.yaml'
            raise GimbalFrictionError(msg)
        refuse_existing(correction_out, '--correction-out', force=args.force)
        correction_settings(load_parameters(args.config, node_name='friction_feedforward'))   # refuse bad ones now
    if args.plot is not None:
        refuse_existing(args.plot, '--plot', force=args.force)
    fit = parse_fit(args.fit)
    cfg = load_parameters(args.config)
    done = refit_logs(list(args.logs), configured=axis_names(cfg), base_of=lambda axis: axis_params(cfg, axis),
                      fit=fit, axes=args.axis, direction=args.direction, loss=args.loss, bin_width_c=args.bin_width,
                      offset=args.offset, calibration_se_nm=args.calibration_se, calibration=args.calibration,
                      on_read=print_read_note)
    fits, report, ignored = done.fits, done.report, done.ignored
    for note in done.notes:
        print(f'gimbal-friction refit: note: {note}', file=sys.stderr)
    where = ', '.join(str(p) for p in args.logs)
    if args.plot is not None:
        plot_refit(fits, args.plot)
    text = render_parameter_file(axes_overrides={f.axis: f.result.refitted for f in fits},
                                 header=provenance_header(fits, list(args.logs), len(report.files), fit,
                                                          list(args.config)))
    text += refit_section_text({f.axis: offset_values(f.result) for f in fits},   # the offsets, as data
                               {f.axis: validity_values(f.result, f.held_out) for f in fits})
    write_text_atomic(out, text)
    for f in fits:
        for warning in f.result.warnings:
            print(f'gimbal-friction refit: warning: axis {f.axis}: {warning}', file=sys.stderr)
    learned = None
    if correction_out is not None:   # against the model the feedforward will run: the configuration + the refit
        learned = learn_correction(list(args.logs), [*args.config, out], label='refit: correction')
        save_correction(learned.correction, correction_out)

    if args.format == 'json':
        print_json({'logs': [str(p) for p in args.logs], 'files': [str(p) for p in report.files],
                    'truncated_files': [str(p) for p in report.truncated_files], 'read': report.as_dict(),
                    'out': str(out),
                    'plot': None if args.plot is None else str(args.plot), 'fit': list(fit),
                    'config': [str(c) for c in args.config], 'offset_mode': args.offset,
                    'ignored_joints': ignored, 'axes': {f.axis: _axis_record(f) for f in fits},
                    'correction': None if learned is None or correction_out is None
                    else correction_record(learned, correction_out)})
        print(f'wrote {out}' + ('' if args.plot is None else f', plot: {args.plot}')
              + ('' if correction_out is None else f', correction: {correction_out}'), file=sys.stderr)
        return 0
    print(f'refit of {", ".join(fit)} from {len(report.files)} file(s) in {where}'
          + (f': {report.summary()}; the fit below uses the {report.rows} rows read, and no other'
             if report.skipped else ''))
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
    if learned is not None and correction_out is not None:
        print()
        print_correction(learned, correction_out)
    return 0
