"""Configuration of the gimbal-axis simulator: every parameter with its unit, default, justification and rule.

One job in one module: the simulator's parameters, each with its unit, default, justification and rule, in one
dataclass.

One frozen dataclass, :class:`SimConfig`, holds the simulator's own parameters (plant, motor drive, sensors, the
seeker's stabilization controller, the truth friction beyond the model, the thermal lag, base motion, the
feedforward transport latency and the study profiles). The *configured* model of the axis (K_T, I_0, J, the
bearing and lubricant of the friction model: the configuration under test, what the controller, the feedforward
and the estimator use) comes from the suite's :class:`~gimbal_friction.physics.params.AxisParams`. The *truth* is the
simulator's own and never reads that configuration (group ``truth``, plus the sensor, thermal and plant groups): the
paper's bearing with its own lubricant (``truth_walther_a`` + ``lubricant_walther_a_shift``, ``truth_walther_b``),
Palmgren factor and motor (``truth_torque_constant_nm_per_a``, ``truth_no_load_current_a``), plus what the model
does not know (LuGre pre-sliding and Stribeck breakaway, position ripple, a CW/CCW asymmetry that grows in the
cold), a temperature sensor with its own offset (``temperature_bias_c``) and lag
(``temperature_sensor_time_constant_s``), the bearing's thermal lag. The one exception is the plant's inertia,
stated relative to the configured J (``inertia_truth_ratio``).

It is read from the ``gimbal_sim`` section of a ROS 2 parameter file (``gimbal_sim: ros__parameters: {...}``,
see ``config/gimbal_sim.yaml``) with :meth:`SimConfig.from_mapping`, so the (later) ``gimbal_sim`` node and the
``loop-study`` CLI accept and refuse the same values. Every refusal is a
:class:`~gimbal_friction.common.errors.ConfigError` naming the parameter and the rule:

>>> SimConfig.from_mapping({'inertia_truth_ratio': -1.0})
Traceback (most recent call last):
...
gimbal_friction.common.errors.ConfigError: parameter 'inertia_truth_ratio' = -1.0: must lie in (0, 100] [-]
>>> c = SimConfig.from_mapping({'gimbal_sim': {'ros__parameters': {'rate_bandwidth_hz': 30}}})
>>> c.rate_bandwidth_hz, c.rate_loop_hz
(30.0, 1000.0)

Defaults and why (the seeker is the paper's gimbaled-mirror seeker, elevation axis)
-----------------------------------------------------------------------------------
Inertia. The configured J is the axis parameter ``inertia_kg_m2`` of
:class:`~gimbal_friction.physics.params.AxisParams` (default 1.0e-4 kg·m²; the seeker's controller gains and the
estimator's observer use it); the plant's true J is that times ``inertia_truth_ratio`` (default 1: the configured J
is right), so the number has one default. Why 1.0e-4 kg·m²; assumed load: an aluminium (6061, 2700 kg/m³) flat
mirror 60 mm in diameter and 8 mm thick, rotating about a diameter: m = 61 g, J = m(r²/4 + t²/12) = 1.4e-5 kg·m²;
its inner frame / yoke and the shaft between the two 26 mm bearings (≈ 100 g at a radius of gyration of ≈ 25 mm):
6e-5 kg·m²; the rotor of a frameless torque motor sized for the 17 mm shaft: ≈ 1e-5 kg·m². Sum ≈ 8.5e-5, rounded
up to 1.0e-4 kg·m². The
friction-to-inertia ratio T_F/J (Stockum 1988, the paper's Sec. 3) is then 10 rad/s² at +20 °C and 39 rad/s² at
−40 °C (truth), which is why a light mirror axis is so sensitive to friction.

Motor drive: ``current_limit_a = 2 A`` (the suite's motor current rating, ``max_current_a`` of the estimator), so
the peak torque is K_T · 2 A = 0.1 N·m with the suite's K_T = 0.05 N·m/A (25× the coldest friction); a first-order
current loop of ``current_loop_time_constant_s = 0.2 ms`` (≈ 800 Hz bandwidth, a typical PWM drive).

Controller (the seeker's own, sampled at ``rate_loop_hz = 1000``): a rate PI on the LOS gyro with crossover
``rate_bandwidth_hz = 40`` and its integral corner at ``rate_integral_hz = 8`` (a fifth of the crossover); gains
from the bandwidths with the configured J and K_T: K_p = 2π·40 = 251 1/s, current = J (K_p e + K_p ω_i ∫e) / K_T. With
the 0.5 ms hold, 0.2 ms current loop the phase margin is ≈ 68°. A mirror seeker's rate loop runs at a few tens
of Hz (bounded by the mirror/yoke's first structural mode at a few hundred Hz); the outer track loop runs on the
imaging tracker's boresight error at the frame rate ``track_loop_hz = 100`` with crossover
``track_bandwidth_hz = 4`` (a tenth of the rate loop) and the target rate as feedforward.

Sensors: a tactical-grade (FOG-class) rate gyro on the LOS, white noise ``gyro_noise_rad_s = 2e-4`` rad/s per
1 kHz sample (angle random walk 0.02 °/√h) and bias 5e-6 rad/s (1 °/h); a precision resolver with an RDC,
angle noise 5e-6 rad (1 arcsec), velocity noise 2e-4 rad/s behind the RDC's 1 ms velocity filter; the
tracker's boresight error with 5e-6 rad noise; a bearing-housing temperature sensor at 10 Hz, 0.1 °C noise,
5 s own lag (``temperature_stop_s`` makes it fall silent during a run, to see the stale-temperature rules at
work); motor current sensing with 2 mA noise (as the synthetic chamber bag).

Truth friction beyond the model: LuGre (Canudas de Wit et al. 1995) with bristle stiffness
``sigma0_nm_per_rad = 100`` (pre-sliding displacement at the Coulomb level F_C/σ0 ≈ 10 µrad at +20 °C,
40 µrad at −40 °C, i.e. 2–8 arcsec, the order of a preloaded precision ball bearing), damping
``sigma1_nm_s_per_rad = 0.1`` = √(σ0 J) (the choice of the 1995 paper's example, σ1 = √(σ0 m), damping ratio 0.5
of the pre-sliding resonance at √(σ0/J)/2π = 159 Hz), Stribeck velocity 0.002 rad/s (the friction drops to its
sliding level by ≈ 3 v_s = 0.006 rad/s, well below the paper's 0.0349 rad/s test speed, so the measured means are
sliding values) and breakaway ratio F_S/F_C = 1.5 (the 1995 paper's example); position ripple 6 % at 3.4° and
3 % at 0.85° (as the synthetic chamber bag), doubled at −40 °C ("its fluctuation was much more severe at −40 ℃");
the datasheet lubricant (``truth_walther_a``/``_b`` = the packaged model's) with ``walther_a`` shifted by +0.015 (the
synthetic chamber bag's truth: +46 % viscosity at −40 °C), the model's Palmgren factor and motor constants, and the
paper's measured CW/CCW means (3.19 / −2.45 N·mm at −40 °C, 1.05 / −1.34 N·mm at +60 °C) as a direction asymmetry
and a mean factor (see :mod:`gimbal_friction.sim.truth`).

A truth of the other pre-sliding family (``presliding_model = 'gms'``, the generalized Maxwell-slip model of
Al-Bender, Lampaert & Swevers 2005, :mod:`gimbal_friction.sim.gms`) replaces the bristle by four elasto-slide
elements with stiffnesses (200, 80, 30, 10) N·m/rad holding (40, 30, 20, 10) % of the Stribeck level: at the
default truth's breakaway level at +20 °C (≈ 1.6 N·mm) they saturate after ≈ 3, 6, 10 and 16 µrad, the same
order as the LuGre bristle's F/σ0, and the total initial stiffness 320 N·m/rad puts the pre-sliding resonance at
√(K/J)/2π ≈ 285 Hz (h √(K/J) = 0.45 at the default 4 kHz plant step: stable, see
:class:`~gimbal_friction.sim.engine.Plant`). The element limits follow the truth's own Stribeck level, so the
pre-sliding hysteresis grows in the cold with the friction; the damping is ``sigma1_nm_s_per_rad``'s. The default
truth is LuGre's.

Thermal: bearing temperature lags the environment with 30 s (as the synthetic chamber bag).

Base motion: missile body rate 0.05 rad/s at 0.5 Hz (airframe weaving / autopilot), 0.02 rad/s at 2 Hz
(short-period mode) and 0.005 rad/s at 10 Hz (structural vibration), i.e. up to 4 °/s.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gimbal_friction.common.errors import ConfigError, check_rules
from gimbal_friction.common.settings import coerce, setting, settings_from
from gimbal_friction.common.text import did_you_mean

#: Profiles the simulator knows (see :mod:`gimbal_friction.sim.profiles`).
PROFILES = ('tracking', 'scan', 'pointing', 'weave')
#: Pre-sliding forms of the truth friction (:mod:`gimbal_friction.sim.lugre`, :mod:`gimbal_friction.sim.gms`).
PRESLIDING_MODELS = ('lugre', 'gms')
#: Name of the section of a ROS 2 parameter file that holds the simulator parameters.
SECTION = 'gimbal_sim'
#: Parameters that are lists of names (every other list holds numbers).
_NAME_LISTS = frozenset({'base_motion_profiles'})


def _p(default: Any, unit: str, description: str, group: str) -> Any:
    """A parameter field with its unit, description and group (the YAML / node descriptors read them)."""
    return field(default=default, metadata={'unit': unit, 'description': description, 'group': group})


@dataclass(frozen=True)
class SimConfig:
    """Every parameter of the gimbal-axis simulator (units in the names; see the module notes for the defaults).

    Model parameters of the axis (K_T, I_0, bearing, lubricant) are not here: they come from
    :class:`~gimbal_friction.physics.params.AxisParams`.
    """

    # --- plant
    inertia_truth_ratio: float = _p(1.0, '-', 'true inertia of the plant over the configured one (AxisParams '
                                    'inertia_kg_m2, used by the controller and the estimator)', 'plant')
    disturbance_torque_nm: float = _p(0.0, 'N*m', 'constant external disturbance torque tau_dist (unbalance, '
                                      'cable)', 'plant')
    unbalance_torque_nm: float = _p(0.0, 'N*m', 'amplitude of an unbalance torque that depends on the joint angle: '
                                    'unbalance_torque_nm * sin(joint angle + unbalance_phase_rad) (a mass off the '
                                    'axis under gravity)', 'plant')
    unbalance_phase_rad: float = _p(0.0, 'rad', 'phase of the angle-dependent unbalance torque', 'plant')
    plant_substeps: int = _p(4, '-', 'plant integration steps per controller tick (LuGre pre-sliding stiffness)',
                             'plant')
    # --- motor drive
    current_limit_a: float = _p(2.0, 'A', 'drive current limit (saturation of the commanded current)', 'motor')
    current_loop_time_constant_s: float = _p(2.0e-4, 's', 'time constant of the first-order current loop',
                                             'motor')
    current_noise_a: float = _p(2.0e-3, 'A', 'white noise of the motor-current sensor, standard deviation',
                                'motor')
    # --- controller
    rate_loop_hz: float = _p(1000.0, 'Hz', 'sample rate of the seeker controller (rate loop, feedforward '
                             'input, recorded traces)', 'controller')
    rate_bandwidth_hz: float = _p(40.0, 'Hz', 'crossover of the rate PI loop on the LOS gyro', 'controller')
    rate_integral_hz: float = _p(8.0, 'Hz', 'integral corner (zero) of the rate PI', 'controller')
    track_loop_hz: float = _p(100.0, 'Hz', 'sample rate of the outer track loop (tracker frame rate)',
                              'controller')
    track_bandwidth_hz: float = _p(4.0, 'Hz', 'crossover of the outer track (position) loop', 'controller')
    track_noise_rad: float = _p(5.0e-6, 'rad', 'white noise of the tracker boresight error, standard deviation',
                                'controller')
    # --- sensors
    gyro_noise_rad_s: float = _p(2.0e-4, 'rad/s', 'white noise of the LOS rate gyro per controller sample, '
                                 'standard deviation', 'sensors')
    gyro_bias_rad_s: float = _p(5.0e-6, 'rad/s', 'constant bias of the LOS rate gyro', 'sensors')
    resolver_noise_rad: float = _p(5.0e-6, 'rad', 'white noise of the resolver angle (gimbal relative to base), '
                                   'standard deviation', 'sensors')
    resolver_velocity_noise_rad_s: float = _p(2.0e-4, 'rad/s', 'white noise of the resolver (RDC) velocity, '
                                              'standard deviation', 'sensors')
    resolver_velocity_time_constant_s: float = _p(1.0e-3, 's', 'time constant of the RDC velocity filter',
                                                  'sensors')
    temperature_rate_hz: float = _p(10.0, 'Hz', 'sample rate of the bearing temperature sensor', 'sensors')
    temperature_noise_c: float = _p(0.1, 'degC', 'white noise of the temperature sensor, standard deviation',
                                    'sensors')
    temperature_bias_c: float = _p(0.0, 'degC', 'constant error of the temperature sensor', 'sensors')
    temperature_sensor_time_constant_s: float = _p(5.0, 's', 'first-order lag of the sensor behind the '
                                                   'bearing temperature', 'sensors')
    temperature_stop_s: float = _p(-1.0, 's', 'the temperature sensor publishes nothing from this time of a run on '
                                   '(a failed sensor or link: the stale-temperature rules act); < 0: never', 'sensors')
    # --- thermal
    thermal_time_constant_s: float = _p(30.0, 's', 'first-order lag of the bearing temperature behind the '
                                        'environment', 'thermal')
    environment_ramp_c_per_s: float = _p(0.0, 'degC/s', 'environment temperature ramp during a run (0: hold '
                                         'the plateau)', 'thermal')
    initial_bearing_offset_c: float = _p(0.0, 'degC', 'bearing minus environment temperature at t = 0 (0: '
                                         'soaked)', 'thermal')
    # --- base motion
    base_motion_amplitudes_rad_s: tuple[float, ...] = _p((0.05, 0.02, 0.005), 'rad/s', 'missile body rate: '
                                                         'amplitude of each sine', 'base')
    base_motion_frequencies_hz: tuple[float, ...] = _p((0.5, 2.0, 10.0), 'Hz', 'missile body rate: frequency of '
                                                       'each sine (0.5-10 Hz)', 'base')
    base_motion_phases_rad: tuple[float, ...] = _p((0.0, 1.0, 2.0), 'rad', 'missile body rate: phase of each '
                                                   'sine', 'base')
    # --- truth friction: the simulated axis's own, never read from the configuration under test (the truth's
    # bearing is the paper's, Table 1; see gimbal_friction.sim.truth)
    truth_walther_a: float = _p(8.6195, '-', 'Walther constant a1 (Eq. 22, improved Walther form) of the truth '
                                'lubricant before lubricant_walther_a_shift (default: the datasheet Krytox 143AA, '
                                "the packaged model's walther_a)", 'truth')
    truth_walther_b: float = _p(-21.2471, '-', 'Walther slope b1 (Eq. 22) of the truth lubricant, < 0 (default: the '
                                "datasheet's)", 'truth')
    lubricant_walther_a_shift: float = _p(0.015, '-', 'truth walther_a minus truth_walther_a (a lubricant that '
                                          'differs from the datasheet: +0.015 is +46 % viscosity at -40 degC); the '
                                          "truth lubricant's a1 is truth_walther_a + this", 'truth')
    truth_palmgren_factor: float = _p(1.917, '-', 'Palmgren factor f0 of the truth bearing (Eq. 9; the low-speed '
                                      'floor of the lubricant moment)', 'truth')
    truth_torque_constant_nm_per_a: float = _p(0.05, 'N*m/A', 'true motor torque constant K_T of the plant (the '
                                               'controller, feedforward and estimator use the configured one)',
                                               'truth')
    truth_no_load_current_a: float = _p(0.0, 'A', 'true motor no-load current I_0 of the plant (a Coulomb torque '
                                        'K_T I_0 against the motion)', 'truth')
    sigma0_nm_per_rad: float = _p(100.0, 'N*m/rad', 'LuGre bristle stiffness sigma0', 'truth')
    sigma1_nm_s_per_rad: float = _p(0.1, 'N*m*s/rad', 'LuGre bristle damping sigma1 (gms: the same damping of '
                                    "the pre-sliding springs, sigma1 / sum(k_i) x the rate of the elements' force)",
                                    'truth')
    stribeck_velocity_rad_s: float = _p(0.002, 'rad/s', 'LuGre Stribeck velocity v_s', 'truth')
    breakaway_ratio: float = _p(1.5, '-', 'breakaway (static) over sliding friction F_S/F_C', 'truth')
    presliding_model: str = _p('lugre', '-', 'pre-sliding form of the truth friction: lugre (Canudas de Wit et al. '
                               '1995, one bristle state) or gms (generalized Maxwell-slip, Al-Bender et al. 2005: '
                               'gms_stiffness_nm_per_rad elements with limits gms_weights x the Stribeck level); the '
                               'static Stribeck curve is the same for both', 'truth')
    gms_stiffness_nm_per_rad: tuple[float, ...] = _p((200.0, 80.0, 30.0, 10.0), 'N*m/rad', 'gms: stiffness k_i of '
                                                     'each Maxwell-slip element', 'truth')
    gms_weights: tuple[float, ...] = _p((0.4, 0.3, 0.2, 0.1), '-', 'gms: share W_i of the Stribeck level each '
                                        'element holds before it slips (sum 1); element i saturates after a '
                                        'displacement W_i s(v) / k_i', 'truth')
    gms_attraction_nm_per_s: float = _p(0.0, 'N*m/s', 'gms: attraction C of the slip law dF_i/dt = C (sgn v - '
                                        'F_i / (W_i s(v))); 0: infinitely fast (a slipping element is dragged at '
                                        'its limit)', 'truth')
    ripple_amplitudes: tuple[float, ...] = _p((0.06, 0.03), '-', 'position ripple: amplitude of each sine as a '
                                              'fraction of the friction', 'truth')
    ripple_periods_deg: tuple[float, ...] = _p((3.4, 0.85), 'deg', 'position ripple: period of each sine in '
                                               'joint angle', 'truth')
    ripple_phases_rad: tuple[float, ...] = _p((0.0, 1.3), 'rad', 'position ripple: phase of each sine', 'truth')
    ripple_cold_gain: float = _p(1.0, '-', 'ripple x (1 + this) at -40 degC, linear to x 1 at +20 degC and above',
                                 'truth')
    asymmetry_enabled: bool = _p(True, '-', 'direction factors from the measured CW/CCW means (false: both '
                                 'directions follow the model)', 'truth')
    asymmetry_temperatures_c: tuple[float, ...] = _p((-40.0, 60.0), 'degC', '[cold, warm] temperatures of the '
                                                     'measured means (paper Sec. 6)', 'truth')
    asymmetry_cw_nmm: tuple[float, ...] = _p((3.19, 1.05), 'N*mm', 'measured mean friction moving positive '
                                             '(CW) at those temperatures (paper Sec. 6)', 'truth')
    asymmetry_ccw_nmm: tuple[float, ...] = _p((2.45, 1.34), 'N*mm', 'measured mean |friction| moving negative '
                                              '(CCW) at those temperatures (paper Sec. 6)', 'truth')
    # --- feedforward transport
    feedforward_latency_s: float = _p(1.0e-3, 's', 'transport latency of the feedforward (node) cases, rounded '
                                      'to whole controller ticks', 'feedforward')
    feedforward_timeout_s: float = _p(0.02, 's', 'the seeker controller adds a feedforward only while it is at most '
                                      'this old (its stamp vs the tick; older: 0 N*m): a stalled link must not '
                                      'apply a torque of the past', 'feedforward')
    # --- profiles
    tracking_speed_rpm: float = _p(1.0 / 3.0, 'rpm', 'tracking profile: LOS speed (paper test: 1/3 rpm)',
                                   'profiles')
    tracking_travel_deg: tuple[float, ...] = _p((-6.0, 11.0), 'deg', 'tracking profile: reversal points '
                                                '(paper: -6..+11 deg)', 'profiles')
    tracking_reversal_s: float = _p(0.2, 's', 'tracking profile: duration of a constant-acceleration reversal',
                                    'profiles')
    tracking_duration_s: float = _p(14.0, 's', 'tracking profile: duration (two reversals)', 'profiles')
    scan_amplitude_deg: float = _p(3.0, 'deg', 'sine scan: amplitude', 'profiles')
    scan_frequency_hz: float = _p(0.5, 'Hz', 'sine scan: frequency', 'profiles')
    scan_duration_s: float = _p(6.0, 's', 'sine scan: duration', 'profiles')
    pointing_duration_s: float = _p(6.0, 's', 'pointing at a fixed target: duration', 'profiles')
    weave_duration_s: float = _p(10.0, 's', 'tracking under base motion (the tracking motion while the body '
                                 'weaves; never in the learning history): duration', 'profiles')
    base_motion_profiles: tuple[str, ...] = _p(('pointing',), '-', 'profiles that run under base motion',
                                               'profiles')
    settle_s: float = _p(1.0, 's', 'initial transient left out of the metrics', 'profiles')
    reversal_window_s: float = _p(0.25, 's', 'half-width of the window around each reversal for the reversal '
                                  'error', 'profiles')
    seed: int = _p(0, '-', 'seed of the sensor noise (numpy default_rng)', 'profiles')

    def __post_init__(self) -> None:
        self.validate()

    # ------------------------------------------------------------------ derived
    @property
    def controller_period_s(self) -> float:
        """Controller period T [s]."""
        return 1.0 / self.rate_loop_hz

    @property
    def plant_step_s(self) -> float:
        """Plant integration step h = T / substeps [s]."""
        return self.controller_period_s / self.plant_substeps

    @property
    def latency_ticks(self) -> int:
        """Feedforward transport latency in whole controller ticks [-]."""
        return int(round(self.feedforward_latency_s * self.rate_loop_hz))

    @property
    def timeout_ticks(self) -> int:
        """Oldest feedforward the controller applies, in whole controller ticks [-]."""
        return int(math.floor(self.feedforward_timeout_s * self.rate_loop_hz + 1e-9))

    def feedforward_fresh(self, age_ticks: int) -> bool:
        """The controller applies a feedforward ``age_ticks`` controller ticks old [-]: 0 <= age <= timeout_ticks
        (a negative age: none received yet)."""
        return 0 <= age_ticks <= self.timeout_ticks

    @property
    def rate_kp_per_s(self) -> float:
        """Rate-loop proportional gain K_p = 2π f_rate [1/s] (torque = J K_p e)."""
        return 2.0 * math.pi * self.rate_bandwidth_hz

    @property
    def rate_ki_per_s(self) -> float:
        """Rate-loop integral corner ω_i = 2π f_i [1/s] (torque = J K_p ω_i ∫e)."""
        return 2.0 * math.pi * self.rate_integral_hz

    @property
    def track_k_per_s(self) -> float:
        """Track-loop gain K_track = 2π f_track [1/s] (rate command = K_track · boresight error)."""
        return 2.0 * math.pi * self.track_bandwidth_hz

    @property
    def track_every_ticks(self) -> int:
        """Controller ticks per tracker frame [-]."""
        return max(1, int(round(self.rate_loop_hz / self.track_loop_hz)))

    @property
    def temperature_every_ticks(self) -> int:
        """Controller ticks per temperature sample [-]."""
        return max(1, int(round(self.rate_loop_hz / self.temperature_rate_hz)))

    def profile_duration_s(self, profile: str) -> float:
        """Configured duration of ``profile`` [s]."""
        return float(getattr(self, f'{profile}_duration_s'))

    # ------------------------------------------------------------------ construction and validation
    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, base: SimConfig | None = None) -> SimConfig:
        """Configuration from parameter values over ``base`` (default: the defaults), validated.

        ``values`` is the flat ``ros__parameters`` mapping of the ``gimbal_sim`` section, the section itself
        (``{'ros__parameters': {...}}``) or a whole parsed parameter file holding a ``gimbal_sim`` section.

        Raises:
            ConfigError: unknown name, wrong type, or a value that breaks a rule.
        """
        values = _section(values)
        fields = {f.name: f for f in dataclasses.fields(cls)}
        node = {f.name for f in dataclasses.fields(RealtimeSettings)}
        start = base if base is not None else cls()
        kwargs: dict[str, Any] = {}
        for name, value in values.items():
            if name in node:   # the gimbal_sim node's own settings share the section
                continue
            if name not in fields:
                hint = did_you_mean(str(name), fields, same_first_word=True)
                raise ConfigError(str(name), f'unknown simulator parameter{hint}', value)
            kwargs[name] = _coerce(name, value, getattr(start, name))
        return dataclasses.replace(start, **kwargs)

    def to_mapping(self) -> dict[str, Any]:
        """Flat mapping of every parameter (tuples as lists), the inverse of :meth:`from_mapping`."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    def replace(self, **changes: Any) -> SimConfig:
        """Validated copy with some parameters changed."""
        return SimConfig.from_mapping(changes, base=self)

    def validate(self) -> None:
        """Check every parameter against its rule.

        Raises:
            ConfigError: naming the parameter and the rule it breaks.
        """
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            items = value if isinstance(value, tuple) else (value,)
            for item in items:
                if isinstance(item, float) and not math.isfinite(item):
                    raise ConfigError(f.name, 'must be finite', value)
        check_rules(self, self._rules())

    def _rules(self) -> list[tuple[str, bool, str]]:
        s = self
        n_base = len(s.base_motion_amplitudes_rad_s)
        n_rip = len(s.ripple_amplitudes)
        cold = 1.0 + s.ripple_cold_gain
        return [
            ('inertia_truth_ratio', 0.0 < s.inertia_truth_ratio <= 100.0, 'must lie in (0, 100] [-]'),
            ('plant_substeps', 1 <= s.plant_substeps <= 1000, 'must be an integer in [1, 1000]'),
            ('current_limit_a', s.current_limit_a > 0.0, 'must be > 0 [A]'),
            ('current_loop_time_constant_s', s.current_loop_time_constant_s >= 0.0, 'must be >= 0 [s]'),
            ('current_noise_a', s.current_noise_a >= 0.0, 'must be >= 0 [A]'),
            ('rate_loop_hz', 10.0 <= s.rate_loop_hz <= 1e5, 'must lie in [10, 100000] [Hz]'),
            ('rate_bandwidth_hz', 0.0 < s.rate_bandwidth_hz <= 0.25 * s.rate_loop_hz,
             'must lie in (0, rate_loop_hz / 4] [Hz]'),
            ('rate_integral_hz', 0.0 <= s.rate_integral_hz < s.rate_bandwidth_hz,
             'must lie in [0, rate_bandwidth_hz) [Hz]'),
            ('track_loop_hz', 0.0 < s.track_loop_hz <= s.rate_loop_hz, 'must lie in (0, rate_loop_hz] [Hz]'),
            ('track_bandwidth_hz', 0.0 <= s.track_bandwidth_hz <= 0.25 * min(s.track_loop_hz, s.rate_bandwidth_hz),
             'must lie in [0, min(track_loop_hz, rate_bandwidth_hz) / 4] [Hz]'),
            ('track_noise_rad', s.track_noise_rad >= 0.0, 'must be >= 0 [rad]'),
            ('gyro_noise_rad_s', s.gyro_noise_rad_s >= 0.0, 'must be >= 0 [rad/s]'),
            ('resolver_noise_rad', s.resolver_noise_rad >= 0.0, 'must be >= 0 [rad]'),
            ('resolver_velocity_noise_rad_s', s.resolver_velocity_noise_rad_s >= 0.0, 'must be >= 0 [rad/s]'),
            ('resolver_velocity_time_constant_s', s.resolver_velocity_time_constant_s >= 0.0, 'must be >= 0 [s]'),
            ('temperature_rate_hz', 0.0 < s.temperature_rate_hz <= s.rate_loop_hz,
             'must lie in (0, rate_loop_hz] [Hz]'),
            ('temperature_noise_c', s.temperature_noise_c >= 0.0, 'must be >= 0 [degC]'),
            ('temperature_sensor_time_constant_s', s.temperature_sensor_time_constant_s >= 0.0, 'must be >= 0 [s]'),
            ('thermal_time_constant_s', s.thermal_time_constant_s >= 0.0, 'must be >= 0 [s]'),
            ('base_motion_amplitudes_rad_s', all(a >= 0.0 for a in s.base_motion_amplitudes_rad_s),
             'must be >= 0 [rad/s]'),
            ('base_motion_frequencies_hz', len(s.base_motion_frequencies_hz) == n_base
             and len(s.base_motion_phases_rad) == n_base,
             'base_motion_amplitudes_rad_s, _frequencies_hz and _phases_rad must have the same length'),
            ('base_motion_frequencies_hz', all(0.0 < f < 0.5 * s.rate_loop_hz for f in s.base_motion_frequencies_hz),
             'must lie in (0, rate_loop_hz / 2) [Hz]'),
            ('truth_walther_a', 0.0 < s.truth_walther_a <= 100.0, 'must lie in (0, 100] [-]'),
            ('truth_walther_b', -1000.0 <= s.truth_walther_b < 0.0, 'must lie in [-1000, 0) [-]'),
            ('lubricant_walther_a_shift', abs(s.lubricant_walther_a_shift) <= 1.0, 'must lie in [-1, 1] [-]'),
            ('truth_palmgren_factor', 0.0 < s.truth_palmgren_factor <= 100.0, 'must lie in (0, 100] [-]'),
            ('truth_torque_constant_nm_per_a', 0.0 < s.truth_torque_constant_nm_per_a <= 100.0,
             'must lie in (0, 100] [N*m/A]'),
            ('truth_no_load_current_a', 0.0 <= s.truth_no_load_current_a <= s.current_limit_a,
             'must lie in [0, current_limit_a] [A]'),
            ('sigma0_nm_per_rad', s.sigma0_nm_per_rad > 0.0, 'must be > 0 [N*m/rad]'),
            ('sigma1_nm_s_per_rad', s.sigma1_nm_s_per_rad >= 0.0, 'must be >= 0 [N*m*s/rad]'),
            ('stribeck_velocity_rad_s', s.stribeck_velocity_rad_s > 0.0, 'must be > 0 [rad/s]'),
            ('breakaway_ratio', 1.0 <= s.breakaway_ratio <= 10.0, 'must lie in [1, 10] [-]'),
            ('presliding_model', s.presliding_model in PRESLIDING_MODELS,
             f'must be one of {", ".join(PRESLIDING_MODELS)}'),
            ('gms_stiffness_nm_per_rad', 1 <= len(s.gms_stiffness_nm_per_rad) <= 20
             and all(k > 0.0 for k in s.gms_stiffness_nm_per_rad), 'must give 1 to 20 stiffnesses > 0 [N*m/rad]'),
            ('gms_weights', len(s.gms_weights) == len(s.gms_stiffness_nm_per_rad)
             and all(w > 0.0 for w in s.gms_weights) and abs(sum(s.gms_weights) - 1.0) <= 1e-3,
             'must give one share > 0 per element of gms_stiffness_nm_per_rad, summing to 1 [-]'),
            ('gms_attraction_nm_per_s', s.gms_attraction_nm_per_s >= 0.0, 'must be >= 0 [N*m/s]'),
            ('ripple_periods_deg', len(s.ripple_periods_deg) == n_rip and len(s.ripple_phases_rad) == n_rip,
             'ripple_amplitudes, ripple_periods_deg and ripple_phases_rad must have the same length'),
            ('ripple_periods_deg', all(p > 0.0 for p in s.ripple_periods_deg), 'must be > 0 [deg]'),
            ('ripple_cold_gain', s.ripple_cold_gain >= 0.0, 'must be >= 0 [-]'),
            ('ripple_amplitudes', all(a >= 0.0 for a in s.ripple_amplitudes) and sum(s.ripple_amplitudes) * cold < 1.0,
             'must be >= 0 with sum x (1 + ripple_cold_gain) < 1 (friction keeps its sign)'),
            ('asymmetry_temperatures_c', len(s.asymmetry_temperatures_c) == 2
             and s.asymmetry_temperatures_c[0] < s.asymmetry_temperatures_c[-1],
             'must be [cold, warm] with cold < warm [degC]'),
            ('asymmetry_cw_nmm', len(s.asymmetry_cw_nmm) == len(s.asymmetry_temperatures_c)
             and all(x > 0.0 for x in s.asymmetry_cw_nmm), 'must give one value > 0 per asymmetry temperature [N*mm]'),
            ('asymmetry_ccw_nmm', len(s.asymmetry_ccw_nmm) == len(s.asymmetry_temperatures_c)
             and all(x > 0.0 for x in s.asymmetry_ccw_nmm),
             'must give one magnitude > 0 per asymmetry temperature [N*mm]'),
            ('feedforward_latency_s', 0.0 <= s.feedforward_latency_s <= 1.0, 'must lie in [0, 1] [s]'),
            ('feedforward_timeout_s', 0.0 < s.feedforward_timeout_s <= 10.0, 'must lie in (0, 10] [s]'),
            ('tracking_speed_rpm', 0.0 < s.tracking_speed_rpm <= 100.0, 'must lie in (0, 100] [rpm]'),
            ('tracking_travel_deg', len(s.tracking_travel_deg) == 2
             and s.tracking_travel_deg[0] < s.tracking_travel_deg[1], 'must be [low, high] with low < high [deg]'),
            ('tracking_reversal_s', s.tracking_reversal_s > 0.0, 'must be > 0 [s]'),
            ('tracking_reversal_s', self._reversal_fits(),
             'reversals must fit in the travel: speed x tracking_reversal_s must be shorter than the travel'),
            ('tracking_duration_s', 0.0 < s.tracking_duration_s <= 3600.0, 'must lie in (0, 3600] [s]'),
            ('scan_amplitude_deg', 0.0 < s.scan_amplitude_deg <= 90.0, 'must lie in (0, 90] [deg]'),
            ('scan_frequency_hz', 0.0 < s.scan_frequency_hz <= 0.25 * s.rate_bandwidth_hz,
             'must lie in (0, rate_bandwidth_hz / 4] [Hz]'),
            ('scan_duration_s', 0.0 < s.scan_duration_s <= 3600.0, 'must lie in (0, 3600] [s]'),
            ('pointing_duration_s', 0.0 < s.pointing_duration_s <= 3600.0, 'must lie in (0, 3600] [s]'),
            ('weave_duration_s', 0.0 < s.weave_duration_s <= 3600.0, 'must lie in (0, 3600] [s]'),
            ('unbalance_torque_nm', abs(s.unbalance_torque_nm) <= 1.0, 'must lie in [-1, 1] [N*m]'),
            ('unbalance_phase_rad', abs(s.unbalance_phase_rad) <= 100.0, 'must lie in [-100, 100] [rad]'),
            ('base_motion_profiles', all(p in PROFILES for p in s.base_motion_profiles),
             f'must name profiles among {", ".join(PROFILES)}'),
            ('settle_s', s.settle_s >= 0.0, 'must be >= 0 [s]'),
            ('reversal_window_s', s.reversal_window_s > 0.0, 'must be > 0 [s]'),
            ('seed', s.seed >= 0, 'must be an integer >= 0'),
        ]

    def _reversal_fits(self) -> bool:
        low, high = (*self.tracking_travel_deg, 0.0, 0.0)[:2]
        speed_deg_s = self.tracking_speed_rpm * 6.0
        return speed_deg_s * self.tracking_reversal_s < (high - low)


#: The parameters that make up the simulated axis's truth, none of them read from the configuration under test:
#: the truth friction (group ``truth``: lubricant, Palmgren factor, motor, LuGre breakaway/Stribeck, ripple, CW/CCW
#: asymmetry), the plant's inertia ratio and disturbance, the bearing's thermal lag and the temperature sensor's
#: offset and lag. A ``loop-study --truth`` file holds only these.
TRUTH_PARAMETERS: tuple[str, ...] = (
    *(f.name for f in dataclasses.fields(SimConfig) if f.metadata['group'] == 'truth'),
    'inertia_truth_ratio', 'disturbance_torque_nm', 'unbalance_torque_nm', 'unbalance_phase_rad',
    'thermal_time_constant_s', 'temperature_bias_c',
    'temperature_sensor_time_constant_s')


def with_truth(base: SimConfig, values: Mapping[str, Any]) -> SimConfig:
    """``base`` with the truth parameters of ``values`` (a flat mapping, a ``gimbal_sim`` section or a parameter
    file holding one), validated; every other parameter keeps ``base``'s value.

    >>> with_truth(SimConfig(), {'temperature_bias_c': 3.0}).temperature_bias_c
    3.0
    >>> with_truth(SimConfig(), {'rate_bandwidth_hz': 30.0})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    gimbal_friction.common.errors.ConfigError: parameter 'rate_bandwidth_hz' = 30.0: is not a truth parameter (...)

    Raises:
        ConfigError: a name that is not a truth parameter, a wrong type, or a value that breaks a rule.
    """
    values = _section(values)
    for name, value in values.items():
        if name not in TRUTH_PARAMETERS:
            raise ConfigError(str(name), f'is not a truth parameter (a truth holds only {", ".join(TRUTH_PARAMETERS)}; '
                              "put the simulator's other parameters in --config)", value)
    return SimConfig.from_mapping(values, base=base)


def truth_differences(config: SimConfig) -> dict[str, Any]:
    """The truth parameters of ``config`` that differ from the defaults (tuples as lists) [units of each]."""
    default, mine = SimConfig().to_mapping(), config.to_mapping()
    return {k: mine[k] for k in TRUTH_PARAMETERS if mine[k] != default[k]}


@dataclass(frozen=True)
class RealtimeSettings:
    """Parameters of the ``gimbal_sim`` node besides the simulator's (:class:`SimConfig`) and the model's."""

    joint: str = setting('', '-', 'simulated axis: a configured joint name (empty: the first configured axis)')
    environment_temperature_c: float = setting(20.0, 'degC', 'environment (chamber) temperature of the run; the '
                                               'bearing starts soaked at it (see initial_bearing_offset_c)')
    profile: str = setting('tracking', '-', 'reference motion: tracking (1/3 rpm with reversals), scan (sine), '
                           'pointing (fixed target under base motion) or weave (tracking under base motion)')
    duration_s: float = setting(0.0, 's', "length of one run; 0: the profile's configured <profile>_duration_s")
    repeat: bool = setting(True, '-', 'start a new run (soaked again) when one ends; false: stop stepping')
    exit_when_done: bool = setting(False, '-', 'end the process after the first run (used by loop-study --live)')
    use_feedforward: bool = setting(True, '-', 'add the effort of /gimbal/friction/feedforward for the joint to the '
                                    'controller output (false: no compensation)')
    realtime_factor: float = setting(1.0, '-', 'simulated seconds per wall-clock second (below 1 on a busy '
                                     'machine); stamps are always the simulated sample times')
    publish_every_ticks: int = setting(1, '-', 'publish /joint_states, /gimbal/motor_current and '
                                       '/gimbal/reference_velocity every this many controller ticks')
    los_error_every_ticks: int = setting(10, '-', 'publish /gimbal_sim/los_error every this many controller '
                                         'ticks')
    publish_reference_velocity: bool = setting(True, '-', 'publish the reference joint velocity (commanded LOS rate '
                                               '- base rate estimate) on /gimbal/reference_velocity')
    wait_for_subscribers: int = setting(0, '-', 'before a run starts, wait until /joint_states has this many '
                                        'subscribers')
    wait_for_feedforward: bool = setting(False, '-', 'before a run starts, wait until /gimbal/friction/feedforward '
                                         'has a publisher (with use_feedforward)')
    start_timeout_s: float = setting(60.0, 's', 'give up waiting for subscribers / the feedforward after this')
    record_path: str = setting('', '-', 'write the traces and latencies of each run to this .npz file when it '
                               'ends (empty: do not)')
    run_seed: int = setting(0, '-', "noise stream of the run (with the simulator's seed; the offline study uses 0)")
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        checks = [
            ('environment_temperature_c', -60.0 <= self.environment_temperature_c <= 120.0,
             'must lie in [-60, 120] [degC]'),
            ('profile', self.profile in PROFILES, f'must be one of {", ".join(PROFILES)}'),
            ('duration_s', 0.0 <= self.duration_s <= 86400.0, 'must lie in [0, 86400] [s]'),
            ('realtime_factor', 0.01 <= self.realtime_factor <= 100.0, 'must lie in [0.01, 100] [-]'),
            ('publish_every_ticks', 1 <= self.publish_every_ticks <= 10000, 'must be an integer in [1, 10000]'),
            ('los_error_every_ticks', 1 <= self.los_error_every_ticks <= 100000,
             'must be an integer in [1, 100000]'),
            ('wait_for_subscribers', 0 <= self.wait_for_subscribers <= 100, 'must be an integer in [0, 100]'),
            ('start_timeout_s', 0.0 < self.start_timeout_s <= 3600.0, 'must lie in (0, 3600] [s]'),
            ('run_seed', self.run_seed >= 0, 'must be an integer >= 0'),
            ('diagnostics_period_s', 0.05 <= self.diagnostics_period_s <= 60.0, 'must lie in [0.05, 60] [s]'),
        ]
        check_rules(self, checks)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, base: RealtimeSettings | None = None) -> RealtimeSettings:
        """The node settings of a ``gimbal_sim`` section (as :meth:`SimConfig.from_mapping`; the simulator's own
        parameters are ignored), validated.

        Raises:
            ConfigError: wrong type or a value that breaks a rule.
        """
        values = _section(values)
        names = {f.name for f in dataclasses.fields(cls)}
        return settings_from(cls, {k: v for k, v in values.items() if k in names}, base)


def _section(values: Mapping[str, Any]) -> Mapping[str, Any]:
    """The flat parameters of a parameter file, its ``gimbal_sim`` section, or the flat mapping itself."""
    if not isinstance(values, Mapping):
        raise ConfigError(SECTION, 'parameters must be a mapping of names to values', type(values).__name__)
    if SECTION in values or '/' + SECTION in values:
        values = values.get(SECTION, values.get('/' + SECTION))
        if not isinstance(values, Mapping):
            raise ConfigError(SECTION, 'section must hold a ros__parameters mapping')
    if 'ros__parameters' in values:
        values = values['ros__parameters']
        if not isinstance(values, Mapping):
            raise ConfigError(SECTION, 'ros__parameters must be a mapping of names to values')
    return values


def _coerce(name: str, value: Any, current: Any) -> Any:
    """``value`` converted to the type of the parameter's current value (the one rule of
    :func:`gimbal_friction.common.settings.coerce`: NaN and inf refused as by the nodes)."""
    return coerce(name, value, current, names=name in _NAME_LISTS)


def parameter_specs(*, node: bool = False) -> list[dict[str, Any]]:
    """Name, default, unit, description and group of every simulator parameter (for the YAML, node, docs);
    with ``node`` also the ``gimbal_sim`` node's settings (group ``node``)."""
    out = []
    for f in dataclasses.fields(SimConfig):
        out.append({'name': f.name, 'default': f.default, **f.metadata})
    if node:
        for f in dataclasses.fields(RealtimeSettings):
            out.append({'name': f.name, 'default': f.default, 'group': 'node', **f.metadata})
    return out


_FILE_HEADER = """\
# gimbal_sim parameters: the closed-loop gimbal-axis simulator (gimbal_friction.sim), a ROS 2 parameters file
# section read by the gimbal_sim node and by gimbal-friction loop-study (--config, layered key by key).
# The configured model of the axis (K_T, I_0, J = inertia_kg_m2, bearing, lubricant: what the controller, the
# feedforward and the estimator use) comes from config/gimbal_friction.yaml (/** model.*, axis.<joint>.*). The
# truth is this file's own (group 'truth', plus the sensors' bias and lag and the thermal lag) and never reads that
# configuration: the paper's bearing with the truth lubricant (truth_walther_a + lubricant_walther_a_shift,
# truth_walther_b), Palmgren factor and motor, LuGre pre-sliding/breakaway, position ripple and the paper's measured
# CW/CCW means. Units are in the names and the comments; every value is SI except where named.
# Why each default: see the docstring of gimbal_friction/sim/config.py. The 'node' group is read by the gimbal_sim
# node only. This file is generated by gimbal_friction.sim.config.parameter_file_text() (tested to match).
"""


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml_scalar(v) for v in value) + ']'
    text = repr(value)
    if isinstance(value, float) and 'e' in text and '.' not in text:
        text = text.replace('e', '.0e')   # YAML 1.1 (and rcl) read 5e-06 as a string, 5.0e-06 as a double
    return text


def parameter_file_text() -> str:
    """Text of ``config/gimbal_sim.yaml``: every parameter (simulator and node) with its default, unit and
    description, grouped."""
    lines = [_FILE_HEADER.rstrip('\n'), f'{SECTION}:', '  ros__parameters:']
    group = None
    for spec in parameter_specs(node=True):
        if spec['group'] != group:
            group = spec['group']
            lines.append(f'    # --- {group}')
        entry = f'    {spec["name"]}: {_yaml_scalar(spec["default"])}'
        lines.append(f'{entry:<58s} # [{spec["unit"]}] {spec["description"]}')
    return '\n'.join(lines) + '\n'
