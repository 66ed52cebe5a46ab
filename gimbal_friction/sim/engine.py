r"""Fixed-step closed-loop simulation of a gimbal axis, vectorised over independent runs.

The plant (one rigid axis, inertial angle θ and rate ω of the LOS, base rate ω_B of the missile body)::

    J dω/dt = K_T i − F + τ_dist + τ_u sin(θ − θ_B + φ_u),      F = truth friction (LuGre or GMS) at v = ω − ω_B
    τ_i di/dt = i_cmd − i,             i_cmd = clip(i_fb + τ_ff / K_T, ±current_limit)

Friction acts on the rate of the gimbal *relative to the base*, so base motion reaches the LOS through friction
(Lagunowich et al. 2007, the paper's introduction). The plant integrates at ``plant_substeps`` steps per
controller tick (explicit Euler for ω, trapezoidal θ, exact exponential updates for the current loop and the LuGre
deflection, see :func:`~gimbal_friction.sim.lugre.lugre_z_step`, or the exact stick/slip update of the GMS elements,
:func:`~gimbal_friction.sim.gms.gms_step_AlBender_2005`); the controller runs at ``rate_loop_hz`` with a
zero-order hold. The friction of a step is that of the deflection at its end, so the pre-sliding spring and the
inertia form a symplectic-Euler pair, stable while ``h √(K/J) < 2`` (``K`` the contact's initial stiffness, ``J`` the
plant's inertia); a GMS truth is refused above 1.5 (raise ``plant_substeps``).

Sensors at each tick: the LOS rate gyro (inertial rate + bias + noise), the resolver (joint angle θ − θ_B and the
RDC velocity: the relative rate behind a first-order filter, + noise), the tracker's boresight error θ_T − θ at
``track_loop_hz`` (+ noise), the motor-current sensor (+ noise) and the bearing temperature sensor at
``temperature_rate_hz`` (a first-order lag behind the bearing, + bias + noise). The bearing temperature follows
the environment (the run's plateau, plus an optional ramp) with a first-order lag.

The seeker controller: outer track loop ω_c = ω_T + K_track e_b (target rate as feedforward), inner rate PI on
the gyro i_fb = J (K_p e + K_p ω_i ∫e) / K_T (nominal J and K_T; conditional-integration anti-windup while the
drive saturates). Compensations (:mod:`gimbal_friction.sim.compensation`) add a torque τ_ff; the ``ideal`` case
cancels the truth friction of the current state exactly at every plant step (its current K_T⁻¹ F is counted in
the motor current).

Every run has its own environment temperature, case and noise seed, so a batch of runs is the same as the runs
one by one (tested); runs with the same seed see the same sensor noise (common random numbers across cases).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.compensation import CASE_IDEAL, CASE_NONE, Compensator, ControllerInputs
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.gms import gms_force_AlBender_2005, gms_step_AlBender_2005
from gimbal_friction.sim.lugre import lugre_force_1995, lugre_z_step
from gimbal_friction.sim.profiles import Profile
from gimbal_friction.sim.truth import TemperatureTerms, TruthFriction, TruthTerms, ripple
from gimbal_friction.streams.arrays import ChamberArrays, JointStateArrays, TemperatureArrays

Array = NDArray[np.float64]

__all__ = ['BatchResult', 'ClosedLoop', 'EstimatorTrace', 'Plant', 'Run', 'Traces', 'simulate']

#: The truth's temperature-dependent terms are recomputed when a bearing temperature moved more than this [°C].
TRUTH_TEMPERATURE_RESOLUTION_C = 0.01
#: Noise channels (standard normal draws per tick and run), in this order.
_NOISE = ('gyro', 'resolver', 'velocity', 'track', 'temperature', 'current')


class Run(NamedTuple):
    """One independent run of a batch."""

    case: str              #: ``none``, ``ideal`` or a key of the compensators
    temperature_c: float   #: environment temperature (plateau) [°C]
    seed: int = 0          #: sensor-noise stream (with ``SimConfig.seed``)


class Traces(NamedTuple):
    """Per-run time series at the controller ticks, each of shape (ticks, runs)."""

    los_angle_rad: Array              #: true inertial LOS angle θ [rad]
    los_rate_rad_s: Array             #: true inertial LOS rate ω [rad/s]
    joint_position_rad: Array         #: resolver angle (measured) [rad]
    joint_velocity_rad_s: Array       #: resolver (RDC) velocity (measured) [rad/s]
    joint_velocity_true_rad_s: Array  #: true relative rate ω − ω_B [rad/s]
    current_a: Array                  #: true motor current at the tick [A]
    current_measured_a: Array         #: motor current as the sensor reads it [A]
    current_command_a: Array          #: commanded current after the limit [A]
    temperature_c: Array              #: measured bearing temperature (held between samples) [°C]
    bearing_temperature_c: Array      #: true bearing temperature [°C]
    gyro_rate_rad_s: Array            #: gyro reading [rad/s]
    rate_command_rad_s: Array         #: rate command of the outer loop ω_c [rad/s]
    reference_velocity_rad_s: Array   #: reference joint velocity ω_c − (gyro − resolver rate) [rad/s]
    friction_nm: Array                #: truth friction torque F at the end of the tick [N·m]
    feedforward_nm: Array             #: compensation torque applied at the tick (after the latency) [N·m]
    feedforward_computed_nm: Array    #: compensation torque computed from this tick's inputs (what a feedforward
    #: node publishes for this tick's joint state; applied ``latency_ticks`` later) [N·m]


class EstimatorTrace(NamedTuple):
    """What the suite's estimator and logger would receive from one run, at the controller rate."""

    run: Run
    stamp_ns: NDArray[np.int64]       #: message stamps [ns]
    joint_position_rad: Array         #: /joint_states position [rad]
    joint_velocity_rad_s: Array       #: /joint_states velocity [rad/s]
    current_a: Array                  #: /gimbal/motor_current [A]
    temperature_c: Array              #: /gimbal/temperature at every tick (held) [°C]
    temperature_sampled: NDArray[np.bool_]  #: ticks where a new temperature sample was published
    gyro_rate_rad_s: Array            #: gyro [rad/s]

    def chamber_arrays(self, joint: str = 'elevation', every: int = 1) -> ChamberArrays:
        """The trace as the suite's input streams (log time = stamp), joint states and current every ``every``
        ticks (e.g. 10: 100 Hz from a 1 kHz controller), temperature at its own sample ticks."""
        if every < 1:
            raise ConfigError('every', 'must be an integer >= 1', every)
        sel = slice(None, None, every)
        stamps = np.asarray(self.stamp_ns[sel], dtype=np.int64)
        t_idx = np.flatnonzero(self.temperature_sampled)
        t_stamps = np.asarray(self.stamp_ns[t_idx], dtype=np.int64)
        temperature = TemperatureArrays(t_stamps, t_stamps.copy(), np.asarray(self.temperature_c[t_idx]))
        nan = np.full(stamps.shape, np.nan)
        joints = JointStateArrays(stamps, stamps.copy(), (joint,), {joint: self.joint_position_rad[sel].copy()},
                                  {joint: self.joint_velocity_rad_s[sel].copy()}, {joint: nan})
        current = JointStateArrays(stamps.copy(), stamps.copy(), (joint,), {joint: nan.copy()}, {joint: nan.copy()},
                                   {joint: self.current_a[sel].copy()})
        return ChamberArrays(temperature, joints, current)


class BatchResult(NamedTuple):
    """A simulated batch: configuration, profile, runs and their traces."""

    config: SimConfig
    profile: Profile
    runs: tuple[Run, ...]
    traces: Traces
    temperature_sampled: NDArray[np.bool_]   #: ticks where the temperature sensor published, (ticks,)

    def estimator_trace(self, index: int, start_ns: int = 0) -> EstimatorTrace:
        """The estimator's inputs of run ``index``, stamped from ``start_ns`` [ns]."""
        tr = self.traces
        stamps = start_ns + np.round(self.profile.time_s * NS_PER_S).astype(np.int64)
        return EstimatorTrace(self.runs[index], stamps, tr.joint_position_rad[:, index].copy(),
                              tr.joint_velocity_rad_s[:, index].copy(), tr.current_measured_a[:, index].copy(),
                              tr.temperature_c[:, index].copy(), self.temperature_sampled.copy(),
                              tr.gyro_rate_rad_s[:, index].copy())


class Plant:
    """The rigid axis with its current loop and the truth friction (LuGre or GMS), vectorised over runs.

    State per run: inertial LOS angle ``theta`` [rad] and rate ``omega`` [rad/s], bristle deflection ``z`` [rad]
    (LuGre) or the GMS element forces ``gms_force`` [N·m] and slip states ``gms_slipping``, shape (runs, elements),
    motor current ``current`` [A]; ``friction`` is the truth torque of the last step [N·m].
    :meth:`advance` integrates one controller tick in ``plant_substeps`` steps: explicit Euler for ω with the
    torque of the step (the friction from the bristle deflection at the end of the step), the trapezoidal rule for
    θ (exact under constant torque), exact exponential updates for the current loop and the bristle deflection.

    Parameters
    ----------
    config : SimConfig
        Inertia ratio, disturbance, current loop, sub-steps.
    axis : AxisParams
        The configured J (the plant's is ``J · inertia_truth_ratio``); the truth friction and the plant's K_T are
        the simulator's own (``config``, see :class:`TruthFriction`), whatever the configured model says.
    theta, omega : array_like
        Initial angle [rad] and rate [rad/s], one per run.
    cancel_friction : array_like of bool, optional
        Runs whose friction is cancelled exactly (case ``ideal``); their current includes F/K_T.

    Raises:
        ConfigError: a GMS truth too stiff for the plant step (``h √(Σk_i/J) > 1.5``).
    """

    def __init__(self, config: SimConfig, axis: AxisParams, theta: Array, omega: Array,
                 cancel_friction: NDArray[np.bool_] | None = None) -> None:
        m = theta.shape[0]
        self.truth = TruthFriction(config)
        self.J = axis.inertia_kg_m2 * config.inertia_truth_ratio
        self.K_T = config.truth_torque_constant_nm_per_a
        self.substeps = config.plant_substeps
        self.h = config.plant_step_s
        tau_i = config.current_loop_time_constant_s
        self.decay_i = math.exp(-self.h / tau_i) if tau_i > 0.0 else 0.0
        self.tau_dist = config.disturbance_torque_nm
        self.theta = np.array(theta, dtype=float)
        self.omega = np.array(omega, dtype=float)
        self.z = np.zeros(m)
        n_el = self.truth.gms_stiffness.size if self.truth.presliding == 'gms' else 0
        self.gms_force = np.zeros((m, n_el))
        self.gms_slipping = np.zeros((m, n_el), dtype=bool)
        if n_el and self.h * math.sqrt(self.truth.presliding_stiffness_nm_per_rad / self.J) > 1.5:
            raise ConfigError('gms_stiffness_nm_per_rad', 'too stiff for the plant step: h sqrt(sum(k_i) / J) must be '
                              '<= 1.5 (raise plant_substeps)', config.gms_stiffness_nm_per_rad)
        self.current = np.zeros(m)
        self.friction = np.zeros(m)
        cancel = np.zeros(m, dtype=bool) if cancel_friction is None else np.asarray(cancel_friction, dtype=bool)
        self.cancel = cancel
        self._keep = np.where(cancel, 0.0, 1.0)

    @property
    def motor_current(self) -> Array:
        """Motor current [A], including the ideal compensation's F/K_T in the cancelled runs."""
        return np.asarray(self.current + self.cancel * self.friction / self.K_T)

    def advance(self, i_cmd: Array, base_rates: Array, terms: TruthTerms, ripple_factor: Array | float,
                external_nm: Array | float = 0.0) -> None:
        """Integrate one controller tick with the commanded current ``i_cmd`` [A] held (zero-order hold).

        ``base_rates`` [rad/s] is the body rate at the start of every sub-step, shape (substeps,);
        ``terms`` and ``ripple_factor`` (1 + r) the truth's temperature terms and position ripple of the tick;
        ``external_nm`` a torque held over the tick besides the constant disturbance (the angle-dependent
        unbalance) [N·m].
        """
        truth, h, J, K_T = self.truth, self.h, self.J, self.K_T
        sigma0, sigma1 = truth.sigma0, truth.sigma1
        theta, omega, z, current = self.theta, self.omega, self.z, self.current
        friction = self.friction
        gms = truth.presliding == 'gms'
        f_el, slipping = self.gms_force, self.gms_slipping
        k_total = truth.presliding_stiffness_nm_per_rad
        for j in range(self.substeps):
            v = omega - base_rates[j]
            current = i_cmd + (current - i_cmd) * self.decay_i
            g = truth.stribeck_level_nm(terms, v, ripple_factor)
            if gms:
                f_new, slipping = gms_step_AlBender_2005(f_el, slipping, v, g, truth.gms_stiffness,
                                                         truth.gms_weights, h, truth.gms_attraction)
                friction = gms_force_AlBender_2005(f_new, (f_new.sum(axis=-1) - f_el.sum(axis=-1)) / h, v,
                                                   k_total, sigma1)
                f_el = f_new
            else:
                z_new = lugre_z_step(z, v, g, sigma0, h)
                friction = lugre_force_1995(z_new, (z_new - z) / h, v, sigma0, sigma1)
                z = z_new
            omega_new = omega + h * (K_T * current - self._keep * friction + self.tau_dist + external_nm) / J
            theta = theta + 0.5 * h * (omega + omega_new)
            omega = omega_new
        self.theta, self.omega, self.z, self.current, self.friction = theta, omega, z, current, friction
        self.gms_force, self.gms_slipping = f_el, slipping


def _noise(config: SimConfig, runs: Sequence[Run], n: int) -> Array:
    """Scaled sensor noise, shape (channels, ticks, runs); one stream per distinct run seed."""
    seeds = sorted({r.seed for r in runs})
    draws = {s: np.random.default_rng([config.seed, s]).standard_normal((len(_NOISE), n)) for s in seeds}
    out = np.stack([draws[r.seed] for r in runs], axis=-1)
    sigma = np.array([config.gyro_noise_rad_s, config.resolver_noise_rad, config.resolver_velocity_noise_rad_s,
                      config.track_noise_rad, config.temperature_noise_c, config.current_noise_a])
    return np.asarray(out * sigma[:, None, None])


def _update_terms(old: TruthTerms, new: TruthTerms, moved: NDArray[np.bool_]) -> TruthTerms:
    """``new`` where ``moved``, else ``old``, field by field."""
    model = TemperatureTerms(*(np.where(moved, n, o) for n, o in zip(new.model, old.model, strict=True)))
    return TruthTerms(model, np.where(moved, new.k_positive, old.k_positive),
                      np.where(moved, new.k_negative, old.k_negative))


def _lag_step(x: Array, u0: Array, rate: float | Array, dt: float, tau: float) -> Array:
    """Exact first-order lag step τ dx/dt = u − x over ``dt`` for an input ramp u = u0 + rate·s."""
    if tau <= 0.0:
        return np.asarray(u0 + rate * dt)
    e = math.exp(-dt / tau)
    return np.asarray(u0 + rate * dt - rate * tau + (x - u0 + rate * tau) * e)


class ClosedLoop:
    """The closed loop of a batch of runs, advanced one controller tick at a time.

    :func:`simulate` runs it to the end of the profile; a real-time adapter (the later ``gimbal_sim`` node) can
    call :meth:`step` at wall-clock pace, publish :meth:`last` and feed the received feedforward through a
    compensator hook. Parameters as :func:`simulate`.

    Raises:
        ConfigError: an unknown case, no runs, or a profile sampled with another controller rate.
    """

    def __init__(self, config: SimConfig, axis: AxisParams, profile: Profile, runs: Sequence[Run],
                 compensators: Mapping[str, Compensator] | None = None) -> None:
        comps = dict(compensators or {})
        if not runs:
            raise ConfigError('runs', 'needs at least one run')
        for r in runs:
            if r.case not in (CASE_NONE, CASE_IDEAL) and r.case not in comps:
                raise ConfigError('case', f'no compensator for this case (have none, ideal, {", ".join(comps)})',
                                  r.case)
            if not math.isfinite(r.temperature_c) or not -100.0 <= r.temperature_c <= 200.0:
                raise ConfigError('temperature_c', 'must lie in [-100, 200] [degC]', r.temperature_c)
        n = profile.time_s.shape[0]
        if profile.base_rate_rad_s.shape != (n, config.plant_substeps) or (
                n > 1 and not math.isclose(profile.time_s[1] - profile.time_s[0], config.controller_period_s)):
            raise ConfigError('profile', 'was sampled with another controller rate or plant_substeps')
        m = len(runs)
        self.config, self.axis, self.profile, self.runs = config, axis, profile, tuple(runs)
        self.ticks = n
        self.k = 0
        tau_v = config.resolver_velocity_time_constant_s
        self._alpha_v = 1.0 - math.exp(-config.controller_period_s / tau_v) if tau_v > 0.0 else 1.0
        self._noise = _noise(config, runs, n)
        # cases: (compensator, run indices, all runs?, latency buffer)
        ideal = np.array([r.case == CASE_IDEAL for r in runs])
        self._groups: list[tuple[Compensator, NDArray[np.intp], bool, Array]] = []
        for name, comp in comps.items():
            idx = np.flatnonzero([r.case == name for r in runs])
            if idx.size:
                depth = config.latency_ticks if comp.delayed else 0
                self._groups.append((comp, idx, idx.size == m, np.zeros((depth + 1, idx.size))))
        # state
        self._env0 = np.array([r.temperature_c for r in runs], dtype=float)
        self.plant = Plant(config, axis, np.full(m, profile.target_angle_rad[0]),
                           np.full(m, profile.target_rate_rad_s[0]), ideal)
        self._integ = np.zeros(m)
        self.bearing = self._env0 + config.initial_bearing_offset_c
        self._sensor_t = self.bearing.copy()
        self._v_filter = self.plant.omega - profile.base_rate_rad_s[0, 0]
        self._boresight = np.zeros(m)
        self._measured_t = np.full(m, np.nan)
        self._measured_t_time = np.full(m, np.nan)
        self._terms = self.plant.truth.terms(self.bearing)
        self._terms_at = self.bearing.copy()
        self._bias = config.gyro_bias_rad_s + np.zeros(m)
        self.sampled = np.zeros(n, dtype=bool)
        self._rec = {f: np.empty((n, m)) for f in Traces._fields}

    @property
    def done(self) -> bool:
        """All ticks of the profile simulated."""
        return bool(self.k >= self.ticks)

    def last(self) -> Traces:
        """The values recorded at the last tick, arrays of shape (runs,) (views into the traces)."""
        k = max(self.k - 1, 0)
        return Traces(**{f: v[k] for f, v in self._rec.items()})

    def result(self) -> BatchResult:
        """The batch so far (traces of the ticks simulated)."""
        k = self.k
        prof = self.profile
        cut = Profile(prof.name, prof.time_s[:k], prof.target_angle_rad[:k], prof.target_rate_rad_s[:k],
                      prof.base_angle_rad[:k], prof.base_rate_rad_s[:k], prof.reversal_times_s, prof.base_motion)
        traces = Traces(**{f: v[:k] for f, v in self._rec.items()})
        return BatchResult(self.config, cut if k < self.ticks else prof, self.runs, traces, self.sampled[:k])

    def step(self) -> None:
        """Simulate one controller tick: sensors, controller (+ compensations), plant, thermal.

        Raises:
            ConfigError: the profile is over.
        """
        k = self.k
        if k >= self.ticks:
            raise ConfigError('tick', 'the profile is over', k)
        cfg, prof, plant, rec = self.config, self.profile, self.plant, self._rec
        T = cfg.controller_period_s
        K_T = self.axis.torque_constant_nm_per_a
        limit = cfg.current_limit_a
        kp, ki = cfg.rate_kp_per_s, cfg.rate_ki_per_s
        n_gyro, n_res, n_vel, n_track, n_temp, n_cur = self._noise
        t_k = float(prof.time_s[k])
        theta, omega = plant.theta, plant.omega
        bearing = self.bearing
        # ---------------------------------------------------------------- sensors
        joint_true = theta - prof.base_angle_rad[k]
        gyro = omega + self._bias + n_gyro[k]
        joint_meas = joint_true + n_res[k]
        vel_meas = self._v_filter + n_vel[k]
        if k % cfg.track_every_ticks == 0:
            self._boresight = prof.target_angle_rad[k] - theta + n_track[k]
        if k % cfg.temperature_every_ticks == 0 and not 0.0 <= cfg.temperature_stop_s <= t_k:
            self._measured_t = self._sensor_t + cfg.temperature_bias_c + n_temp[k]
            self._measured_t_time = np.full(theta.shape, t_k)
            self.sampled[k] = True
        measured_t = self._measured_t
        # ---------------------------------------------------------------- controller
        rate_cmd = prof.target_rate_rad_s[k] + cfg.track_k_per_s * self._boresight
        err = rate_cmd - gyro
        i_raw = self.axis.inertia_kg_m2 * (kp * err + self._integ) / K_T
        tau_ff = np.zeros(theta.shape)
        tau_new = np.zeros(theta.shape)
        reference = rate_cmd - (gyro - vel_meas)
        if self._groups:
            inputs = ControllerInputs(t_k, measured_t, self._measured_t_time, joint_meas, vel_meas, reference, gyro)
            for comp, idx, whole, buf in self._groups:
                sub = inputs if whole else ControllerInputs(
                    t_k, measured_t[idx], self._measured_t_time[idx], joint_meas[idx], vel_meas[idx],
                    inputs.reference_velocity_rad_s[idx], gyro[idx])
                out = np.broadcast_to(np.asarray(comp.torque(sub), dtype=float), (idx.size,))
                if buf.shape[0] > 1:
                    buf[1:] = buf[:-1]
                buf[0] = out
                tau_ff[idx] = buf[-1] if cfg.feedforward_fresh(buf.shape[0] - 1) else 0.0   # too old: not applied
                tau_new[idx] = out
            i_raw = i_raw + tau_ff / K_T
        i_cmd = np.clip(i_raw, -limit, limit)
        wind = ((i_raw > limit) & (err > 0.0)) | ((i_raw < -limit) & (err < 0.0))
        self._integ = self._integ + np.where(wind, 0.0, kp * ki * T * err)
        # ---------------------------------------------------------------- record
        rec['los_angle_rad'][k] = theta
        rec['los_rate_rad_s'][k] = omega
        rec['joint_position_rad'][k] = joint_meas
        rec['joint_velocity_rad_s'][k] = vel_meas
        rec['joint_velocity_true_rad_s'][k] = omega - prof.base_rate_rad_s[k, 0]
        i_total = plant.motor_current
        rec['current_a'][k] = i_total
        rec['current_measured_a'][k] = i_total + n_cur[k]
        rec['current_command_a'][k] = i_cmd
        rec['temperature_c'][k] = measured_t
        rec['bearing_temperature_c'][k] = bearing
        rec['gyro_rate_rad_s'][k] = gyro
        rec['rate_command_rad_s'][k] = rate_cmd
        rec['reference_velocity_rad_s'][k] = reference
        rec['feedforward_nm'][k] = tau_ff
        rec['feedforward_computed_nm'][k] = tau_new
        # ---------------------------------------------------------------- plant
        moved = np.abs(bearing - self._terms_at) > TRUTH_TEMPERATURE_RESOLUTION_C
        if moved.any():   # per run, so a batch gives the same numbers as its runs one by one
            self._terms = _update_terms(self._terms, plant.truth.terms(bearing), moved)
            self._terms_at = np.where(moved, bearing, self._terms_at)
        unbalance = cfg.unbalance_torque_nm * np.sin(joint_true + cfg.unbalance_phase_rad) \
            if cfg.unbalance_torque_nm else 0.0
        plant.advance(i_cmd, prof.base_rate_rad_s[k], self._terms, 1.0 + ripple(cfg, joint_true, bearing), unbalance)
        rec['friction_nm'][k] = plant.friction
        self._v_filter = self._v_filter + self._alpha_v * (
            plant.omega - prof.base_rate_rad_s[k, cfg.plant_substeps - 1] - self._v_filter)
        # ---------------------------------------------------------------- thermal
        ramp = cfg.environment_ramp_c_per_s
        new_bearing = _lag_step(bearing, self._env0 + ramp * t_k, ramp, T, cfg.thermal_time_constant_s)
        self._sensor_t = _lag_step(self._sensor_t, bearing, (new_bearing - bearing) / T, T,
                                   cfg.temperature_sensor_time_constant_s)
        self.bearing = new_bearing
        self.k = k + 1


def simulate(config: SimConfig, axis: AxisParams, profile: Profile, runs: Sequence[Run],
             compensators: Mapping[str, Compensator] | None = None, *,
             progress: Callable[[float], None] | None = None) -> BatchResult:
    """Simulate ``runs`` of ``profile`` in closed loop, all in one vectorised fixed-step loop.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration.
    axis : AxisParams
        The configured model of the axis (K_T, I_0, J and the friction model: the configuration under test, used by
        the controller and the compensations; the truth is ``config``'s own).
    profile : Profile
        Reference and base motion (:func:`~gimbal_friction.sim.profiles.make_profile` with the same config).
    runs : sequence of Run
        Independent runs (case, environment temperature, noise seed).
    compensators : mapping of str to Compensator, optional
        The compensation of each case other than ``none`` and ``ideal``; each is called once per tick with the
        inputs of its runs.
    progress : callable, optional
        Called with the fraction done (0..1) about a hundred times.

    Raises:
        ConfigError: an unknown case, no runs, or a profile sampled with another controller rate.
    """
    loop = ClosedLoop(config, axis, profile, runs, compensators)
    n = loop.ticks
    every = max(1, n // 100)
    for k in range(n):
        loop.step()
        if progress is not None and (k % every == 0 or k == n - 1):
            progress((k + 1) / n)
    return loop.result()
