"""A refit result's records as JSON-ready mappings (torques in N*mm), shared by ``refit`` and ``fleet``: one form;
and the refit's calibration offsets as data in its parameter file (:func:`refit_section_text`,
:func:`read_refit_offsets`).

The offset is no model parameter (the nodes must not add it: it is the measurement's error, not the friction's), so
the refit's file carries it beside the parameters in a section ``gimbal_friction_refit: ros__parameters:
{format_version: 1, axis: {<joint>: {torque_offset_nm, torque_offset_se_nm, torque_offset_estimated}}}``: to ROS
the parameters of a node of that name, which does not exist, so the nodes, the config loader and ``--params-file``
ignore it and the file stays layerable. ``report --compare`` reads it to draw the refit model of the measurement as
the refit's own table shows it.

>>> text = refit_section_text({'elevation': (-4.8e-06, 1.1e-05, True)})
>>> print(text.strip())
gimbal_friction_refit:
  ros__parameters:
    format_version: 1
    axis:
      elevation:
        torque_offset_nm: -4.8e-06
        torque_offset_se_nm: 1.1e-05
        torque_offset_estimated: true
>>> read_refit_offsets_text(text, 'refit.yaml')
{'elevation': -4.8e-06}
>>> read_refit_offsets_text('/**: {ros__parameters: {}}', 'mine.yaml')     # a file without the section: none
{}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from gimbal_friction.common.errors import ConfigFileError
from gimbal_friction.refit.fit import RefitResult
from gimbal_friction.refit.fit_check import BinCheck, FitCheck, direction_name

#: the section of refit's parameter file that carries the fitted calibration offsets as data, and its version
REFIT_SECTION = 'gimbal_friction_refit'
REFIT_FORMAT_VERSION = 1


def offset_record(r: RefitResult) -> dict[str, Any]:
    """The calibration offset of a refit as JSON (torques in N*mm)."""
    o = r.offset
    return {'mode': o.mode, 'estimated': o.estimated, 'reason': o.reason, 'value_nmm': 1e3 * o.value_nm,
            'standard_error_nmm': 1e3 * o.standard_error_nm,
            'ci95_nmm': [1e3 * o.confidence_interval_nm[0], 1e3 * o.confidence_interval_nm[1]],
            'calibration_se_nmm': 1e3 * o.calibration_se_nm, 'exceeds_calibration': o.exceeds_calibration,
            'torque_constant_nm_per_a': o.torque_constant_nm_per_a, 'no_load_current_a': o.no_load_current_a,
            'implied_no_load_current_a': o.implied_no_load_current_a}


def confounding_record(r: RefitResult) -> dict[str, Any]:
    """How far a calibration offset the fit set could not separate moves the result, as JSON (torque in N*mm;
    ``checked`` false: the offset was fitted, switched off, or the data could not have determined it)."""
    c = r.offset_confounding
    return {'checked': c.checked, 'confounded': list(c.confounded),
            'reference_offset_nmm': 1e3 * c.reference_offset_nm, 'reference': c.reference,
            'shifts': dict(c.shifts), 'shifts_in_standard_errors': dict(c.shifts_in_se),
            'viscosity_shift_percent': [{'temperature_c': t, 'percent': 100.0 * x} for t, x in c.viscosity_shift_rel]}


def bin_check_record(b: BinCheck) -> dict[str, Any]:
    """One bin of a lack-of-fit check as JSON (torques in N*mm)."""
    return {'temperature_c': b.temperature_c, 'temperature_bin_c': b.temperature_bin_c,
            'direction': direction_name(b.direction).lower(), 'speed_rpm': b.speed_rpm, 'samples': b.n,
            'measured_mean_nmm': 1e3 * b.measured_mean_nm, 'model_nmm': 1e3 * b.model_nm,
            'residual_nmm': 1e3 * b.residual_nm, 'standard_error_nmm': 1e3 * b.standard_error_nm, 'z': b.z}


def fit_check_record(c: FitCheck) -> dict[str, Any]:
    """A lack-of-fit check as JSON: whether the model fits, the |z| allowed, chi2 and its dof, the bins that do not
    fit (largest |z| first), what they have in common and what to try."""
    return {'checked': c.checked, 'fits': c.fits, 'z_critical': c.z_critical, 'chi2': c.chi2, 'dof': c.dof,
            'bins_checked': len(c.bins), 'max_abs_z': abs(c.worst.z) if c.worst is not None else None,
            'bins_not_fitting': [bin_check_record(b) for b in c.misfits], 'pattern': c.pattern,
            'advice': list(c.advice)}


def refit_record(r: RefitResult) -> dict[str, Any]:
    """The one JSON form of a refit result (torques in N*mm): ``refit --json`` per axis (after the rows read)
    and each axis of ``fleet.json`` (which adds its population fields, :func:`fleet_record`)."""
    z = {(b.temperature_bin_c, b.direction, round(b.speed_rpm, 9)): b.z for b in r.fit_check.bins}
    bad = {(b.temperature_bin_c, b.direction, round(b.speed_rpm, 9)) for b in r.fit_check.misfits}
    return {
        'direction': r.direction,
        'fit_check': fit_check_record(r.fit_check),
        'intervals_are_confidence_intervals': r.intervals_are_confidence_intervals,
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
            'friction_after_nmm': 1e3 * b.friction_after_nm,
            'z_after': z.get((b.temperature_bin_c, b.direction, round(b.speed_rpm, 9))),
            'fits': (b.temperature_bin_c, b.direction, round(b.speed_rpm, 9)) not in bad if b.used else None,
        } for b in r.bins],
        'cost': r.cost,
        'message': r.message,
        'fine_bins': r.n_bins,
        'offset': offset_record(r),
        'offset_confounding': confounding_record(r),
        'warnings': list(r.warnings),
    }


def fleet_record(r: RefitResult, viscosity_m40_cst: float, friction_nmm: dict[str, float]) -> dict[str, Any]:
    """:func:`refit_record` with the fields the fleet's population uses (viscosity at -40 degC [cSt], total
    friction at report temperatures [N*mm]) and the short names ``fleet.json`` has always had (``ci95``,
    ``identifiable``, ``reasons``, ``offset.se_nmm``)."""
    out = refit_record(r)
    out['ci95'] = out['confidence_intervals_95']
    out['identifiable'] = {k: v.identifiable for k, v in r.identifiability.items()}
    out['reasons'] = {k: v.reason for k, v in r.identifiability.items() if not v.identifiable}
    out['viscosity_m40_cst'] = viscosity_m40_cst
    out['friction_nmm'] = friction_nmm
    out['offset']['se_nmm'] = out['offset']['standard_error_nmm']
    return out


# ------------------------------------------------------------------------------------------------------------
# the offsets as data in the parameter file


def offset_values(r: RefitResult) -> tuple[float, float, bool]:
    """The calibration offset of a refit as the section holds it: value and 1-sigma [N*m] (0 and NaN when it was not
    estimated: the model of the measurement is then the friction alone) and whether it was estimated."""
    o = r.offset
    if not o.estimated:
        return 0.0, math.nan, False
    return float(o.value_nm), float(o.standard_error_nm), True


def _bin_text(b: BinCheck) -> str:
    rel = b.residual_nm / b.model_nm if b.model_nm else math.nan
    return (f'{b.temperature_c:.1f} degC {direction_name(b.direction)}: measured {100 * rel:+.1f} % off the model '
            f'(z {b.z:+.1f})')


def validity_values(r: RefitResult, held_out: FitCheck | None = None) -> dict[str, Any]:
    """What a refit's file is good for, as the section holds it: the directions fitted ('both', 'cw', 'ccw'),
    whether the model fits every bin (its intervals are then 95 % confidence intervals), the largest |z| and the
    bins that do not fit ('<t> degC <dir> <measured vs model> % (z <z>)'); with ``held_out`` (the check of a
    one-direction refit against the other direction) whether that direction fits too and its worst bin."""
    c = r.fit_check
    out: dict[str, Any] = {'fitted_directions': r.direction, 'model_fits': bool(c.checked and c.fits)}
    if c.worst is not None:
        out['max_abs_z'] = float(f'{abs(c.worst.z):.4g}')
    if c.misfits:
        out['bins_not_fitting'] = [_bin_text(b) for b in c.misfits]
    if held_out is not None and held_out.checked:
        out['other_direction_fits'] = bool(held_out.fits)
        if held_out.misfits:
            worst_rel = max(held_out.misfits, key=lambda b: abs(b.residual_nm / b.model_nm) if b.model_nm else 0.0)
            out['other_direction_worst'] = _bin_text(worst_rel)
    return out


def validity_text(v: Mapping[str, Any]) -> str:
    """What a refitted file is good for, in words, from its section's values (:func:`validity_values`; '' for a
    file without them).

    >>> print(validity_text({'fitted_directions': 'cw', 'model_fits': True, 'other_direction_fits': False,
    ...                      'other_direction_worst': '-39.6 degC CCW: measured -22.5 % off the model (z -38.2)'}))
    fitted on CW samples only: good for CW motion; NOT for CCW (the logs' CCW samples do not fit it:
    -39.6 degC CCW: measured -22.5 % off the model (z -38.2))
    >>> print(validity_text({'fitted_directions': 'both', 'model_fits': False, 'bins_not_fitting': ['-20.3 degC']}))
    fitted on both directions, but its model does NOT fit 1 bin(s) (-20.3 degC): its intervals are not
    confidence intervals
    """
    if not v:
        return ''
    side = str(v.get('fitted_directions', 'both'))
    fits = bool(v.get('model_fits', True))
    text = 'fitted on both directions' if side == 'both' else \
        f'fitted on {side.upper()} samples only: good for {side.upper()} motion'
    if not fits:
        bad = list(v.get('bins_not_fitting') or [])
        text += (f', but its model does NOT fit {len(bad)} bin(s) ({"; ".join(bad[:2])}'
                 f'{"; ..." if len(bad) > 2 else ""}): its intervals are not confidence intervals')
    if side != 'both' and v.get('other_direction_fits') is False:
        other = 'CCW' if side == 'cw' else 'CW'
        text += f"; NOT for {other} (the logs' {other} samples do not fit it: {v.get('other_direction_worst', '')})"
    elif side != 'both' and v.get('other_direction_fits') is True:
        text += ' (the other direction of the logs fits it too)'
    return text


def refit_section_text(offsets: Mapping[str, tuple[float, float, bool]],
                       validity: Mapping[str, Mapping[str, Any]] | None = None) -> str:
    """The ``gimbal_friction_refit`` section as YAML: per axis the offset, its 1-sigma [N*m] (left out when not
    finite) and whether it was estimated (:func:`offset_values`), and what the file is good for
    (:func:`validity_values`, when given); floats written with a decimal point or an exponent, so that rcl reads
    them as doubles."""
    axes: dict[str, dict[str, Any]] = {}
    for axis, (value, se, estimated) in offsets.items():
        rec: dict[str, Any] = {'torque_offset_nm': float(repr(float(value)))}
        if math.isfinite(se):
            rec['torque_offset_se_nm'] = float(repr(float(se)))
        rec['torque_offset_estimated'] = bool(estimated)
        rec.update((validity or {}).get(axis, {}))
        axes[axis] = rec
    body = {REFIT_SECTION: {'ros__parameters': {'format_version': REFIT_FORMAT_VERSION, 'axis': axes}}}
    text: str = yaml.safe_dump(body, sort_keys=False, default_flow_style=False)
    return text


def _read(path: str | Path) -> str:
    try:
        return Path(path).read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigFileError(str(path), f'cannot read: {getattr(err, "strerror", None) or err}') from None


def read_refit_offsets(path: str | Path) -> dict[str, float]:
    """:func:`read_refit_offsets_text` of a file.

    Raises:
        ConfigFileError: the file cannot be read, or its section is malformed or of another format version.
    """
    return read_refit_offsets_text(_read(path), str(path))


def read_refit_validity(path: str | Path) -> dict[str, dict[str, Any]]:
    """What a refit's file says it is good for, per axis (:func:`validity_values`: ``fitted_directions``,
    ``model_fits``, ``bins_not_fitting``); empty for a file without them (not a refit's, or an older one). Call
    :func:`read_refit_offsets` first to refuse a malformed section.

    >>> import tempfile
    >>> text = refit_section_text({'elevation': (0.0, math.nan, False)},
    ...                           {'elevation': {'fitted_directions': 'cw', 'model_fits': True}})
    >>> with tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False) as f:
    ...     _ = f.write(text)
    >>> read_refit_validity(f.name)
    {'elevation': {'fitted_directions': 'cw', 'model_fits': True}}
    """
    try:
        doc = yaml.safe_load(_read(path))
    except yaml.YAMLError:
        return {}
    section = doc.get(REFIT_SECTION) if isinstance(doc, dict) else None
    params = section.get('ros__parameters') if isinstance(section, dict) else None
    axes = params.get('axis') if isinstance(params, dict) else None
    out: dict[str, dict[str, Any]] = {}
    for axis, rec in (axes.items() if isinstance(axes, dict) else ()):
        if isinstance(rec, dict):
            keep = {k: rec[k] for k in ('fitted_directions', 'model_fits', 'bins_not_fitting', 'other_direction_fits',
                                        'other_direction_worst') if k in rec}
            if keep:
                out[str(axis)] = keep
    return out


def read_refit_offsets_text(text: str, source: str) -> dict[str, float]:
    """The calibration torque offset [N*m] per axis that a refit wrote into its parameter file (0 for an axis whose
    offset was not estimated); empty for a file without the ``gimbal_friction_refit`` section (not a refit's, or
    written before the section: its offsets are unknown).

    Raises:
        ConfigFileError: a malformed section, an unknown format version or a value that is not a finite number.
    """
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return {}   # not YAML: the config loader refuses the file with its own reason
    section = doc.get(REFIT_SECTION) if isinstance(doc, dict) else None
    if section is None:
        return {}
    params = section.get('ros__parameters') if isinstance(section, dict) else None
    if not isinstance(params, dict):
        raise ConfigFileError(source, f'{REFIT_SECTION} must hold a ros__parameters mapping')
    version = params.get('format_version')
    if version != REFIT_FORMAT_VERSION:
        raise ConfigFileError(source, f'{REFIT_SECTION} format_version {version!r} is not supported (this version '
                              f'reads {REFIT_FORMAT_VERSION}); rerun refit or upgrade gimbal_friction')
    axes = params.get('axis') or {}
    if not isinstance(axes, dict):
        raise ConfigFileError(source, f'{REFIT_SECTION}.axis must map joints to their offsets')
    out: dict[str, float] = {}
    for axis, rec in axes.items():
        value = rec.get('torque_offset_nm') if isinstance(rec, dict) else None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigFileError(source, f'{REFIT_SECTION}.axis.{axis}.torque_offset_nm must be a finite torque '
                                  f'[N*m], not {value!r}')
        out[str(axis)] = float(value) if rec.get('torque_offset_estimated', True) is not False else 0.0
    return out
