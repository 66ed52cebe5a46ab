"""Synthetic chamber test following the paper's protocol (Yu & Shang 2017, Sec. 6): pure numpy, no file I/O.
One job in one module: the generator (schedule, temperatures, motion and currents follow one seeded state); writing
the bag is :mod:`gimbal_friction.chamber.synth_bag`.

The test the paper ran, and what is generated here:

- The gimbal sits in a temperature chamber whose set point steps through ``plateaus_c`` (paper: −40 to +60 °C
  in 20 °C steps). Between plateaus the chamber ramps linearly at ``ramp_rate_c_per_min`` (the chamber does
  3–15 °C/min). The bearing follows the chamber through a first-order lag of time constant ``bearing_lag_s``,
  integrated exactly for the piecewise-linear chamber profile (no time stepping).
- At each plateau the chamber first *soaks* until the bearing has settled (paper: "each temperature point was
  kept for 1 h before a measure was carried"; here ``soak_s``, by default just long enough for the bearing to
  come within ``settle_tol_c`` of the plateau), then *holds* for ``hold_s`` while the measurement runs.
- The axis sweeps all the time, a triangle wave between ``travel_deg`` (paper: −6…+11°) at ``speed_rpm``
  (paper: 1/3 rpm) with a short constant-acceleration reversal of ``reversal_s`` at each end; the constant-speed
  part therefore spans slightly less than the travel, and the speed-up phases are what the estimator rejects.
- The motor current follows Eq. (23) with a *truth* model that differs from the package defaults
  (:data:`DEFAULT_TRUTH_OVERRIDES`)::

      I = (sign(v) F(T_b, |v|) d(T_b, sign v) (1 + r(θ, T_b)) + J a) / K_T + sign(v) I_0 + noise

  with ``F`` the truth model (:class:`~gimbal_friction.physics.table.FrictionTable`, N·m), ``d`` the direction
  factor (truth ``scale_positive``/``scale_negative`` times the cold asymmetry below), ``r`` the position ripple,
  ``J a`` the inertial torque during reversals, ``K_T``/``I_0`` the truth motor constants.
- The direction factor ``d`` is the model's own (:func:`~gimbal_friction.physics.direction.direction_factor` of the
  truth parameters: ``scale_positive``/``scale_negative`` and the temperature-dependent ``direction_asymmetry_*``,
  none by default) times a synthetic cold asymmetry that is *not* in the model's form, on the CCW side only
  (the default, as before): ``|CCW|/|CW| = 1 − (1 − asym_ratio_cold) · w(T)`` with ``w(T) = clip((asym_t_ref_c − T)
  / (asym_t_ref_c − asym_t_cold_c), 0, 1)``, i.e. 2.45/3.19 ≈ 0.768 at −40 °C and 1 at +20 °C and above.
  Positive velocity is the paper's clockwise (docs/ros.md).
- Preset ``paper`` (:func:`preset_config`): a chamber test whose plateau means are the paper's four measured
  values (CW 3.19 / CCW −2.45 N·mm at −40 °C, CW 1.05 / CCW −1.34 at +60 °C, Sec. 6): truth lubricant, Palmgren
  factor and direction asymmetry :data:`PAPER_TRUTH_OVERRIDES` (the synthetic cold asymmetry off). The mean of
  the two directions sets ``walther_a`` (cold: ν(−40 °C) = 27.7k cSt) and ``palmgren_factor`` (warm floor); their
  difference sets the asymmetry anchors (``(CW − |CCW|)/(CW + |CCW|)``). Whether the paper's warm excess over the
  model (1.195 vs 1.084 N·mm) is a higher Palmgren floor or an I_0 error cannot be told from these four numbers;
  the preset takes the Palmgren floor.
- Ripple is a sum of sines in position (amplitude as a fraction of the friction torque, spatial period in
  degrees), amplified in the cold by ``1 + ripple_cold_gain · w(T)`` ("its fluctuation was much more severe at
  −40 °C"): the simulator truth's :func:`~gimbal_friction.sim.truth.position_ripple` (one implementation).

Everything is seeded (``numpy.random.default_rng(seed)``): the same configuration gives identical arrays.

>>> data = generate(SynthConfig(plateaus_c=(20.0,), hold_s=20.0, joint_rate_hz=50.0))
>>> data.joint_stamp_ns.shape, data.position_rad.shape, round(data.duration_s, 2)
((1000,), (1000, 1), 20.0)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import NM_PER_NMM, NS_PER_S, rad_s_from_rpm, rpm_from_rad_s
from gimbal_friction.physics.direction import ARRAY, direction_factor
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import FrictionTable
from gimbal_friction.recording import topics
from gimbal_friction.sim.truth import cold_weight, position_ripple

Array = NDArray[np.float64]


#: Paper Sec. 6: mean |CCW| / |CW| friction at −40 °C (2.45 / 3.19 N·mm).
PAPER_COLD_RATIO = 2.45 / 3.19

#: Default truth: the package defaults (paper model) with a different lubricant and Palmgren factor.
#: ``walther_a`` 8.6195 -> 8.6345 (+0.015) raises the Krytox 143AA viscosity by ~46 % at −40 °C (44.7k -> 65.1k
#: cSt) and ~17 % at 20 °C. At 1/3 rpm only the coldest plateau is above Palmgren's ``nu n = 2000`` threshold,
#: so M_L grows from 2.30 to ~3.1 N·mm at −40 °C. ``palmgren_factor`` 1.917 -> 2.0 raises M_L by 4 % everywhere
#: (+0.03 N·mm on the low-speed floor). Truth M at 1/3 rpm: ≈3.93 N·mm at −40 °C (defaults 3.14), ≈1.07 at
#: +20 °C (1.05).
DEFAULT_TRUTH_OVERRIDES: Mapping[str, Any] = {'walther_a': 8.6345, 'palmgren_factor': 2.0}

#: Paper Sec. 6 measured plateau means [N·mm], keyed by (temperature [°C], direction ±1); CCW negative.
PAPER_MEANS_NMM: Mapping[tuple[float, int], float] = {(-40.0, 1): 3.19, (-40.0, -1): -2.45, (60.0, 1): 1.05,
                                                     (60.0, -1): -1.34}

#: Truth of preset ``paper`` (see the module notes): reproduces :data:`PAPER_MEANS_NMM` at 1/3 rpm within 0.01 %.
PAPER_TRUTH_OVERRIDES: Mapping[str, Any] = {'walther_a': 8.59967, 'palmgren_factor': 2.2660,
                                            'direction_asymmetry_cold': 0.13121, 'direction_asymmetry_warm': -0.12134,
                                            'direction_asymmetry_cold_c': -40.0, 'direction_asymmetry_warm_c': 60.0}

#: Presets of :func:`preset_config`: SynthConfig fields that differ from the defaults.
PRESETS: Mapping[str, Mapping[str, Any]] = {
    'default': {},
    'paper': {'truth_overrides': PAPER_TRUTH_OVERRIDES, 'asym_ratio_cold': 1.0,
              'plateaus_c': (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0)},
}

#: Default epoch of the first sample, [ns since the Unix epoch] (2017-05-01T00:00:00Z, the paper's year).
DEFAULT_START_NS = 1_493_596_800_000_000_000

#: Resolution the measured streams are written with (``generate(quantise=True)``, the default): motor current
#: [A], temperature [°C], position [rad], velocity [rad/s]. Far below each sensor's noise (2 mA, 0.05 °C, 1e-5 rad,
#: 1e-4 rad/s: 2000x, 500x, 10^4x, 10^5x), so no statistic moves, but far above the last bit of the values: the
#: vectorised math (sin, exp, log, pow) may differ by an ulp between CPU instruction sets, and rounding to this grid
#: makes the written values, and so a regenerated bag, the same bytes on every machine. The margin: a value is
#: written differently only if it lies within its cross-machine error (a few ulp, < 1e-14 of the value's unit)
#: of a half-step; :func:`half_step_margin` measures how close the values come (the shipped sample's test checks it
#: exceeds 1e-6 of a step, i.e. 1e-12 A, 1e-10 degC, 1e-15 rad, 1e-15 rad/s).
CURRENT_RESOLUTION_A = 1e-6
TEMPERATURE_RESOLUTION_C = 1e-4
POSITION_RESOLUTION_RAD = 1e-9
VELOCITY_RESOLUTION_RAD_S = 1e-9


def quantised(x: Any, step: float) -> Array:
    """``x`` rounded to the nearest multiple of ``step`` (same unit as ``x``; ties to even) [unit of ``x``].

    >>> quantised([0.12345678949, -2.5e-7], 1e-6).tolist()
    [0.123457, -0.0]
    """
    return np.asarray(np.rint(np.asarray(x, dtype=float) / step) * step)


def half_step_margin(x: Any, step: float) -> float:
    """Smallest distance of ``x / step`` from a half-integer (a rounding boundary of :func:`quantised`), in steps
    [-] (0.5 = every value on the grid; 0 = a value exactly on a boundary). ``inf`` for no values.

    >>> round(half_step_margin([0.1234564, 0.1234566], 1e-6), 6)
    0.1
    """
    r = np.asarray(x, dtype=float).ravel() / step
    return float(np.min(np.abs(r - np.floor(r) - 0.5))) if r.size else math.inf


def _tuple_f(values: Any, name: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ConfigError(name, 'must be a sequence of numbers', values) from None
    if not all(math.isfinite(v) for v in out):
        raise ConfigError(name, 'must be finite numbers', values)
    return out


@dataclass(frozen=True)
class SynthConfig:
    """Everything that defines a synthetic chamber test. Units are in the names; see the module docstring.

    The truth model of a joint is ``truth_base`` (one :class:`AxisParams` for every joint, or a mapping joint ->
    params) with ``truth_overrides`` applied on top (default :data:`DEFAULT_TRUTH_OVERRIDES`; pass ``{}`` when
    ``truth_base`` already is the truth, e.g. read from a parameter file).
    """

    # --- chamber protocol
    plateaus_c: tuple[float, ...] = (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0)  #: chamber plateaus, in order [°C]
    hold_s: float = 60.0            #: measuring hold at each plateau after the soak [s] (compressed; paper 1 h soak)
    soak_s: float | None = None     #: soak before the hold [s]; None = until the bearing is within settle_tol_c
    settle_tol_c: float = 0.2       #: bearing-to-plateau tolerance that ends the automatic soak [°C]
    ramp_rate_c_per_min: float = 15.0   #: chamber ramp rate between plateaus [°C/min] (chamber: 3–15)
    bearing_lag_s: float = 30.0     #: first-order time constant of bearing vs chamber temperature [s]
    start_soaked: bool = True       #: bearing starts at the first plateau (True) or at ``initial_bearing_c``
    initial_bearing_c: float = 20.0  #: bearing temperature at t = 0 when not ``start_soaked`` [°C]
    duration_s: float | None = None  #: cut the test after this many seconds [s]; None = whole schedule
    # --- motion
    speed_rpm: float = 1.0 / 3.0    #: sweep speed [rpm] (paper: 1/3 rpm)
    travel_deg: tuple[float, float] = (-6.0, 11.0)  #: sweep limits [deg] (paper: −6…+11°)
    reversal_s: float = 0.2         #: duration of a reversal from +v to −v at constant acceleration [s]
    inertia_kg_m2: float = 1e-3     #: axis inertia J for the inertial torque during reversals [kg·m²]
    # --- sample rates
    joint_rate_hz: float = 100.0    #: /joint_states rate [Hz]
    current_rate_hz: float | None = None  #: /gimbal/motor_current rate [Hz]; None = joint_rate_hz
    temperature_rate_hz: float = 2.0  #: /gimbal/temperature rate [Hz]
    log_jitter_s: float = 2e-4      #: transport delay of the log time after the stamp, uniform in [0, this) [s]
    start_ns: int = DEFAULT_START_NS  #: stamp of the first sample [ns since epoch]
    # --- measurement noise
    current_noise_a: float = 2e-3   #: white noise on the motor current, standard deviation [A]
    temperature_noise_c: float = 0.05  #: white noise on the temperature sensor, standard deviation [°C]
    position_noise_rad: float = 1e-5   #: white noise on the encoder position, standard deviation [rad]
    velocity_noise_rad_s: float = 1e-4  #: white noise on the measured velocity, standard deviation [rad/s]
    # --- torque ripple with position
    ripple_amplitude: tuple[float, ...] = (0.06, 0.03)  #: sine amplitudes, fraction of the friction torque [-]
    ripple_period_deg: tuple[float, ...] = (3.4, 0.85)  #: spatial periods [deg]
    ripple_phase_rad: tuple[float, ...] = (0.0, 1.3)    #: phases [rad]
    ripple_cold_gain: float = 1.0   #: ripple amplitude x (1 + this · w(T)): doubles at asym_t_cold_c by default
    # --- direction asymmetry in the cold
    asym_ratio_cold: float = PAPER_COLD_RATIO  #: |CCW| / |CW| friction at asym_t_cold_c [-] (paper ≈ 0.768)
    asym_t_cold_c: float = -40.0    #: temperature where the ratio is asym_ratio_cold [°C]
    asym_t_ref_c: float = 20.0      #: at and above this temperature both directions are equal [°C]
    # --- motor and truth model
    kt_nm_per_a: float | None = None  #: truth K_T [N·m/A]; None = truth params' torque_constant_nm_per_a (0.05)
    no_load_current_a: float | None = None  #: truth I_0 [A]; None = truth params' no_load_current_a (0.0)
    joints: tuple[str, ...] = ('elevation',)  #: joint names; each sweeps the same profile, phase-shifted
    truth_base: AxisParams | Mapping[str, AxisParams] = field(default_factory=AxisParams)
    truth_overrides: Mapping[str, Any] = field(default_factory=lambda: dict(DEFAULT_TRUTH_OVERRIDES))
    seed: int = 0                   #: seed of numpy.random.default_rng

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, 'plateaus_c', _tuple_f(self.plateaus_c, 'plateaus_c'))
        set_(self, 'travel_deg', _tuple_f(self.travel_deg, 'travel_deg'))
        for name in ('ripple_amplitude', 'ripple_period_deg', 'ripple_phase_rad'):
            set_(self, name, _tuple_f(getattr(self, name), name))
        set_(self, 'joints', tuple(str(j) for j in self.joints))
        self._validate()

    # ------------------------------------------------------------------ validation
    def _validate(self) -> None:
        def need(ok: bool, name: str, rule: str) -> None:
            if not ok:
                raise ConfigError(name, rule, getattr(self, name))

        finite = ('hold_s', 'settle_tol_c', 'ramp_rate_c_per_min', 'bearing_lag_s', 'initial_bearing_c',
                  'speed_rpm', 'reversal_s', 'inertia_kg_m2', 'joint_rate_hz', 'temperature_rate_hz',
                  'log_jitter_s', 'current_noise_a', 'temperature_noise_c', 'position_noise_rad',
                  'velocity_noise_rad_s', 'ripple_cold_gain', 'asym_ratio_cold', 'asym_t_cold_c', 'asym_t_ref_c')
        for name in finite:
            need(isinstance(getattr(self, name), (int, float)) and math.isfinite(getattr(self, name)), name,
                 'must be a finite number')
        need(len(self.plateaus_c) >= 1, 'plateaus_c', 'needs at least one plateau')
        need(all(-60.0 <= t <= 120.0 for t in self.plateaus_c), 'plateaus_c', 'must lie in [-60, 120] degC')
        need(self.hold_s > 0.0, 'hold_s', 'must be > 0 s')
        need(self.soak_s is None or (math.isfinite(self.soak_s) and self.soak_s >= 0.0), 'soak_s',
             'must be >= 0 s (or None = automatic)')
        need(self.settle_tol_c > 0.0, 'settle_tol_c', 'must be > 0 degC')
        need(self.ramp_rate_c_per_min > 0.0, 'ramp_rate_c_per_min', 'must be > 0 degC/min')
        need(self.bearing_lag_s >= 0.0, 'bearing_lag_s', 'must be >= 0 s')
        need(self.duration_s is None or (math.isfinite(self.duration_s) and self.duration_s > 0.0), 'duration_s',
             'must be > 0 s (or None)')
        need(self.speed_rpm > 0.0, 'speed_rpm', 'must be > 0 rpm')
        need(len(self.travel_deg) == 2 and self.travel_deg[0] < self.travel_deg[1], 'travel_deg',
             'must be (low, high) with low < high [deg]')
        need(self.reversal_s > 0.0, 'reversal_s', 'must be > 0 s')
        span = self.travel_deg[1] - self.travel_deg[0]
        need(0.5 * self.speed_rpm * 6.0 * self.reversal_s < span, 'reversal_s',
             'reversals must fit in the travel: speed x reversal_s / 2 < travel span')
        need(self.inertia_kg_m2 >= 0.0, 'inertia_kg_m2', 'must be >= 0 kg m^2')
        need(self.joint_rate_hz > 0.0, 'joint_rate_hz', 'must be > 0 Hz')
        need(self.current_rate_hz is None or (math.isfinite(self.current_rate_hz) and self.current_rate_hz > 0.0),
             'current_rate_hz', 'must be > 0 Hz (or None = joint_rate_hz)')
        need(self.temperature_rate_hz > 0.0, 'temperature_rate_hz', 'must be > 0 Hz')
        fastest = max(self.joint_rate_hz, self.current_rate or 0.0, self.temperature_rate_hz)
        need(0.0 <= self.log_jitter_s < 0.5 / fastest, 'log_jitter_s',
             'must be >= 0 and below half the shortest sample period (keeps each topic in order)')
        for name in ('current_noise_a', 'temperature_noise_c', 'position_noise_rad', 'velocity_noise_rad_s',
                     'ripple_cold_gain'):
            need(getattr(self, name) >= 0.0, name, 'must be >= 0')
        n_rip = len(self.ripple_amplitude)
        need(len(self.ripple_period_deg) == n_rip and len(self.ripple_phase_rad) == n_rip, 'ripple_period_deg',
             'ripple_amplitude, ripple_period_deg and ripple_phase_rad must have the same length')
        need(all(p > 0.0 for p in self.ripple_period_deg), 'ripple_period_deg', 'must be > 0 deg')
        need(all(a >= 0.0 for a in self.ripple_amplitude), 'ripple_amplitude', 'must be >= 0')
        need(sum(self.ripple_amplitude) * (1.0 + self.ripple_cold_gain) < 1.0, 'ripple_amplitude',
             'sum of amplitudes x (1 + ripple_cold_gain) must be < 1 (friction keeps its sign)')
        need(0.0 < self.asym_ratio_cold <= 2.0, 'asym_ratio_cold', 'must lie in (0, 2]')
        need(self.asym_t_cold_c < self.asym_t_ref_c, 'asym_t_cold_c', 'must be below asym_t_ref_c')
        need(self.kt_nm_per_a is None or (math.isfinite(self.kt_nm_per_a) and self.kt_nm_per_a > 0.0),
             'kt_nm_per_a', 'must be > 0 N*m/A (or None = truth params)')
        need(self.no_load_current_a is None or math.isfinite(self.no_load_current_a), 'no_load_current_a',
             'must be finite (or None = truth params)')
        need(len(self.joints) >= 1 and all(j.strip() for j in self.joints), 'joints',
             'needs at least one non-empty joint name')
        need(len(set(self.joints)) == len(self.joints), 'joints', 'joint names must be unique')
        need(isinstance(self.seed, int) and self.seed >= 0, 'seed', 'must be an integer >= 0')
        need(isinstance(self.start_ns, int) and self.start_ns >= 0, 'start_ns', 'must be an integer >= 0 ns')
        if isinstance(self.truth_base, Mapping):
            missing = [j for j in self.joints if j not in self.truth_base]
            need(not missing, 'truth_base', f'no truth parameters for joint(s) {", ".join(missing)}')
        for joint in self.joints:
            self.truth_params(joint)   # validates the overrides

    # ------------------------------------------------------------------ derived
    @property
    def current_rate(self) -> float:
        """Motor-current sample rate [Hz]."""
        return float(self.current_rate_hz if self.current_rate_hz is not None else self.joint_rate_hz)

    @property
    def speed_rad_s(self) -> float:
        """Sweep speed [rad/s]."""
        return rad_s_from_rpm(self.speed_rpm)

    def truth_params(self, joint: str | None = None) -> AxisParams:
        """Validated truth model parameters of ``joint`` (default: the first joint).

        Raises:
            ConfigError: an override names an unknown parameter or breaks a physical rule.
        """
        joint = self.joints[0] if joint is None else joint
        base = self.truth_base[joint] if isinstance(self.truth_base, Mapping) else self.truth_base
        if not self.truth_overrides:
            return base
        try:
            return base.replace(**dict(self.truth_overrides))
        except ConfigError as err:
            raise ConfigError(f'truth.{err.parameter}', err.rule, err.value) from None

    def motor_constants(self, joint: str | None = None) -> tuple[float, float]:
        """Truth (K_T [N·m/A], I_0 [A]) of ``joint``."""
        p = self.truth_params(joint)
        kt = self.kt_nm_per_a if self.kt_nm_per_a is not None else p.torque_constant_nm_per_a
        i0 = self.no_load_current_a if self.no_load_current_a is not None else p.no_load_current_a
        return float(kt), float(i0)

    def cold_weight(self, t_c: Any) -> Array:
        """w(T) = clip((asym_t_ref_c − T)/(asym_t_ref_c − asym_t_cold_c), 0, 1) [-] (the truth's
        :func:`~gimbal_friction.sim.truth.cold_weight`)."""
        return cold_weight(t_c, self.asym_t_cold_c, self.asym_t_ref_c)

    def ccw_ratio(self, t_c: Any) -> Array:
        """Configured |CCW|/|CW| friction ratio at bearing temperature ``t_c`` [°C] (cold asymmetry only)."""
        return 1.0 - (1.0 - self.asym_ratio_cold) * self.cold_weight(t_c)


# ---------------------------------------------------------------------------------------------- schedule
class Plateau(NamedTuple):
    """One chamber plateau; times in seconds from the first sample."""

    temperature_c: float   #: chamber set point [°C]
    reached_s: float       #: chamber arrives at the plateau (ramp end) [s]
    hold_start_s: float    #: soak over, measuring hold begins [s]
    hold_end_s: float      #: hold over, next ramp begins [s]

    def records(self, start_ns: int) -> dict[str, float | int]:
        """As a JSON-ready dict, with absolute stamps [ns] too."""
        out: dict[str, float | int] = dict(self._asdict())
        for key in ('reached_s', 'hold_start_s', 'hold_end_s'):
            out[key.replace('_s', '_ns')] = start_ns + int(round(getattr(self, key) * 1e9))
        return out


class _Segment(NamedTuple):
    t0: float      # start [s]
    c0: float      # chamber temperature at t0 [°C]
    rate: float    # chamber rate [°C/s]
    b0: float      # bearing temperature at t0 [°C]


def _lag_step(b0: Any, c0: Any, rate: Any, dt: Any, tau: float) -> Any:
    """Exact first-order lag ``tau db/dt = c − b`` over a linear input ``c = c0 + rate t`` after ``dt`` [s]."""
    dt = np.asarray(dt, dtype=float)
    c = c0 + rate * dt
    if tau <= 0.0:
        return c
    return c - rate * tau + (b0 - c0 + rate * tau) * np.exp(-dt / tau)


def schedule(cfg: SynthConfig) -> tuple[tuple[Plateau, ...], tuple[_Segment, ...], float]:
    """Chamber plateaus, the piecewise-linear chamber segments and the total duration [s] of ``cfg``."""
    tau = cfg.bearing_lag_s
    rate_s = cfg.ramp_rate_c_per_min / 60.0
    t = 0.0
    chamber = cfg.plateaus_c[0]
    bearing = chamber if cfg.start_soaked else cfg.initial_bearing_c
    plateaus: list[Plateau] = []
    segs: list[_Segment] = []
    for temp in cfg.plateaus_c:
        if temp != chamber:                                   # ramp
            r = math.copysign(rate_s, temp - chamber)
            dur = abs(temp - chamber) / rate_s
            segs.append(_Segment(t, chamber, r, bearing))
            bearing = float(_lag_step(bearing, chamber, r, dur, tau))
            t += dur
            chamber = temp
        reached = t
        err = abs(bearing - temp)
        if cfg.soak_s is not None:
            soak = cfg.soak_s
        elif err > cfg.settle_tol_c and tau > 0.0:
            soak = tau * math.log(err / cfg.settle_tol_c)
        else:
            soak = 0.0
        segs.append(_Segment(t, temp, 0.0, bearing))
        bearing = float(_lag_step(bearing, temp, 0.0, soak + cfg.hold_s, tau))
        plateaus.append(Plateau(temp, reached, reached + soak, reached + soak + cfg.hold_s))
        t += soak + cfg.hold_s
    total = t
    if cfg.duration_s is not None and cfg.duration_s < total:
        total = cfg.duration_s
        plateaus = [p._replace(hold_start_s=min(p.hold_start_s, total), hold_end_s=min(p.hold_end_s, total))
                    for p in plateaus if p.reached_s < total]
    return tuple(plateaus), tuple(segs), total


def chamber_and_bearing(cfg: SynthConfig, t_s: Any) -> tuple[Array, Array]:
    """Chamber set-point and (noise-free) bearing temperature [°C] at times ``t_s`` [s], exact lag solution."""
    _, segs, _ = schedule(cfg)
    t = np.asarray(t_s, dtype=float)
    starts = np.array([s.t0 for s in segs])
    k = np.clip(np.searchsorted(starts, t, side='right') - 1, 0, len(segs) - 1)
    t0 = starts[k]
    c0 = np.array([s.c0 for s in segs])[k]
    rate = np.array([s.rate for s in segs])[k]
    b0 = np.array([s.b0 for s in segs])[k]
    dt = t - t0
    return c0 + rate * dt, _lag_step(b0, c0, rate, dt, cfg.bearing_lag_s)


# ---------------------------------------------------------------------------------------------- motion
def sweep_period_s(cfg: SynthConfig) -> float:
    """Period of one full sweep (up and back) [s]."""
    v = cfg.speed_rpm * 6.0                      # [deg/s]
    span = cfg.travel_deg[1] - cfg.travel_deg[0]
    d = v * cfg.reversal_s / 4.0                 # distance covered in half a reversal [deg]
    return 2.0 * ((span - 2.0 * d) / v + cfg.reversal_s)


def sweep(cfg: SynthConfig, t_s: Any, phase_s: float = 0.0) -> tuple[Array, Array, Array]:
    """Triangle-wave sweep: position [rad], velocity [rad/s], acceleration [rad/s²] at times ``t_s`` [s].

    Constant speed between the limits, constant-acceleration reversals of ``reversal_s`` that turn exactly at
    ``travel_deg``. At ``t = -phase_s`` the axis is at 0° (mechanical zero) moving positive when 0 lies inside
    the travel.
    """
    lo, hi = cfg.travel_deg
    v = cfg.speed_rpm * 6.0                      # [deg/s]
    tr = cfg.reversal_s
    a = 2.0 * v / tr                             # [deg/s²]
    d = v * tr / 4.0
    tc = (hi - lo - 2.0 * d) / v                 # constant-speed time per direction
    period = 2.0 * (tc + tr)
    zero = min(max(0.0, lo + d), hi - d)
    offset = 0.5 * tr + (zero - (lo + d)) / v    # cycle phase at which the axis passes `zero` moving up
    tau = np.mod(np.asarray(t_s, dtype=float) + phase_s + offset, period)
    e1, e2, e3, e4 = 0.5 * tr, 0.5 * tr + tc, 1.5 * tr + tc, 1.5 * tr + 2.0 * tc
    pos = np.empty_like(tau)
    vel = np.empty_like(tau)
    acc = np.zeros_like(tau)
    m = tau < e1                                 # speeding up from the lower limit
    s = tau[m]
    pos[m], vel[m], acc[m] = lo + 0.5 * a * s * s, a * s, a
    m = (tau >= e1) & (tau < e2)                 # constant +v
    s = tau[m] - e1
    pos[m], vel[m] = lo + d + v * s, v
    m = (tau >= e2) & (tau < e3)                 # reversal at the upper limit
    s = tau[m] - e2
    pos[m], vel[m], acc[m] = hi - d + v * s - 0.5 * a * s * s, v - a * s, -a
    m = (tau >= e3) & (tau < e4)                 # constant −v
    s = tau[m] - e3
    pos[m], vel[m] = hi - d - v * s, -v
    m = tau >= e4                                # slowing down into the lower limit
    s = tau[m] - e4
    pos[m], vel[m], acc[m] = lo + d - v * s + 0.5 * a * s * s, -v + a * s, a
    rad = math.pi / 180.0
    return pos * rad, vel * rad, acc * rad


# ---------------------------------------------------------------------------------------------- data
class SynthData(NamedTuple):
    """A generated chamber test: three sampled streams plus the truth behind them.

    Arrays per joint have shape ``(n, len(joints))``. Stamps are int64 [ns since epoch]; log times are the
    stamps plus the transport jitter.
    """

    config: SynthConfig
    joints: tuple[str, ...]
    plateaus: tuple[Plateau, ...]
    duration_s: float
    # /joint_states
    joint_stamp_ns: NDArray[np.int64]
    joint_log_ns: NDArray[np.int64]
    position_rad: Array            #: measured (with encoder noise) [rad]
    velocity_rad_s: Array          #: measured (with noise) [rad/s]
    # /gimbal/motor_current
    current_stamp_ns: NDArray[np.int64]
    current_log_ns: NDArray[np.int64]
    current_a: Array               #: motor armature current [A]
    # /gimbal/temperature
    temperature_stamp_ns: NDArray[np.int64]
    temperature_log_ns: NDArray[np.int64]
    temperature_c: Array           #: measured bearing temperature (with noise) [°C]
    # truth at the current samples
    truth_position_rad: Array      #: [rad]
    truth_velocity_rad_s: Array    #: [rad/s]
    truth_acceleration_rad_s2: Array  #: [rad/s²]
    truth_friction_nm: Array       #: signed friction torque incl. asymmetry and ripple [N·m]
    truth_model_nm: Array          #: truth model magnitude F(T_b, |v|), no asymmetry or ripple [N·m]
    bearing_temperature_c: Array   #: noise-free bearing temperature [°C]
    chamber_temperature_c: Array   #: chamber set point [°C]
    truth: Mapping[str, AxisParams]

    def message_counts(self) -> dict[str, int]:
        """Messages per contract topic."""
        return {topics.TEMPERATURE: int(self.temperature_stamp_ns.size),
                topics.JOINT_STATES: int(self.joint_stamp_ns.size),
                topics.MOTOR_CURRENT: int(self.current_stamp_ns.size)}

    def seconds(self, stamp_ns: NDArray[np.int64]) -> Array:
        """Stamps converted to seconds from the first sample."""
        return (np.asarray(stamp_ns, dtype=np.int64) - self.config.start_ns).astype(float) / NS_PER_S


def _sample_times(rate_hz: float, duration_s: float) -> Array:
    n = int(math.floor(duration_s * rate_hz + 1e-9))
    return np.arange(n, dtype=float) / rate_hz


def _stamps(cfg: SynthConfig, t_s: Array) -> NDArray[np.int64]:
    return cfg.start_ns + np.round(t_s * 1e9).astype(np.int64)


def _jitter(cfg: SynthConfig, rng: np.random.Generator, stamps: NDArray[np.int64]) -> NDArray[np.int64]:
    if cfg.log_jitter_s <= 0.0:
        return stamps.copy()
    return stamps + np.floor(rng.uniform(0.0, cfg.log_jitter_s * 1e9, stamps.size)).astype(np.int64)


def generate(cfg: SynthConfig | None = None, *, quantise: bool = True) -> SynthData:
    """Generate the synthetic chamber test described by ``cfg`` (default :class:`SynthConfig`).

    Deterministic for a given configuration (seeded ``numpy.random.default_rng(cfg.seed)``). With ``quantise``
    (default) the measured streams are rounded to :data:`CURRENT_RESOLUTION_A`, :data:`TEMPERATURE_RESOLUTION_C`,
    :data:`POSITION_RESOLUTION_RAD` and :data:`VELOCITY_RESOLUTION_RAD_S` (the same bytes on every machine); the
    truth arrays are never rounded.
    """
    cfg = cfg if cfg is not None else SynthConfig()
    rng = np.random.default_rng(cfg.seed)
    plateaus, _, duration = schedule(cfg)
    joints = cfg.joints
    nj = len(joints)
    period = sweep_period_s(cfg)
    phases = [j * period / 4.0 for j in range(nj)]

    # --- joint states
    tj = _sample_times(cfg.joint_rate_hz, duration)
    pos_j = np.empty((tj.size, nj))
    vel_j = np.empty((tj.size, nj))
    for j in range(nj):
        pos_j[:, j], vel_j[:, j], _ = sweep(cfg, tj, phases[j])
    pos_meas = pos_j + rng.normal(0.0, cfg.position_noise_rad, pos_j.shape) if cfg.position_noise_rad else pos_j
    vel_meas = vel_j + rng.normal(0.0, cfg.velocity_noise_rad_s, vel_j.shape) if cfg.velocity_noise_rad_s \
        else vel_j

    # --- motor current
    tc = _sample_times(cfg.current_rate, duration)
    chamber_c, bearing_c = chamber_and_bearing(cfg, tc)
    w = cfg.cold_weight(bearing_c)
    asym_neg = 1.0 - (1.0 - cfg.asym_ratio_cold) * w
    pos_c = np.empty((tc.size, nj))
    vel_c = np.empty((tc.size, nj))
    acc_c = np.empty((tc.size, nj))
    model = np.empty((tc.size, nj))
    friction = np.empty((tc.size, nj))
    current = np.empty((tc.size, nj))
    truth: dict[str, AxisParams] = {}
    tables: dict[AxisParams, FrictionTable] = {}
    for j, joint in enumerate(joints):
        p = cfg.truth_params(joint)
        truth[joint] = p
        table = tables.get(p)
        if table is None:
            table = tables[p] = FrictionTable(p)
        kt, i0 = cfg.motor_constants(joint)
        pos, vel, acc = sweep(cfg, tc, phases[j])
        pos_c[:, j], vel_c[:, j], acc_c[:, j] = pos, vel, acc
        m_nm = NM_PER_NMM * table.evaluate(bearing_c, rpm_from_rad_s(np.abs(vel)))[2]
        model[:, j] = m_nm
        ripple = position_ripple(pos, bearing_c, cfg.ripple_amplitude, cfg.ripple_period_deg, cfg.ripple_phase_rad,
                                 cfg.ripple_cold_gain, cfg.asym_t_cold_c, cfg.asym_t_ref_c)
        sgn = np.sign(vel)
        direction = direction_factor(p, bearing_c, sgn, ARRAY) * np.where(sgn > 0.0, 1.0, asym_neg)
        friction[:, j] = sgn * m_nm * direction * (1.0 + ripple)
        noise = rng.normal(0.0, cfg.current_noise_a, tc.size) if cfg.current_noise_a else 0.0
        current[:, j] = (friction[:, j] + cfg.inertia_kg_m2 * acc) / kt + sgn * i0 + noise

    # --- temperature sensor
    tt = _sample_times(cfg.temperature_rate_hz, duration)
    _, bearing_t = chamber_and_bearing(cfg, tt)
    temp_meas = bearing_t + rng.normal(0.0, cfg.temperature_noise_c, tt.size) if cfg.temperature_noise_c \
        else bearing_t

    if quantise:
        pos_meas = quantised(pos_meas, POSITION_RESOLUTION_RAD)
        vel_meas = quantised(vel_meas, VELOCITY_RESOLUTION_RAD_S)
        current, temp_meas = quantised(current, CURRENT_RESOLUTION_A), quantised(temp_meas, TEMPERATURE_RESOLUTION_C)
    js, cs, ts = _stamps(cfg, tj), _stamps(cfg, tc), _stamps(cfg, tt)
    return SynthData(
        config=cfg, joints=joints, plateaus=plateaus, duration_s=duration,
        joint_stamp_ns=js, joint_log_ns=_jitter(cfg, rng, js), position_rad=pos_meas, velocity_rad_s=vel_meas,
        current_stamp_ns=cs, current_log_ns=_jitter(cfg, rng, cs), current_a=current,
        temperature_stamp_ns=ts, temperature_log_ns=_jitter(cfg, rng, ts), temperature_c=np.asarray(temp_meas),
        truth_position_rad=pos_c, truth_velocity_rad_s=vel_c, truth_acceleration_rad_s2=acc_c,
        truth_friction_nm=friction, truth_model_nm=model, bearing_temperature_c=np.asarray(bearing_c),
        chamber_temperature_c=np.asarray(chamber_c), truth=truth)


# ---------------------------------------------------------------------------------------------- messages
def message_order(data: SynthData) -> tuple[NDArray[np.int64], NDArray[np.int8], NDArray[np.int64]]:
    """(log time [ns], stream 0/1/2 = temperature/joint/current, index in stream) of every message, in log order.

    Ties in log time keep the order temperature, joint states, current.
    """
    logs = [data.temperature_log_ns, data.joint_log_ns, data.current_log_ns]
    log = np.concatenate(logs)
    stream = np.concatenate([np.full(x.size, k, dtype=np.int8) for k, x in enumerate(logs)])
    index = np.concatenate([np.arange(x.size, dtype=np.int64) for x in logs])
    order = np.lexsort((stream, log))
    return log[order], stream[order], index[order]


def messages(data: SynthData, *, frame_id: str = 'gimbal') -> Iterator[tuple[str, str, int, Any]]:
    """``(topic, msgtype, log_time_ns, msg)`` of every message of ``data`` in log-time order (contract topics).

    ``/gimbal/temperature`` sensor_msgs/msg/Temperature (bearing °C), ``/joint_states`` JointState with position
    [rad] and velocity [rad/s], ``/gimbal/motor_current`` JointState with effort = current [A]. Each
    ``header.stamp`` is the sample time; messages are rosbags typestore objects built by
    :mod:`gimbal_friction.recording.bag`.
    """
    from gimbal_friction.recording.bag_write import make_joint_state, make_temperature

    names = list(data.joints)
    log, stream, index = message_order(data)
    t_stamp, t_val = data.temperature_stamp_ns.tolist(), data.temperature_c.tolist()
    j_stamp, c_stamp = data.joint_stamp_ns.tolist(), data.current_stamp_ns.tolist()
    pos, vel, cur = data.position_rad, data.velocity_rad_s, data.current_a
    temp_t, joint_t, cur_t = topics.TEMPERATURE, topics.JOINT_STATES, topics.MOTOR_CURRENT
    temp_type, js_type = topics.TEMPERATURE_TYPE, topics.JOINT_STATE_TYPE
    for log_ns, k, i in zip(log.tolist(), stream.tolist(), index.tolist(), strict=False):
        if k == 0:
            yield temp_t, temp_type, log_ns, make_temperature(t_stamp[i], t_val[i], frame_id=frame_id)
        elif k == 1:
            yield joint_t, js_type, log_ns, make_joint_state(j_stamp[i], names, position=pos[i], velocity=vel[i])
        else:
            yield cur_t, js_type, log_ns, make_joint_state(c_stamp[i], names, effort=cur[i])


def preset_config(name: str, **changes: Any) -> SynthConfig:
    """The :class:`SynthConfig` of preset ``name`` (:data:`PRESETS`) with ``changes`` on top.

    >>> cfg = preset_config('paper', hold_s=20.0)
    >>> cfg.truth_params().direction_asymmetry_cold, cfg.asym_ratio_cold
    (0.13121, 1.0)

    Raises:
        ConfigError: unknown preset or a bad field.
    """
    if name not in PRESETS:
        raise ConfigError('preset', f'must be one of {", ".join(PRESETS)}', name)
    fields = {**PRESETS[name], **changes}
    if 'truth_overrides' in PRESETS[name] and 'truth_overrides' in changes:
        fields['truth_overrides'] = {**PRESETS[name]['truth_overrides'], **changes['truth_overrides']}
    return SynthConfig(**fields)


def truth_summary(cfg: SynthConfig) -> dict[str, Any]:
    """JSON-ready description of the truth: per joint the parameters that differ from the package defaults,
    the motor constants, and the truth model torque at each plateau at the sweep speed [N·mm]."""
    defaults = AxisParams()
    out: dict[str, Any] = {}
    for joint in cfg.joints:
        p = cfg.truth_params(joint)
        kt, i0 = cfg.motor_constants(joint)
        table = FrictionTable(p)
        temps = np.asarray(cfg.plateaus_c)
        torque = table.evaluate(temps, np.full(temps.size, cfg.speed_rpm))[2]
        ref = FrictionTable(defaults).evaluate(temps, np.full(temps.size, cfg.speed_rpm))[2]
        k_pos = direction_factor(p, temps, 1.0, ARRAY)
        k_neg = direction_factor(p, temps, -1.0, ARRAY) * cfg.ccw_ratio(temps)
        out[joint] = {
            'differs_from_defaults': {f.name: getattr(p, f.name) for f in dataclasses.fields(p)
                                      if getattr(p, f.name) != getattr(defaults, f.name)},
            'torque_constant_nm_per_a': kt, 'no_load_current_a': i0,
            'plateaus': [{'temperature_c': float(t), 'viscosity_cst': table.viscosity_cst(float(t)),
                          'truth_cw_nmm': float(m) * float(kp), 'truth_ccw_nmm': -float(m) * float(kn),
                          'default_model_nmm': float(r)}
                         for t, m, r, kp, kn in zip(temps, torque, ref, k_pos, k_neg, strict=True)],
        }
    return out
