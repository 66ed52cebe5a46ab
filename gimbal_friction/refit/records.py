"""A refit result's records as JSON-ready mappings (torques in N*mm), shared by ``refit`` and ``fleet``: one form."""

from __future__ import annotations

from typing import Any

from gimbal_friction.refit.fit import RefitResult


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


def refit_record(r: RefitResult) -> dict[str, Any]:
    """The one JSON form of a refit result (torques in N*mm): ``refit --json`` per axis (after the rows read)
    and each axis of ``fleet.json`` (which adds its population fields, :func:`fleet_record`)."""
    return {
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
