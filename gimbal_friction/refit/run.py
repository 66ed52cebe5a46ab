"""``refit``'s run as a library function: read residual logs, choose the axes, check the calibration input, refit
each axis (:func:`refit_logs`). The command (``gimbal_friction.cli.refit_cmd``) parses the options, calls this,
writes the parameter file and prints; the configuration comes in as the configured axis names and a function that
gives an axis' base parameters (the config loader sits above this package).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

from gimbal_friction.common.errors import ConfigError, FitError
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.calibration import read_calibration
from gimbal_friction.recording.residual_read import ReadReport
from gimbal_friction.recording.topics import RESIDUAL_DETAIL
from gimbal_friction.refit.fit import RefitResult, refit_stats
from gimbal_friction.refit.logs import AxisData, read_stats
from gimbal_friction.streams.inputs import unconfigured_joints


class AxisRefit(NamedTuple):
    """One axis refitted: its name, base parameters, what the logs held for it, and the result."""

    axis: str
    base: AxisParams
    data: AxisData
    result: RefitResult


class LogsRefit(NamedTuple):
    """A refit of residual logs: each axis refitted, what the read skipped, the joints present but not configured,
    and the notes to show (an old calibration file read from its comments)."""

    fits: list[AxisRefit]
    report: ReadReport
    ignored: list[str]
    notes: list[str]


def select_axes(wanted: Sequence[str] | None, configured: Sequence[str], present: Sequence[str]
                ) -> tuple[list[str], list[str]]:
    """(axes to refit, joints present but not configured): ``wanted`` (each configured and in the logs), else
    every configured joint present. Raises ConfigError (not configured) or FitError (not in the logs)."""
    if wanted:
        for name in wanted:
            refused = unconfigured_joints([name], configured)
            if refused:
                raise ConfigError('axes', refused)
            if name not in present:
                msg = (f'no {RESIDUAL_DETAIL} samples for axis {name!r} in the logs (joints present: '
                       f'{", ".join(present) or "none"})')
                raise FitError(msg)
        return list(dict.fromkeys(wanted)), []
    axes = [name for name in present if name in configured]
    if not axes:
        msg = (f'the logs hold joints {", ".join(repr(p) for p in present)}, none of them configured '
               f'(axes: {", ".join(configured)}); pass --config with those axes')
        raise FitError(msg)
    return axes, [name for name in present if name not in configured]


def empty_reason(data: AxisData, direction: str) -> str:
    """Why an axis of the logs has no usable sample ('' if it has some): its rows, what was skipped, the filter."""
    if data.stats.n_samples > 0:
        return ''
    if data.rows == 0:
        return f'the logs hold no rows of it moving {direction.upper()} (--direction {direction})'
    return (f'all {data.rows} rows skipped ({data.skipped_nonfinite} with a non-finite temperature, velocity or '
            f'measurement, {data.skipped_standstill} at standstill)')


def calibration_se_by_axis(axes: Sequence[str], calibration_se: float | None, calibration: Path | None
                           ) -> tuple[dict[str, float | None], list[str]]:
    """The T_0 uncertainty [N*m] to compare each axis' offset with (from ``calibration_se`` [N*m] or the
    calibrate-kt file ``calibration``, :func:`~gimbal_friction.recording.calibration.read_calibration`) and the
    notes of the read."""
    out: dict[str, float | None] = dict.fromkeys(axes)
    notes: list[str] = []
    if calibration_se is not None:
        if not (math.isfinite(calibration_se) and calibration_se >= 0.0):
            raise ConfigError('--calibration-se', 'must be a finite torque >= 0 [N*m]', calibration_se)
        out = {axis: float(calibration_se) for axis in axes}
    if calibration is not None:
        if calibration_se is not None:
            raise ConfigError('--calibration', 'give --calibration or --calibration-se, not both', str(calibration))
        cal = read_calibration(calibration)
        notes += [cal.note] if cal.note else []
        for axis in axes:
            if cal.axis is None or cal.axis == axis:
                out[axis] = cal.no_load_torque_se_nm
    return out, notes


def refit_logs(logs: Sequence[Path], *, configured: Sequence[str], base_of: Callable[[str], AxisParams],
               fit: tuple[str, ...], axes: Sequence[str] | None = None, direction: str = 'both',
               loss: str = 'linear', bin_width_c: float = 5.0, offset: str = 'auto',
               calibration_se_nm: float | None = None, calibration: Path | None = None,
               on_read: Callable[[ReadReport], None] | None = None) -> LogsRefit:
    """Refit each axis of the residual ``logs`` (:func:`~gimbal_friction.refit.fit.refit_stats`): the axes are
    ``axes`` or every configured one present; ``base_of(axis)`` gives its base parameters. A bad calibration
    input is refused before the logs are read; ``on_read`` sees the read report before the fits.

    Raises:
        ConfigError: a bad option value or calibration file; FitError: no samples, or a refused fit (the axis named).
    """
    if not (math.isfinite(bin_width_c) and bin_width_c > 0.0):
        raise ConfigError('--bin-width', 'must be > 0 [degC]', bin_width_c)
    if calibration is not None:
        read_calibration(calibration)  # refuse a bad file before reading the logs
    report = ReadReport()
    data_by_joint = read_stats(list(logs), direction=direction, report=report)
    if on_read is not None:
        on_read(report)
    where = ', '.join(str(p) for p in logs)
    if not data_by_joint:
        msg = f'{where}: the residual log holds no {RESIDUAL_DETAIL} samples ({report.summary()})'
        raise FitError(msg)
    chosen, ignored = select_axes(axes, configured, sorted(data_by_joint))
    for axis in chosen:
        empty = empty_reason(data_by_joint[axis], direction)
        if empty:
            msg = f'{where}: no usable samples of axis {axis!r}: {empty}'
            raise FitError(msg)
    cal_se, notes = calibration_se_by_axis(chosen, calibration_se_nm, calibration)
    fits: list[AxisRefit] = []
    for axis in chosen:
        base = base_of(axis)
        data = data_by_joint[axis]
        try:
            result = refit_stats(base, data.stats, fit=fit, loss=loss, bin_width_c=bin_width_c, offset=offset,
                                 calibration_se_nm=cal_se[axis])
        except FitError as err:
            hint = ' (pass --axis to refit only the others)' if len(chosen) > 1 else ''
            msg = f'axis {axis}: {err}{hint}'
            raise FitError(msg) from None
        fits.append(AxisRefit(axis, base, data, result))
    return LogsRefit(fits, report, ignored, notes)
