"""A refit result's records as JSON-ready mappings (torques in N*mm), shared by ``refit`` and ``fleet``."""

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
