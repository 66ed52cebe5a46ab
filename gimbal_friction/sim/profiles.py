"""Reference profiles of the LOS and the missile body (base) motion, sampled for the simulation.

Three profiles (inertial LOS target angle θ_T(t) and rate ω_T(t); the seeker's tracker sees the boresight error
θ_T − θ_LOS, and the target rate is the rate loop's feedforward):

``tracking``
    slow tracking with reversals, the paper's test motion (Sec. 6): a triangle wave between
    ``tracking_travel_deg`` (−6…+11°) at ``tracking_speed_rpm`` (1/3 rpm = 0.0349 rad/s) with constant-acceleration
    reversals of ``tracking_reversal_s`` (the extremes are exactly the travel limits). It starts at rest at the
    middle of the travel, so with the defaults the reversals are at 4.35 s (top) and 12.95 s (bottom).
``scan``
    a sine scan θ_T = −A cos(2π f t) (starts at rest at −A; reversals every half period).
``pointing``
    a fixed target θ_T = 0.
``weave``
    the tracking motion while the missile body weaves (always under base motion, whatever ``base_motion_profiles``
    says): a seeker tracking a target from a manoeuvring airframe. Never part of the learning history
    (:func:`history_profile`), so the learned correction is scored on a motion it never saw.

A profile listed in ``base_motion_profiles`` (default: ``pointing``) runs under base motion, the missile body rate
ω_B(t) = Σ A_k sin(2π f_k t + φ_k) (body angle θ_B(0) = 0). The gimbal joint angle (what the resolver measures) is
θ_LOS − θ_B, its rate ω_LOS − ω_B, and friction acts on that relative rate.

Reversals are the zero crossings of the reference joint velocity ω_T − ω_B (interpolated between ticks): the
tracking and scan turn-arounds, or, under base motion, every sign change of the relative motion.

>>> from gimbal_friction.sim.config import SimConfig
>>> p = make_profile(SimConfig(), 'tracking')
>>> [round(float(t), 2) for t in p.reversal_times_s]
[4.35, 12.95]
>>> round(float(p.target_angle_rad.max()), 6) == round(math.radians(11.0), 6)
True
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.units import RAD_S_PER_RPM
from gimbal_friction.sim.config import PROFILES, SimConfig

Array = NDArray[np.float64]

__all__ = ['HISTORY', 'Profile', 'base_motion', 'history_profile', 'make_profile', 'trapezoid_velocity_profile',
           'zero_crossings']


class Profile(NamedTuple):
    """A profile sampled at the controller ticks (and the base rate at every plant sub-step)."""

    name: str
    time_s: Array                   #: controller tick times, shape (n,) [s]
    target_angle_rad: Array         #: inertial LOS target angle θ_T, (n,) [rad]
    target_rate_rad_s: Array        #: inertial LOS target rate ω_T, (n,) [rad/s]
    base_angle_rad: Array           #: body angle θ_B at the ticks, (n,) [rad]
    base_rate_rad_s: Array          #: body rate ω_B at every plant sub-step start, (n, substeps) [rad/s]
    reversal_times_s: Array         #: zero crossings of ω_T − ω_B [s]
    base_motion: bool               #: runs under base motion

    @property
    def reference_joint_velocity_rad_s(self) -> Array:
        """Reference joint velocity ω_T − ω_B at the ticks, (n,) [rad/s]."""
        return self.target_rate_rad_s - self.base_rate_rad_s[:, 0]

    @property
    def nominal_speed_rad_s(self) -> float:
        """Mean |ω_T − ω_B| over the profile, the speed a constant compensation is tuned at [rad/s]."""
        return float(np.mean(np.abs(self.reference_joint_velocity_rad_s)))


def base_motion(config: SimConfig, t_s: ArrayLike) -> tuple[Array, Array]:
    """Missile body angle θ_B [rad] and rate ω_B [rad/s] at times ``t_s`` [s]: a sum of sines, θ_B(0) = 0.

    ``ω_B = Σ A_k sin(2π f_k t + φ_k)``, ``θ_B = Σ A_k/(2π f_k) (cos φ_k − cos(2π f_k t + φ_k))``.

    >>> c = SimConfig(base_motion_amplitudes_rad_s=(0.1,), base_motion_frequencies_hz=(1.0,),
    ...               base_motion_phases_rad=(0.0,))
    >>> angle, rate = base_motion(c, [0.0, 0.25, 0.5])
    >>> [round(float(x), 6) for x in rate], [round(float(x), 6) for x in angle]
    ([0.0, 0.1, 0.0], [0.0, 0.015915, 0.031831])
    """
    t = np.asarray(t_s, dtype=float)
    angle = np.zeros(t.shape)
    rate = np.zeros(t.shape)
    for a, f, phi in zip(config.base_motion_amplitudes_rad_s, config.base_motion_frequencies_hz,
                         config.base_motion_phases_rad, strict=True):
        w = 2.0 * math.pi * f
        rate += a * np.sin(w * t + phi)
        angle += a / w * (math.cos(phi) - np.cos(w * t + phi))
    return angle, rate


def trapezoid_velocity_profile(low: float, high: float, speed: float, reversal_s: float,
                               duration_s: float) -> tuple[Array, Array]:
    """Breakpoints (times [s], velocities [rad/s]) of the tracking motion: piecewise-linear velocity.

    Starts at rest at the middle of [``low``, ``high``] [rad], accelerates to ``+speed`` [rad/s] in
    ``reversal_s``/2, reverses at each limit at constant acceleration 2·speed/``reversal_s`` so that the motion
    stops exactly at the limit. Covers at least ``duration_s``.
    """
    half = 0.5 * reversal_s
    ramp = 0.25 * speed * reversal_s        # distance covered while speeding up or slowing down
    span = high - low
    times = [0.0, half]
    vels = [0.0, speed]
    t = half + (0.5 * span - 2.0 * ramp) / speed   # start of the first reversal (top)
    sign = 1.0
    while times[-1] < duration_s:
        times += [t, t + reversal_s]
        vels += [sign * speed, -sign * speed]
        sign = -sign
        t += reversal_s + (span - 2.0 * ramp) / speed
    return np.asarray(times), np.asarray(vels)


def _integrate_piecewise_linear(times: Array, vels: Array, start: float, t_s: Array) -> tuple[Array, Array]:
    """Exact position and velocity at ``t_s`` of a piecewise-linear velocity through the breakpoints."""
    dt = np.diff(times)
    pos_b = start + np.concatenate([[0.0], np.cumsum(0.5 * (vels[1:] + vels[:-1]) * dt)])
    i = np.clip(np.searchsorted(times, t_s, side='right') - 1, 0, len(times) - 2)
    tau = t_s - times[i]
    slope = (vels[i + 1] - vels[i]) / dt[i]
    return pos_b[i] + vels[i] * tau + 0.5 * slope * tau * tau, vels[i] + slope * tau


def zero_crossings(t_s: Array, x: Array) -> Array:
    """Times [s] where ``x`` changes sign (linear interpolation between samples; a sample exactly 0 counts once)."""
    s = np.sign(x)
    nz = np.flatnonzero(s != 0)
    if nz.size < 2:
        return np.zeros(0)
    a, b = nz[:-1], nz[1:]
    change = s[a] != s[b]
    a, b = a[change], b[change]
    return np.asarray(t_s[a] + (t_s[b] - t_s[a]) * x[a] / (x[a] - x[b]))


def make_profile(config: SimConfig, name: str, duration_s: float | None = None) -> Profile:
    """Profile ``name`` (``tracking``, ``scan`` or ``pointing``) sampled at the controller rate.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration (profile parameters, controller rate, plant sub-steps, base motion).
    name : str
        Profile name.
    duration_s : float, optional
        Duration [s]; default the configured ``<name>_duration_s``.

    Raises:
        ConfigError: unknown profile or a duration that is not > 0.
    """
    if name not in PROFILES:
        raise ConfigError('profile', f'must be one of {", ".join(PROFILES)}', name)
    duration = config.profile_duration_s(name) if duration_s is None else float(duration_s)
    if not (math.isfinite(duration) and duration > 0.0):
        raise ConfigError(f'{name}_duration_s', 'must be > 0 [s]', duration)
    period = config.controller_period_s
    n = int(round(duration / period))
    t = np.arange(n, dtype=float) * period
    if name in ('tracking', 'weave'):
        low, high = (math.radians(x) for x in config.tracking_travel_deg)
        speed = config.tracking_speed_rpm * RAD_S_PER_RPM
        times, vels = trapezoid_velocity_profile(low, high, speed, config.tracking_reversal_s, duration)
        angle, rate = _integrate_piecewise_linear(times, vels, 0.5 * (low + high), t)
    elif name == 'scan':
        amp = math.radians(config.scan_amplitude_deg)
        w = 2.0 * math.pi * config.scan_frequency_hz
        angle, rate = -amp * np.cos(w * t), amp * w * np.sin(w * t)
    else:
        angle, rate = np.zeros(n), np.zeros(n)
    moving_base = name in config.base_motion_profiles or name == 'weave'
    sub = t[:, None] + config.plant_step_s * np.arange(config.plant_substeps)[None, :]
    if moving_base:
        base_angle, _ = base_motion(config, t)
        _, base_rate = base_motion(config, sub)
    else:
        base_angle, base_rate = np.zeros(n), np.zeros(sub.shape)
    reversals = zero_crossings(t, rate - base_rate[:, 0])
    return Profile(name, t, angle, rate, base_angle, base_rate, reversals, moving_base)


#: The service history a correction is learned from in the loop study (:func:`history_profile`): the study's own
#: motions interleaved with motions it does not score, each segment (kind, duration [s], settings). ``weave`` is never
#: in it. Kinds: ``tracking`` (the tracking motion at ``speed_rpm``, default the configured speed), ``scan`` (a sine
#: scan of ``amplitude_deg`` at ``frequency_hz``, default the configured), ``slew`` (re-pointing: the target jumps
#: between the angles ``targets_deg`` and the track loop slews to them), ``hold`` (a fixed target on a quiet base),
#: ``pointing`` (a fixed target under base motion).
HISTORY: tuple[tuple[str, float, dict[str, object]], ...] = (
    ('tracking', 14.0, {}),
    ('slew', 6.0, {'targets_deg': (0.0, 8.0, -5.0, 10.0, -6.0, 2.0)}),
    ('scan', 6.0, {}),
    ('tracking', 10.0, {'speed_rpm': 2.0}),
    ('hold', 4.0, {}),
    ('pointing', 6.0, {}),
    ('scan', 8.0, {'amplitude_deg': 6.0, 'frequency_hz': 0.25}),
    ('tracking', 10.0, {'speed_rpm': 0.1}),
)
#: Base motion fades in and out over this time at the edges of a segment under base motion [s].
BASE_RAMP_S = 0.5


def _segment(config: SimConfig, kind: str, t: Array, settings: dict[str, object]) -> tuple[Array, Array, bool]:
    """Target angle [rad], target rate [rad/s] at times ``t`` [s] from the segment's start, and base motion on."""
    n = t.size
    if kind == 'tracking':
        low, high = (math.radians(x) for x in config.tracking_travel_deg)
        speed = float(settings.get('speed_rpm', config.tracking_speed_rpm)) * RAD_S_PER_RPM  # type: ignore[arg-type]
        duration = float(t[-1]) + config.controller_period_s if n else 0.0
        reversal = min(config.tracking_reversal_s, 0.9 * (high - low) / speed)
        times, vels = trapezoid_velocity_profile(low, high, speed, reversal, duration)
        angle, rate = _integrate_piecewise_linear(times, vels, 0.5 * (low + high), t)
        return angle, rate, False
    if kind == 'scan':
        amp = math.radians(float(settings.get('amplitude_deg', config.scan_amplitude_deg)))  # type: ignore[arg-type]
        w = 2.0 * math.pi * float(settings.get('frequency_hz', config.scan_frequency_hz))  # type: ignore[arg-type]
        return -amp * np.cos(w * t), amp * w * np.sin(w * t), False
    if kind == 'slew':
        targets = np.radians(np.asarray(settings.get('targets_deg', (0.0,)), dtype=float))
        k = np.minimum((t / (t[-1] + 1e-9) * targets.size).astype(np.int64), targets.size - 1) if n else t
        return targets[k] if n else np.zeros(0), np.zeros(n), False
    if kind in ('hold', 'pointing'):
        return np.zeros(n), np.zeros(n), kind == 'pointing'
    raise ConfigError('history', 'a segment kind must be tracking, scan, slew, hold or pointing', kind)


def history_profile(config: SimConfig, scale: float = 1.0, repeats: int = 1,
                    history: tuple[tuple[str, float, dict[str, object]], ...] = HISTORY) -> Profile:
    """The service history (:data:`HISTORY`, each segment's duration × ``scale``, the whole ``repeats`` times) as one
    profile ``history``: segments one after the other (a target that jumps between them is a slew), the base motion of
    the ``pointing`` segments fading in and out over :data:`BASE_RAMP_S` (the body angle stays continuous).

    >>> from gimbal_friction.sim.config import SimConfig
    >>> p = history_profile(SimConfig(), scale=0.25)
    >>> p.name, round(float(p.time_s[-1]) + 0.001, 3), p.base_motion
    ('history', 16.0, True)
    """
    period = config.controller_period_s
    angles, rates, envelope = [], [], []
    for _ in range(repeats):
        for kind, duration, settings in history:
            n = max(int(round(duration * scale / period)), 1)
            t = np.arange(n, dtype=float) * period
            angle, rate, base = _segment(config, kind, t, settings)
            angles.append(angle)
            rates.append(rate)
            envelope.append(np.full(n, 1.0 if base else 0.0))
    angle = np.concatenate(angles)
    rate = np.concatenate(rates)
    on = np.concatenate(envelope)
    n = angle.size
    t = np.arange(n, dtype=float) * period
    sub_t = t[:, None] + config.plant_step_s * np.arange(config.plant_substeps)[None, :]
    # the envelope: on/off smoothed by a moving average over BASE_RAMP_S (continuous body rate and angle)
    width = max(int(round(BASE_RAMP_S / period)), 1)
    env = np.convolve(np.pad(on, (width // 2, width - 1 - width // 2), mode='edge'), np.ones(width) / width,
                      mode='valid')
    env_sub = np.interp(sub_t.ravel(), t, env).reshape(sub_t.shape)
    _, raw = base_motion(config, sub_t.ravel())
    base_rate = env_sub * raw.reshape(sub_t.shape)
    flat = base_rate.ravel()
    h = config.plant_step_s
    angle_sub = np.concatenate([[0.0], np.cumsum(0.5 * h * (flat[1:] + flat[:-1]))])
    base_angle = angle_sub.reshape(sub_t.shape)[:, 0]
    reversals = zero_crossings(t, rate - base_rate[:, 0])
    return Profile('history', t, angle, rate, base_angle, base_rate, reversals, bool(on.any()))
