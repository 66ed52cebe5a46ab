"""``refit``'s run as a library function: read residual logs, choose the axes, check the calibration input, refit
each axis (:func:`refit_logs`). The command (``gimbal_friction.cli.refit_cmd``) parses the options, calls this,
writes the parameter file and prints; the configuration comes in as the configured axis names and a function that
gives an axis' base parameters (the config loader sits above this package).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from gimbal_friction.common.errors import ConfigError, FitError
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.calibration import read_calibration
from gimbal_friction.recording.residual_read import ReadReport
from gimbal_friction.recording.topics import RESIDUAL_DETAIL
from gimbal_friction.refit.fit import FitCheck, RefitResult, check_model, refit_stats
from gimbal_friction.refit.fit_check import FIT_NOT_CHECKED
from gimbal_friction.refit.logs import AxisData, read_stats
from gimbal_friction.refit.results import ASYMMETRY_PARAMETERS, FIT_PARAMETERS
from gimbal_friction.refit.sufficient import SufficientStats
from gimbal_friction.streams.inputs import unconfigured_joints


class Alternative(NamedTuple):
    """Another fit tried on the same data when the requested one does not fit: its options, and its result or why
    it was refused."""

    options: str                  #: what to pass instead, e.g. '--direction cw'
    fit: tuple[str, ...]
    direction: str
    result: RefitResult | None
    error: str = ''


class AxisRefit(NamedTuple):
    """One axis refitted: its name, base parameters, what the logs held for it, and the result; the check of the
    refitted model against the direction a one-direction refit left out, and the alternatives tried when the
    model does not fit."""

    axis: str
    base: AxisParams
    data: AxisData
    result: RefitResult
    held_out: FitCheck = FIT_NOT_CHECKED
    alternatives: tuple[Alternative, ...] = ()


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
               on_read: Callable[[ReadReport], None] | None = None, try_alternatives: bool = True) -> LogsRefit:
    """Refit each axis of the residual ``logs`` (:func:`~gimbal_friction.refit.fit.refit_stats`): the axes are
    ``axes`` or every configured one present; ``base_of(axis)`` gives its base parameters. A bad calibration
    input is refused before the logs are read; ``on_read`` sees the read report before the fits. Every result
    carries its lack-of-fit check; a one-direction refit is also checked against the other direction of the logs
    (:attr:`AxisRefit.held_out`), and a refit whose model does not fit tries the others of :func:`alternatives`
    (``try_alternatives``).

    Raises:
        ConfigError: a bad option value or calibration file; FitError: no samples, or a refused fit (the axis named).
    """
    if not (math.isfinite(bin_width_c) and bin_width_c > 0.0):
        raise ConfigError('--bin-width', 'must be > 0 [degC]', bin_width_c)
    if calibration is not None:
        read_calibration(calibration)  # refuse a bad file before reading the logs
    report = ReadReport()
    data_by_joint = read_stats(list(logs), direction=direction, report=report, held_out=direction != 'both')
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
        result = result._replace(direction=direction)
        held_out = FIT_NOT_CHECKED
        if data.held_out is not None:
            held_out = check_model(result.params, data.held_out, bin_width_c=bin_width_c,
                                   offset_nm=result.offset.value_nm if result.offset.estimated else 0.0)
        tried: tuple[Alternative, ...] = ()
        if try_alternatives and result.fit_check.checked and not result.fit_check.fits:
            tried = alternatives(base, data.stats, result, fit, direction, loss=loss, bin_width_c=bin_width_c,
                                 offset=offset, calibration_se_nm=cal_se[axis])
        fits.append(AxisRefit(axis, base, data, result, held_out, tried))
    return LogsRefit(fits, report, ignored, notes)


def alternatives(base: AxisParams, stats: SufficientStats, result: RefitResult, fit: tuple[str, ...],
                 direction: str, **options: Any) -> tuple[Alternative, ...]:  # noqa: ANN401 (refit_stats' options)
    """Other fits of the same statistics, tried when ``result`` (of ``fit`` on ``direction``) does not fit: each
    direction alone (when both were fitted), the direction asymmetry added (both directions in the data), the
    viscosity-temperature slope added (two cold plateaus). ``options`` are those of
    :func:`~gimbal_friction.refit.fit.refit_stats`."""
    signs = sorted({b.direction for b in result.bins if b.used})
    candidates: list[tuple[str, tuple[str, ...], str]] = []
    if direction == 'both' and len(signs) == 2:
        candidates += [('--direction cw', fit, 'cw'), ('--direction ccw', fit, 'ccw')]
        if not set(ASYMMETRY_PARAMETERS) <= set(fit):
            more = tuple(name for name in FIT_PARAMETERS if name in fit or name in ASYMMETRY_PARAMETERS)
            candidates.append((f'--fit {",".join(_short(more))}', more, 'both'))
    if len(result.viscous_temperatures_c) >= 2 and 'walther_b' not in fit and 'walther_a' in fit:
        more = tuple(name for name in FIT_PARAMETERS if name in fit or name == 'walther_b')
        label = f'--fit {",".join(_short(more))}' + (f' --direction {direction}' if direction != 'both' else '')
        candidates.append((label, more, direction))
    out = []
    for label, names, side in candidates:
        data = stats if side == 'both' else stats.only_direction(1 if side == 'cw' else -1)
        try:
            res = refit_stats(base, data, fit=names, **options)._replace(direction=side)
        except FitError as err:
            out.append(Alternative(label, names, side, None, str(err)))
            continue
        out.append(Alternative(label, names, side, res))
    return tuple(out)


def _short(names: Sequence[str]) -> list[str]:
    """Fit names with both asymmetry anchors written as their shorthand ``direction_asymmetry``."""
    if set(ASYMMETRY_PARAMETERS) <= set(names):
        return [n for n in names if n not in ASYMMETRY_PARAMETERS] + ['direction_asymmetry']
    return list(names)
