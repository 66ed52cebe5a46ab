"""``gimbal-friction calibrate-kt``: fit K_T and the no-load offset I_0 (paper Eq. 23) from calibration data.

Input is a CSV file with a header row and columns ``current_a`` [A], ``torque_nm`` [N*m] and optionally
``speed_rad_s`` [rad/s] (lines starting with ``#`` are comments), or a rosbag2 bag (directory or ``.mcap`` file)
with the topics ``/gimbal/calibration/current`` and ``/gimbal/calibration/torque`` (``sensor_msgs/msg/JointState``
effort of the axis joint, or ``std_msgs/msg/Float64``), paired by nearest stamp. The fit is
:func:`gimbal_friction.estimation.kt.fit_kt`. The output is a layerable parameter file holding
``axis.<NAME>.torque_constant_nm_per_a`` and ``axis.<NAME>.no_load_current_a``, written only when the fit is
accepted (atomically, so a refused or failed run leaves an existing file untouched), and the result as data in its
``gimbal_friction_calibration`` section (format version 1, read by ``refit --calibration``; ignored by the nodes).
The reading, the fit and the format live in :mod:`gimbal_friction.recording.calibration`; this module parses the
options, prints and draws.
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import sys
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.cli._common import add_common, format_table, print_json, refuse_existing, write_text_atomic
from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.config.loader import axis_names, axis_params, load_parameters, render_parameter_file
from gimbal_friction.estimation.kt import OUTLIER_THRESHOLD, KtFit
from gimbal_friction.recording.calibration import (
    CURRENT_TOPIC,
    DEFAULT_MAX_DT_S,
    TORQUE_TOPIC,
    CalibrationData,
    calibrate,
    calibration_record,
    calibration_section_text,
)


def add_parser(sub: Any) -> None:
    parser = sub.add_parser('calibrate-kt', help='fit K_T and I_0 from calibration data (motor current vs '
                            'reference torque)',
                            description='Fit the motor torque constant K_T and the no-load current I_0 of paper '
                            'Eq. 23 (torque = K_T*(I - sign(speed)*I_0)) by robust least squares, report the fit '
                            'quality and uncertainty, and write a parameter file layerable with --config / '
                            '--params-file.')
    parser.add_argument('input', type=Path, metavar='INPUT',
                        help='CSV with header current_a,torque_nm[,speed_rad_s], or a rosbag2 bag (directory or '
                        f'.mcap) with {CURRENT_TOPIC} and {TORQUE_TOPIC}')
    parser.add_argument('--axis', metavar='NAME', help='configured axis (default: the first in axes)')
    parser.add_argument('--out', type=Path, required=True, metavar='FILE.yaml',
                        help='parameter file to write (only when the fit is accepted; an existing file is refused '
                        'unless --force)')
    parser.add_argument('--force', action='store_true', help='replace an existing --out file (and --plot figure)')
    add_common(parser)
    parser.add_argument('--plot', type=Path, metavar='PNG', help='draw data, fit and residuals (outliers marked)')
    parser.add_argument('--max-dt', type=float, default=DEFAULT_MAX_DT_S, metavar='S',
                        help=f'bag input: largest stamp difference of a current/torque pair [s] '
                        f'(default {DEFAULT_MAX_DT_S:g})')
    parser.set_defaults(func=run)


# ---------------------------------------------------------------------------------------------- output
def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open('rb') as f:
        for chunk in iter(lambda: f.read(1 << 16), b''):
            h.update(chunk)
    return h.hexdigest()


def provenance_header(fit: KtFit, axis: str, source: Path, data: CalibrationData) -> str:
    """Comment header of the written parameter file: source, date, sample count and the fit with its 1-sigma."""
    digest = f' (sha256 {_sha256(source)[:16]})' if source.is_file() else ''
    direction = 'sign of speed_rad_s' if data.speed_rad_s is not None else 'assumed positive (no speed)'
    now = dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat()
    return '\n'.join([
        f"gimbal-friction calibrate-kt: motor torque constant and no-load current of axis '{axis}' (paper Eq. 23)",
        f'source: {source.resolve()}{digest}',
        f'date: {now}',
        (f'points: {fit.n} ({fit.n_outliers} outlier(s) rejected at {OUTLIER_THRESHOLD:g} robust sigma); '
         f'direction: {direction}'),
        (f'K_T = {fit.K_T:.6g} +/- {fit.se_K_T:.2g} N*m/A, I_0 = {fit.I_0:.6g} +/- {fit.se_I_0:.2g} A, '
         f'T_0 = {fit.T_0:.6g} +/- {fit.se_T_0:.2g} N*m (1 sigma)'),
        f'R^2 = {fit.r2:.6f}, residual std = {fit.residual_std:.3g} N*m',
        'layer with: gimbal-friction ... --config FILE, or ros2 run ... --ros-args --params-file FILE',
    ])


def plot_fit(fit: KtFit, data: CalibrationData, path: Path, *, title: str = '') -> Path:
    """Data, fit line(s) per direction and residuals [mN*m] with outliers marked, as a PNG (matplotlib Agg)."""
    from gimbal_friction.plots.figures import pyplot

    plt = pyplot()

    I_arr, tau, inl = data.current_a, data.torque_nm, fit.inliers
    fig, (ax, axr) = plt.subplots(2, 1, figsize=(7.5, 6.4), sharex=True, gridspec_kw={'height_ratios': [3, 1.4]})
    ax.plot(I_arr[inl], tau[inl], '.', color='C0', label=f'data ({fit.n_inliers} inliers)')
    if fit.n_outliers:
        ax.plot(I_arr[~inl], tau[~inl], 'x', color='C3', ms=7, label=f'outliers ({fit.n_outliers})')
    for d in sorted({float(v) for v in np.unique(fit.direction)}, reverse=True):
        sel = I_arr[fit.direction == d]  # each direction's line over its own current range (and through 0 A)
        grid = np.linspace(min(0.0, float(sel.min())), max(0.0, float(sel.max())), 200)
        if data.speed_rad_s is None:
            label = f'fit: T = K_T I - T_0, K_T = {fit.K_T:.5g} +/- {fit.se_K_T:.2g} N*m/A'
        else:
            label = {1.0: 'fit, moving +: T = K_T I - T_0', -1.0: 'fit, moving -: T = K_T I + T_0',
                     0.0: 'fit, standstill: T = K_T I'}[d]
        ax.plot(grid, fit.K_T * grid - d * fit.T_0, '-', lw=1.6, label=label)
    ax.set_ylabel('reference torque [N*m]')
    ax.set_title(title or 'K_T calibration (paper Eq. 23)')
    ax.grid(True, alpha=0.4)
    ax.legend(fontsize=8)
    sigma_band = OUTLIER_THRESHOLD * fit.residual_std * 1e3
    axr.axhline(0.0, color='k', lw=0.8)
    axr.axhspan(-sigma_band, sigma_band, color='C0', alpha=0.12, label=f'+/- {OUTLIER_THRESHOLD:g} x residual std')
    axr.plot(I_arr[inl], fit.residuals[inl] * 1e3, '.', color='C0')
    if fit.n_outliers:
        # keep the inlier scatter readable: outliers beyond the axis are drawn at its edge
        span = max(4.0 * float(np.max(np.abs(fit.residuals[inl]))) * 1e3, 1.5 * sigma_band)
        r_out = np.clip(fit.residuals[~inl] * 1e3, -0.95 * span, 0.95 * span)
        axr.plot(I_arr[~inl], r_out, 'x', color='C3', ms=7, label='outliers (clipped to the axis)')
        axr.set_ylim(-span, span)
    axr.set_xlabel('motor current I [A]')
    axr.set_ylabel('residual [mN*m]')
    axr.grid(True, alpha=0.4)
    axr.legend(fontsize=8, loc='upper right')
    fig.tight_layout()
    from gimbal_friction.plots.figures import save_figure
    return save_figure(fig, path)


def _record(fit: KtFit, axis: str, args: argparse.Namespace, data: CalibrationData) -> dict[str, Any]:
    return {
        'axis': axis,
        'input': str(args.input),
        'input_kind': data.kind,
        'out': str(args.out),
        'plot': None if args.plot is None else str(args.plot),
        'torque_constant_nm_per_a': fit.K_T,
        'torque_constant_se_nm_per_a': fit.se_K_T,
        'no_load_current_a': fit.I_0,
        'no_load_current_se_a': fit.se_I_0,
        'no_load_torque_nm': fit.T_0,
        'no_load_torque_se_nm': fit.se_T_0,
        'r2': fit.r2,
        'residual_std_nm': fit.residual_std,
        'n': fit.n,
        'n_inliers': fit.n_inliers,
        'n_outliers': fit.n_outliers,
        'outlier_threshold_sigma': OUTLIER_THRESHOLD,
        'outlier_rows': [data.rows[i] for i in np.flatnonzero(~fit.inliers)],
        'direction': 'speed_rad_s' if data.speed_rad_s is not None else 'positive',
    }


# ---------------------------------------------------------------------------------------------- command
def run(args: argparse.Namespace) -> int:
    cfg = load_parameters(args.config)
    names = axis_names(cfg)
    axis = args.axis or names[0]
    base = axis_params(cfg, axis)  # refuses an axis that is not configured
    source: Path = args.input
    out: Path = args.out
    if out.exists() and out.resolve() == source.resolve():
        msg = f'--out {out} is the input file; choose another name'
        raise GimbalFrictionError(msg)
    refuse_existing(out, '--out', force=args.force)  # the one rule of every command's outputs
    if args.plot is not None:
        refuse_existing(args.plot, '--plot', force=args.force)
    cal = calibrate(source, axis, base, args.max_dt)
    fit, data, values = cal.fit, cal.data, cal.values
    if args.plot is not None:
        plot_fit(fit, data, args.plot, title=f'{axis}: K_T calibration (paper Eq. 23), {source.name}')
    text = render_parameter_file(axes_overrides={axis: values},
                                 header=provenance_header(fit, axis, source, data))
    text += '\n' + calibration_section_text(calibration_record(cal))
    write_text_atomic(out, text)

    if args.format == 'json':
        print_json(_record(fit, axis, args, data))
        print(f'wrote {out}' + ('' if args.plot is None else f', plot: {args.plot}'), file=sys.stderr)
        return 0
    direction = 'sign of speed_rad_s' if data.speed_rad_s is not None else 'assumed positive (no speed column)'
    print(f'axis {axis}: K_T and no-load offset (paper Eq. 23) from {fit.n} points of {source}')
    print(f'robust fit: {fit.n_outliers} outlier(s) rejected (|residual| > {OUTLIER_THRESHOLD:g} robust sigma); '
          f'direction: {direction}')
    rows = [
        ['K_T', f'{fit.K_T:.6g}', f'{fit.se_K_T:.2g}', 'N*m/A'],
        ['I_0', f'{fit.I_0:.6g}', f'{fit.se_I_0:.2g}', 'A'],
        ['T_0', f'{fit.T_0:.6g}', f'{fit.se_T_0:.2g}', 'N*m'],
        ['R^2', f'{fit.r2:.6f}', '', '-'],
        ['residual std', f'{fit.residual_std:.3g}', '', 'N*m'],
        ['points used', f'{fit.n_inliers} of {fit.n}', '', '-'],
    ]
    print(format_table(rows, ['quantity', 'value', 'std. error', 'unit']))
    print(f'wrote {out} (axis.{axis}.torque_constant_nm_per_a, axis.{axis}.no_load_current_a)')
    if args.plot is not None:
        print(f'plot: {args.plot}')
    return 0
