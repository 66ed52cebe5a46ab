"""``gimbal-friction calibrate-kt``: fit K_T and the no-load offset I_0 (paper Eq. 23) from calibration data.

Input is a CSV file with a header row and columns ``current_a`` [A], ``torque_nm`` [N*m] and optionally
``speed_rad_s`` [rad/s] (lines starting with ``#`` are comments), or a rosbag2 bag (directory or ``.mcap`` file)
with the topics ``/gimbal/calibration/current`` and ``/gimbal/calibration/torque`` (``sensor_msgs/msg/JointState``
effort of the axis joint, or ``std_msgs/msg/Float64``), paired by nearest stamp. The fit is
:func:`gimbal_friction.estimation.kt.fit_kt`. The output is a layerable parameter file holding
``axis.<NAME>.torque_constant_nm_per_a`` and ``axis.<NAME>.no_load_current_a``, written only when the fit is
accepted (atomically, so a refused or failed run leaves an existing file untouched).
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import hashlib
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.cli._common import add_common, format_table, print_json, refuse_existing, write_text_atomic
from gimbal_friction.common.errors import ConfigError, FitError, GimbalFrictionError
from gimbal_friction.config.loader import axis_names, axis_params, load_parameters, render_parameter_file
from gimbal_friction.estimation.kt import OUTLIER_THRESHOLD, KtFit, fit_kt
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.streams.inputs import index_joints

CURRENT_COLUMN = 'current_a'
TORQUE_COLUMN = 'torque_nm'
SPEED_COLUMN = 'speed_rad_s'
REQUIRED_COLUMNS = (CURRENT_COLUMN, TORQUE_COLUMN)

#: bag topics of a calibration run
CURRENT_TOPIC = '/gimbal/calibration/current'
TORQUE_TOPIC = '/gimbal/calibration/torque'
JOINT_STATE_TYPE = 'sensor_msgs/msg/JointState'
FLOAT64_TYPE = 'std_msgs/msg/Float64'
#: largest stamp difference of a (torque, current) pair read from a bag [s]
DEFAULT_MAX_DT_S = 0.05


class CalibrationData(NamedTuple):
    """Calibration points read from a file: current [A], torque [N*m], optional speed [rad/s], provenance."""

    current_a: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    speed_rad_s: NDArray[np.float64] | None
    rows: list[int]          # CSV line number (or 1-based pair index for a bag) of every point
    kind: str                # 'csv' or 'bag'


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


# ---------------------------------------------------------------------------------------------- reading input
def _is_bag(path: Path) -> bool:
    return path.is_dir() or path.suffix in ('.mcap', '.db3')


def read_csv(path: Path) -> CalibrationData:
    """Read a calibration CSV (header row; ``#`` comment lines and blank lines skipped).

    Raises:
        FitError: unreadable file, missing column (named), or a non-numeric cell (row and column named).
    """
    try:
        with path.open(newline='', encoding='utf-8-sig') as f:
            return _parse_csv(path, csv.reader(f))
    except OSError as err:
        msg = f'{path}: cannot read: {err.strerror}'
        raise FitError(msg) from None
    except (csv.Error, UnicodeDecodeError) as err:
        msg = f'{path}: not a readable CSV file: {err}'
        raise FitError(msg) from None


def _parse_csv(path: Path, reader: Any) -> CalibrationData:
    header: list[str] | None = None
    for row in reader:
        if row and not row[0].lstrip().startswith('#') and any(c.strip() for c in row):
            header = [c.strip() for c in row]
            break
    if header is None:
        msg = f'{path}: empty file: expected a header row {",".join(REQUIRED_COLUMNS)}'
        raise FitError(msg)
    for col in REQUIRED_COLUMNS:
        if col not in header:
            msg = f'{path}: missing column {col!r} (header: {", ".join(header)})'
            raise FitError(msg)
    wanted = [c for c in (*REQUIRED_COLUMNS, SPEED_COLUMN) if c in header]
    for col in wanted:
        if header.count(col) > 1:
            msg = f'{path}: column {col!r} appears more than once in the header'
            raise FitError(msg)
    index = {c: header.index(c) for c in wanted}
    values: dict[str, list[float]] = {c: [] for c in wanted}
    lines: list[int] = []
    data_row = 0
    for row in reader:
        if not row or not any(c.strip() for c in row) or row[0].lstrip().startswith('#'):
            continue
        data_row += 1
        where = f'{path}: row {data_row} (line {reader.line_num})'
        for col, i in index.items():
            if i >= len(row) or not row[i].strip():
                msg = f'{where}, column {col!r}: empty cell'
                raise FitError(msg)
            cell = row[i].strip()
            try:
                values[col].append(float(cell))
            except ValueError:
                msg = f'{where}, column {col!r}: {cell!r} is not a number'
                raise FitError(msg) from None
        lines.append(reader.line_num)
    speed = np.asarray(values[SPEED_COLUMN]) if SPEED_COLUMN in values else None
    return CalibrationData(np.asarray(values[CURRENT_COLUMN]), np.asarray(values[TORQUE_COLUMN]), speed, lines,
                           'csv')


def read_bag(path: Path, axis: str, max_dt_s: float = DEFAULT_MAX_DT_S) -> CalibrationData:
    """Read calibration pairs from a bag: each torque sample with the nearest current sample within ``max_dt_s``.

    Stamps are the header stamps when both topics are ``JointState``, else the log times. Speed is the
    ``velocity`` of the current ``JointState`` when every paired sample has one.

    Raises:
        FitError: unreadable bag, missing topic, unsupported message type, or no pairs.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    series: dict[str, tuple[list[float], list[float], list[float], list[float]]] = {}
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            conns = {c.topic: c for c in reader.connections}
            missing = [t for t in (CURRENT_TOPIC, TORQUE_TOPIC) if t not in conns]
            if missing:
                msg = (f'{path}: bag has no topic {", ".join(missing)} (topics: '
                       f'{", ".join(sorted(conns)) or "none"})')
                raise FitError(msg)
            for topic in (CURRENT_TOPIC, TORQUE_TOPIC):
                if conns[topic].msgtype not in (JOINT_STATE_TYPE, FLOAT64_TYPE):
                    msg = (f'{path}: topic {topic} has type {conns[topic].msgtype}, expected {JOINT_STATE_TYPE} '
                           f'or {FLOAT64_TYPE}')
                    raise FitError(msg)
                series[topic] = ([], [], [], [])
            for conn, log_ns, raw in reader.messages(connections=[conns[CURRENT_TOPIC], conns[TORQUE_TOPIC]]):
                msg_obj = reader.deserialize(raw, conn.msgtype)
                _append_sample(series[conn.topic], msg_obj, conn.msgtype, axis, log_ns)
            header_stamps = all(conns[t].msgtype == JOINT_STATE_TYPE for t in (CURRENT_TOPIC, TORQUE_TOPIC))
    except FitError:
        raise
    except Exception as err:  # rosbags raises several unrelated types (AnyReaderError, ReaderError, OSError)
        msg = f'{path}: cannot read bag: {err}'
        raise FitError(msg) from None
    c_stamp, c_log, c_val, c_vel = (np.asarray(v) for v in series[CURRENT_TOPIC])
    t_stamp, t_log, t_val, _ = (np.asarray(v) for v in series[TORQUE_TOPIC])
    if c_val.size == 0 or t_val.size == 0:
        msg = f'{path}: no samples for joint {axis!r} on {CURRENT_TOPIC} and {TORQUE_TOPIC}'
        raise FitError(msg)
    ct, tt = (c_stamp, t_stamp) if header_stamps else (c_log, t_log)
    order = np.argsort(ct, kind='stable')
    ct, c_val, c_vel = ct[order], c_val[order], c_vel[order]
    j = np.clip(np.searchsorted(ct, tt), 1, max(ct.size - 1, 1))
    left = np.clip(j - 1, 0, ct.size - 1)
    right = np.clip(j, 0, ct.size - 1)
    nearest = np.where(np.abs(ct[left] - tt) <= np.abs(ct[right] - tt), left, right)
    ok = np.abs(ct[nearest] - tt) <= max_dt_s
    if not ok.any():
        msg = f'{path}: no torque sample has a current sample within {max_dt_s:g} s'
        raise FitError(msg)
    idx = nearest[ok]
    vel = c_vel[idx]
    speed = vel if np.all(np.isfinite(vel)) else None
    return CalibrationData(c_val[idx], t_val[ok], speed, list(range(1, int(ok.sum()) + 1)), 'bag')


def _append_sample(store: tuple[list[float], list[float], list[float], list[float]], msg: Any, msgtype: str,
                   axis: str, log_ns: int) -> None:
    stamps, logs, values, vels = store
    if msgtype == FLOAT64_TYPE:
        stamps.append(log_ns * 1e-9)
        logs.append(log_ns * 1e-9)
        values.append(float(msg.data))
        vels.append(float('nan'))
        return
    i = index_joints(list(msg.name), (), (axis,)).position.get(axis)
    if i is None:
        if len(msg.effort) != 1:
            return
        i = 0   # a one-joint current message under another name
    if i >= len(msg.effort):
        return
    stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
    logs.append(log_ns * 1e-9)
    values.append(float(msg.effort[i]))
    vels.append(float(msg.velocity[i]) if i < len(msg.velocity) else float('nan'))


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
    if not source.exists():
        msg = f'{source}: no such file or bag'
        raise FitError(msg)
    if out.exists() and out.resolve() == source.resolve():
        msg = f'--out {out} is the input file; choose another name'
        raise GimbalFrictionError(msg)
    refuse_existing(out, '--out', force=args.force)  # the one rule of every command's outputs
    if args.plot is not None:
        refuse_existing(args.plot, '--plot', force=args.force)
    if args.max_dt <= 0.0:
        raise ConfigError('--max-dt', 'must be > 0 [s]', args.max_dt)
    data = read_bag(source, axis, args.max_dt) if _is_bag(source) else read_csv(source)
    try:
        fit = fit_kt(data.current_a, data.torque_nm, data.speed_rad_s)
    except FitError as err:
        msg = f'{source}: {err}'
        raise FitError(msg) from None
    values = {'torque_constant_nm_per_a': fit.K_T, 'no_load_current_a': fit.I_0}
    try:
        AxisParams.from_mapping(values, base=base)
    except ConfigError as err:
        msg = f'{source}: fitted value outside the allowed range: {err}'
        raise FitError(msg) from None
    if args.plot is not None:
        plot_fit(fit, data, args.plot, title=f"{axis}: K_T calibration (paper Eq. 23), {source.name}")
    text = render_parameter_file(axes_overrides={axis: values},
                                 header=provenance_header(fit, axis, source, data))
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
