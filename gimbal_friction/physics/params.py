"""Model parameters of one gimbal axis, with units, paper symbols, defaults and validation.

Every physical parameter of the model is a field of :class:`AxisParams`. The defaults reproduce Yu & Shang (2017)
with the values the paper leaves out chosen as in ``docs/model.md`` §7. Each field carries metadata
(unit, paper symbol, description, allowed range) that the ROS nodes turn into parameter descriptors and the
README into its parameter table.

>>> p = AxisParams()
>>> p.ball_diameter_mm, p.ball_count, round(p.pitch_diameter_mm, 3)
(2.381, 15, 21.5)
>>> AxisParams.from_mapping({'ball_diameter_mm': -1.0})
Traceback (most recent call last):
...
gimbal_friction.common.errors.ConfigError: parameter 'ball_diameter_mm' = -1.0: must be > 0 [mm]
>>> AxisParams.from_mapping({'ball_count': float('inf')})
Traceback (most recent call last):
...
gimbal_friction.common.errors.ConfigError: parameter 'ball_count' = inf: must be a finite number
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.settings import coerce
from gimbal_friction.common.text import did_you_mean

VISCOSITY_MODELS = ('walther_improved', 'walther')
HYSTERESIS_RADII = ('harris', 'half_ball')
#: Temperatures the model is defined for [°C] (every fit and table stays inside them).
MODEL_T_MIN_C, MODEL_T_MAX_C = -200.0, 400.0


class Bound(NamedTuple):
    """An allowed interval; ``None`` leaves a side open."""

    low: float | None = None
    high: float | None = None
    low_inclusive: bool = False
    high_inclusive: bool = True


def _p(default: Any, unit: str, symbol: str, description: str, bound: Bound | None = None,
       choices: tuple[str, ...] | None = None, group: str = '') -> Any:
    meta = {'unit': unit, 'symbol': symbol, 'description': description, 'bound': bound, 'choices': choices,
            'group': group}
    return field(default=default, metadata=meta)


_POS = Bound(0.0, None, False)
_NONNEG = Bound(0.0, None, True)


@dataclass(frozen=True)
class AxisParams:
    """All parameters of the friction model of one gimbal axis (two identical bearings by default).

    Units are in the field names where not obvious (``_mm``, ``_mpa``, ``_per_c``, ``_cst``). Values are those at
    the reference (assembly) temperature. See docs/model.md §1 and §7 for where every default comes from.
    """

    # Bearing geometry, Table 1 [paper]
    outside_diameter_mm: float = _p(26.0, 'mm', 'D_m', 'bearing outside diameter (Table 1)', _POS, group='bearing')
    bore_diameter_mm: float = _p(17.0, 'mm', 'd', 'bearing bore diameter (Table 1)', _POS, group='bearing')
    width_mm: float = _p(5.0, 'mm', 'b0', 'bearing width (Table 1)', _POS, group='bearing')
    ball_count: int = _p(15, '-', 'Z', 'number of balls per bearing (Table 1)', Bound(3, 200, True), group='bearing')
    inner_groove_diameter_mm: float = _p(19.1109, 'mm', 'd_I', 'inner raceway groove (bottom) diameter (Table 1)',
                                         _POS, group='bearing')
    outer_groove_diameter_mm: float = _p(23.8891, 'mm', 'd_O', 'outer raceway groove (bottom) diameter (Table 1)',
                                         _POS, group='bearing')
    ball_diameter_mm: float = _p(2.381, 'mm', 'D_w', 'ball diameter (Table 1)', _POS, group='bearing')
    inner_groove_curvature: float = _p(0.56, '-', 'f_i', 'inner groove curvature ratio r_i/D_w (Table 1)',
                                       Bound(0.5, 1.0, False, False), group='bearing')
    outer_groove_curvature: float = _p(0.54, '-', 'f_o', 'outer groove curvature ratio r_o/D_w (Table 1)',
                                       Bound(0.5, 1.0, False, False), group='bearing')
    bearings_per_axis: int = _p(2, '-', '', 'identical bearings on the axis; axis torque = this x per-bearing',
                                Bound(1, 8, True), group='bearing')
    # Materials
    steel_cte_per_c: float = _p(11.7e-6, '1/degC', 'phi_S', 'CTE of steel: bearing, shaft, inner frame [paper]',
                                Bound(-1e-4, 1e-4, True), group='material')
    aluminium_cte_per_c: float = _p(21.7e-6, '1/degC', 'phi_A', 'CTE of cast aluminium housing/outer frame [paper]',
                                    Bound(-1e-4, 1e-4, True), group='material')
    steel_youngs_modulus_mpa: float = _p(208000.0, 'MPa', 'E_S', 'Young modulus of bearing steel GCr15 [chosen]',
                                         Bound(1e3, 1e6, True), group='material')
    steel_poisson_ratio: float = _p(0.30, '-', 'gamma_S', 'Poisson ratio of bearing steel [chosen]',
                                    Bound(0.0, 0.5, True, False), group='material')
    aluminium_youngs_modulus_mpa: float = _p(70000.0, 'MPa', 'E_A', 'Young modulus of cast aluminium [chosen]',
                                             Bound(1e3, 1e6, True), group='material')
    aluminium_poisson_ratio: float = _p(0.33, '-', 'gamma_A', 'Poisson ratio of cast aluminium [chosen]',
                                        Bound(0.0, 0.5, True, False), group='material')
    # Mounting and thermal coupling
    reference_temperature_c: float = _p(20.0, 'degC', 'T_ref', 'assembly temperature at which Table 1, '
                                        'interference and gasket are defined', Bound(-100.0, 200.0, True),
                                        group='mounting')
    interference_mm: float = _p(0.006, 'mm', 'Delta', 'diametral interference of outer ring in housing at T_ref '
                                '(housing bore = D_m - Delta); negative = clearance fit', Bound(-0.5, 0.5, True),
                                group='mounting')
    interference_factor: int = _p(1, '-', '', '1 = Delta diametral (default, matches Figs. 5/7/8); '
                                  '2 = paper-literal "-2 Delta"', Bound(1, 2, True), group='mounting')
    housing_outside_diameter_mm: float = _p(80.0, 'mm', 'D_L', 'housing outside diameter in the Lame press fit '
                                            '[chosen]', _POS, group='mounting')
    gasket_thickness_mm: float = _p(0.03, 'mm', 'P', 'pre-tightening gasket thickness (axial squeeze per bearing)',
                                    Bound(0.0, 1.0, True), group='mounting')
    gasket_factor: float = _p(2.0, '-', 'g', 'total squeeze = g * P (paper tokens "2(b0 ... P)")',
                              Bound(0.0, 10.0, False), group='mounting')
    shaft_length_mm: float = _p(54.3, 'mm', 'L', 'effective length of the aluminium member between the bearings '
                                '[chosen, calibrated]', _POS, group='mounting')
    steel_section_area_mm2: float = _p(50.0, 'mm^2', 'A_S', 'axial cross-section of the steel member [chosen]',
                                       _POS, group='mounting')
    aluminium_section_area_mm2: float = _p(100.0, 'mm^2', 'A_A', 'axial cross-section of the aluminium member '
                                           '[chosen]', _POS, group='mounting')
    extra_compliance_mm_per_n: float = _p(1.5e-3, 'mm/N', 'C_extra', 'gasket + yoke axial compliance added to C1 '
                                          '[chosen]', Bound(0.0, 1.0, True), group='mounting')
    scale_bearing_width: bool = _p(True, '-', '', 'bearing width expands with steel (True, recommended) or the '
                                   'paper-literal Eq. 16 (False)', group='mounting')
    # Friction
    hysteresis_loss_fraction: float = _p(0.007, '-', 'alpha_r', 'elastic hysteresis loss fraction, Eq. 1 '
                                         '(paper: <= 1 %)', Bound(0.0, 1.0, True), group='friction')
    sliding_friction_coefficient: float = _p(0.095, '-', 'mu', 'spin sliding friction coefficient, Eq. 6 '
                                             '[chosen, calibrated]', Bound(0.0, 2.0, True), group='friction')
    palmgren_factor: float = _p(1.917, '-', 's0', 'Palmgren factor f0 for bearing type and lubrication, Eq. 9 '
                                '[chosen, calibrated]', Bound(0.0, 100.0, False), group='friction')
    hysteresis_radius: str = _p('harris', '-', 'R', 'radius R of Eq. 1: harris = 2 f D_w/(2f+1), '
                                'half_ball = D_w/2', choices=HYSTERESIS_RADII, group='friction')
    # Lubricant (Krytox 143AA, Eq. 22)
    viscosity_model: str = _p('walther_improved', '-', '', 'walther_improved = Eq. 21 '
                              '(loglog(nu+c1) = a1 + b1 loglog T), walther = Eq. 20 (a1 + b1 log T)',
                              choices=VISCOSITY_MODELS, group='lubricant')
    walther_a: float = _p(8.6195, '-', 'a1', 'Walther constant a1 of the selected viscosity model (Eq. 22)',
                          Bound(-1e3, 1e3, True), group='lubricant')
    walther_b: float = _p(-21.2471, '-', 'b1', 'Walther slope b1 of the selected viscosity model (Eq. 22); '
                          'must be < 0', Bound(-1e3, 0.0, True, False), group='lubricant')
    viscosity_offset_cst: float = _p(1.08, 'mm^2/s', 'c1', 'Walther offset c1 added to the kinematic viscosity '
                                     '(Eq. 22)', Bound(-1.0, 100.0, True), group='lubricant')
    kelvin_offset_k: float = _p(273.0, 'K', '', 'T [K] = t [degC] + this; the paper fits use 273',
                                Bound(273.0, 273.15, True), group='lubricant')
    # Operating point
    speed_rpm: float = _p(1.0 / 3.0, 'rpm', 'n', 'shaft speed used when none is given (paper test: 1/3 rpm)',
                          Bound(0.0, 1e5, True), group='operating')
    # Motor (Eq. 23); used by the estimator
    torque_constant_nm_per_a: float = _p(0.05, 'N*m/A', 'K_T', 'motor torque constant (calibrate with '
                                         'gimbal-friction calibrate-kt)', Bound(0.0, 100.0, False), group='motor')
    no_load_current_a: float = _p(0.0, 'A', 'I_0', 'motor no-load current (T_0 = K_T I_0)',
                                  Bound(-100.0, 100.0, True), group='motor')
    inertia_kg_m2: float = _p(1e-4, 'kg*m^2', 'J', 'moment of inertia of the axis (mirror, frame, motor rotor) '
                              "about its bearing axis; used by the estimator's observer (T_f = K_T(I - d I_0) - J "
                              'alpha) and the simulator', Bound(0.0, 10.0, False), group='motor')
    # Direction-dependent scale factors (the paper measured CW and CCW differently)
    scale_positive: float = _p(1.0, '-', '', 'factor on the model torque while moving in the positive direction',
                               Bound(0.0, 10.0, True), group='direction')
    scale_negative: float = _p(1.0, '-', '', 'factor on the model torque while moving in the negative direction',
                               Bound(0.0, 10.0, True), group='direction')
    # Temperature-dependent direction asymmetry (physics/direction.py): k = scale_dir * (1 + dir * a(T)),
    # a(T) linear from the cold to the warm anchor, constant outside; zero by default (no asymmetry)
    direction_asymmetry_cold: float = _p(0.0, '-', 'a_c', 'direction asymmetry a at direction_asymmetry_cold_c: '
                                         'CW (positive) friction x (1 + a), CCW x (1 - a); paper -40 degC: 0.131',
                                         Bound(-0.9, 0.9, True, True), group='direction')
    direction_asymmetry_warm: float = _p(0.0, '-', 'a_w', 'direction asymmetry a at direction_asymmetry_warm_c '
                                         '(paper +60 degC: -0.121); linear in temperature between the anchors',
                                         Bound(-0.9, 0.9, True, True), group='direction')
    direction_asymmetry_cold_c: float = _p(-40.0, 'degC', 'T_c', 'cold anchor temperature of the direction '
                                           'asymmetry; a = direction_asymmetry_cold at and below it',
                                           Bound(MODEL_T_MIN_C, MODEL_T_MAX_C, True), group='direction')
    direction_asymmetry_warm_c: float = _p(60.0, 'degC', 'T_w', 'warm anchor temperature of the direction '
                                           'asymmetry (must exceed the cold one); a = direction_asymmetry_warm at '
                                           'and above it', Bound(MODEL_T_MIN_C, MODEL_T_MAX_C, True), group='direction')

    # ------------------------------------------------------------------ derived quantities (docs/model.md §1.1)
    @property
    def pitch_diameter_mm(self) -> float:
        """Pitch diameter d_m = (d_I + d_O)/2 [mm]."""
        return 0.5 * (self.inner_groove_diameter_mm + self.outer_groove_diameter_mm)

    @property
    def total_curvature(self) -> float:
        """Total curvature B = f_i + f_o - 1 [-]."""
        return self.inner_groove_curvature + self.outer_groove_curvature - 1.0

    @property
    def radial_clearance_mm(self) -> float:
        """Unmounted radial clearance P_d = d_O - d_I - 2 D_w at T_ref [mm]."""
        return self.outer_groove_diameter_mm - self.inner_groove_diameter_mm - 2.0 * self.ball_diameter_mm

    @property
    def free_contact_angle_deg(self) -> float:
        """Unmounted free contact angle alpha0 = arccos(1 - P_d/(2 B D_w)) at T_ref [deg]."""
        c0 = 1.0 - self.radial_clearance_mm / (2.0 * self.total_curvature * self.ball_diameter_mm)
        return math.degrees(math.acos(min(max(c0, -1.0), 1.0)))

    # ------------------------------------------------------------------ construction and validation
    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, base: AxisParams | None = None) -> AxisParams:
        """Build and validate parameters from a flat mapping of field name to value, over ``base`` (defaults).

        Raises:
            ConfigError: unknown name, wrong type, or a value that breaks a physical rule.
        """
        fields = {f.name: f for f in dataclasses.fields(cls)}
        start = base if base is not None else cls()
        kwargs: dict[str, Any] = {}
        for name, value in values.items():
            if name not in fields:
                msg = f'unknown model parameter{did_you_mean(name, fields, same_first_word=True)}'
                raise ConfigError(name, msg, value)
            kwargs[name] = coerce(name, value, getattr(start, name))
        params = dataclasses.replace(start, **kwargs)
        params.validate()
        return params

    def to_mapping(self) -> dict[str, Any]:
        """Flat mapping of every field to its value (the inverse of :meth:`from_mapping`)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def replace(self, **changes: Any) -> AxisParams:
        """Validated copy with some fields changed."""
        return AxisParams.from_mapping(changes, base=self)

    def validate(self) -> None:
        """Check every field against its range and the cross-field geometric rules.

        Raises:
            ConfigError: naming the parameter and the rule it breaks.
        """
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            meta = f.metadata
            if meta['choices'] is not None:
                if value not in meta['choices']:
                    raise ConfigError(f.name, f'must be one of {", ".join(meta["choices"])}', value)
                continue
            if isinstance(value, bool):
                continue
            if not math.isfinite(value):
                raise ConfigError(f.name, 'must be a finite number', value)
            bound: Bound | None = meta['bound']
            if bound is not None:
                _check_bound(f.name, value, bound, meta['unit'])
        _check_geometry(self)


def _check_bound(name: str, value: float, bound: Bound, unit: str) -> None:
    unit_txt = f' [{unit}]' if unit not in ('-', '') else ''
    low, high = bound.low, bound.high
    if low is not None and (value < low or (value == low and not bound.low_inclusive)):
        if high is None:
            rule = f'must be {">=" if bound.low_inclusive else ">"} {low:g}{unit_txt}'
        else:
            rule = _interval_rule(bound, unit_txt)
        raise ConfigError(name, rule, value)
    if high is not None and (value > high or (value == high and not bound.high_inclusive)):
        raise ConfigError(name, _interval_rule(bound, unit_txt), value)


def _interval_rule(bound: Bound, unit_txt: str) -> str:
    left = '[' if bound.low_inclusive else '('
    right = ']' if bound.high_inclusive else ')'
    return f'must lie in {left}{bound.low:g}, {bound.high:g}{right}{unit_txt}'


def _check_geometry(p: AxisParams) -> None:
    """Cross-field rules: the bearing must be buildable and the housing must surround it."""
    if p.bore_diameter_mm >= p.outside_diameter_mm:
        raise ConfigError('bore_diameter_mm', 'must be smaller than outside_diameter_mm', p.bore_diameter_mm)
    if not p.bore_diameter_mm < p.inner_groove_diameter_mm < p.outer_groove_diameter_mm < p.outside_diameter_mm:
        raise ConfigError('inner_groove_diameter_mm',
                          'must satisfy bore < inner groove < outer groove < outside diameter',
                          p.inner_groove_diameter_mm)
    if p.radial_clearance_mm < 0.0:
        raise ConfigError('ball_diameter_mm', 'balls do not fit: outer groove - inner groove - 2 D_w must be >= 0 '
                          '(negative unmounted clearance)', p.ball_diameter_mm)
    if p.free_contact_angle_deg >= 80.0:
        raise ConfigError('ball_diameter_mm', 'free contact angle from the clearance must be < 80 deg '
                          f'(got {p.free_contact_angle_deg:.1f} deg)', p.ball_diameter_mm)
    if p.ball_count * p.ball_diameter_mm >= math.pi * p.pitch_diameter_mm:
        raise ConfigError('ball_count', 'balls do not fit on the pitch circle: Z D_w must be < pi d_m',
                          p.ball_count)
    if p.direction_asymmetry_warm_c <= p.direction_asymmetry_cold_c:
        raise ConfigError('direction_asymmetry_warm_c', 'must exceed direction_asymmetry_cold_c [degC]',
                          p.direction_asymmetry_warm_c)
    if p.housing_outside_diameter_mm <= p.outside_diameter_mm + abs(p.interference_mm):
        raise ConfigError('housing_outside_diameter_mm', 'must exceed the bearing outside_diameter_mm',
                          p.housing_outside_diameter_mm)


def parameter_specs() -> list[dict[str, Any]]:
    """Name, default, unit, symbol, description, bound and choices of every model parameter (for docs/nodes)."""
    out = []
    for f in dataclasses.fields(AxisParams):
        out.append({'name': f.name, 'default': f.default, **f.metadata})
    return out
