"""Feedforward logic of ``friction_feedforward`` (pure: no rclpy), shared by the node and the offline replay.

Torque of a joint = model friction magnitude at the current bearing temperature and speed (the tabulated fast
path) × a smooth sign of velocity × the direction factor of the joint, clamped to ``max_torque_nm``:

    τ = clamp( s(v) · k_dir · M(t, |v|), ±τ_max ),   s(v) = tanh(v / v_th)

``s`` reaches 0.995 at |v| = 3 v_th, so the output does not chatter around zero speed. Inputs that cannot be trusted
(non-finite or out-of-range temperature, stale temperature, unknown joints, mismatched arrays, non-finite
velocity) never reach the output: the logic substitutes the documented fallback and counts the reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from gimbal_friction.core.errors import ConfigError
from gimbal_friction.core.params import AxisParams
from gimbal_friction.core.settings import setting
from gimbal_friction.core.table import RPM_PER_RAD_S, FrictionTable

STALE_POLICIES = ('hold_last', 'fallback_temperature', 'zero')


@dataclass(frozen=True)
class FeedforwardSettings:
    """Settings of the feedforward (ROS parameters of ``friction_feedforward``; units in the names)."""

    velocity_threshold_rad_s: float = setting(0.005, 'rad/s', 'v_th of the smooth sign tanh(v/v_th); the '
                                              "paper's test speed 1/3 rpm is 0.0349 rad/s")
    max_torque_nm: float = setting(0.02, 'N*m', "output clamp on the torque magnitude (the paper's largest friction is "
                                   '3.2e-3 N*m)')
    temperature_timeout_s: float = setting(5.0, 's', 'a temperature older than this is stale')
    stale_policy: str = setting('fallback_temperature', '-', 'with no fresh valid temperature: hold_last (keep '
                                'the last valid one), fallback_temperature (use fallback_temperature_c) or zero '
                                '(publish 0 N*m)')
    fallback_temperature_c: float = setting(20.0, 'degC', 'temperature used by the fallback_temperature policy')
    temperature_min_c: float = setting(-60.0, 'degC', 'lowest credible bearing temperature; the model table '
                                       'spans [temperature_min_c, temperature_max_c]')
    temperature_max_c: float = setting(120.0, 'degC', 'highest credible bearing temperature')
    table_step_c: float = setting(0.1, 'degC', 'temperature step of the model table')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        checks = [
            ('velocity_threshold_rad_s', self.velocity_threshold_rad_s > 0.0, 'must be > 0 [rad/s]'),
            ('max_torque_nm', self.max_torque_nm > 0.0, 'must be > 0 [N*m]'),
            ('temperature_timeout_s', self.temperature_timeout_s > 0.0, 'must be > 0 [s]'),
            ('stale_policy', self.stale_policy in STALE_POLICIES, f'must be one of {", ".join(STALE_POLICIES)}'),
            ('temperature_max_c', self.temperature_max_c > self.temperature_min_c,
             'must exceed temperature_min_c [degC]'),
            ('temperature_min_c', self.temperature_min_c >= -200.0, 'must be >= -200 [degC]'),
            ('temperature_max_c', self.temperature_max_c <= 400.0, 'must be <= 400 [degC]'),
            ('fallback_temperature_c', self.temperature_min_c <= self.fallback_temperature_c
             <= self.temperature_max_c, 'must lie within [temperature_min_c, temperature_max_c] [degC]'),
            ('table_step_c', 0.001 <= self.table_step_c <= 5.0, 'must lie in [0.001, 5] [degC]'),
        ]
        for name, ok, rule in checks:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ConfigError(name, 'must be a finite number', value)
            if not ok:
                raise ConfigError(name, rule, value)


class JointTorque(NamedTuple):
    """Feedforward of one joint."""

    name: str
    torque_nm: float       #: signed feedforward torque [N·m]
    magnitude_nm: float    #: model magnitude before sign, direction factor and clamp [N·m]
    m_rolling_nm: float    #: M_R [N·m]
    m_sliding_nm: float    #: M_S [N·m]
    m_viscous_nm: float    #: M_L [N·m]
    saturated: bool        #: clamped to max_torque_nm
    valid_velocity: bool   #: False when the velocity was not finite (torque 0)


class FeedforwardOutput(NamedTuple):
    """Result of one joint-state message."""

    joints: list[JointTorque]     #: configured joints present in the message, in configured order
    temperature_c: float | None   #: temperature used (None: zero policy, torque 0)
    temperature_source: str       #: 'measured', 'hold_last', 'fallback_temperature' or 'zero'
    in_model_range: bool          #: temperature inside the model table


@dataclass
class _Counters:
    temperature_rejected: dict[str, int] = field(default_factory=dict)
    joint_state_rejected: dict[str, int] = field(default_factory=dict)
    saturated: dict[str, int] = field(default_factory=dict)
    published: int = 0


class FeedforwardLogic:
    """Turns temperature and joint-state inputs into feedforward torques (one instance per node/replay).

    Parameters
    ----------
    axes : Mapping[str, AxisParams]
        Configured joints (in order) and their model parameters.
    settings : FeedforwardSettings
        Validated settings.
    """

    def __init__(self, axes: Mapping[str, AxisParams], settings: FeedforwardSettings) -> None:
        settings.validate()
        self.settings = settings
        self.axes = dict(axes)
        self.tables = {name: self._table(p) for name, p in self.axes.items()}
        self.counters = _Counters()
        self.last_temperature_c: float | None = None
        self.last_temperature_time_s: float | None = None
        self.last_rejection = ''

    def _table(self, params: AxisParams) -> FrictionTable:
        s = self.settings
        return FrictionTable(params, s.temperature_min_c, s.temperature_max_c, s.table_step_c)

    def update_settings(self, settings: FeedforwardSettings) -> None:
        """Replace the settings (validated); the tables are rebuilt only if their range or step changed."""
        settings.validate()
        old = self.settings
        self.settings = settings
        if (old.temperature_min_c, old.temperature_max_c, old.table_step_c) != \
                (settings.temperature_min_c, settings.temperature_max_c, settings.table_step_c):
            self.tables = {name: self._table(p) for name, p in self.axes.items()}

    def set_axis_params(self, name: str, params: AxisParams) -> None:
        """Replace the model of one joint and rebuild its table."""
        self.axes[name] = params
        self.tables[name] = self._table(params)

    def _count(self, bucket: dict[str, int], reason: str) -> None:
        bucket[reason] = bucket.get(reason, 0) + 1
        self.last_rejection = reason

    # ------------------------------------------------------------------ inputs
    def update_temperature(self, temperature_c: float, now_s: float) -> str | None:
        """Accept a bearing temperature [°C] received at ``now_s`` [s]; returns the rejection reason or None."""
        s = self.settings
        reason = None
        if not math.isfinite(temperature_c):
            reason = 'non-finite temperature'
        elif not s.temperature_min_c <= temperature_c <= s.temperature_max_c:
            reason = 'temperature out of range'
        if reason is not None:
            self._count(self.counters.temperature_rejected, reason)
            return reason
        self.last_temperature_c = float(temperature_c)
        self.last_temperature_time_s = now_s
        return None

    def temperature_age_s(self, now_s: float) -> float:
        """Age of the last valid temperature [s] (inf if none)."""
        if self.last_temperature_time_s is None:
            return math.inf
        return max(now_s - self.last_temperature_time_s, 0.0)

    def effective_temperature(self, now_s: float) -> tuple[float | None, str]:
        """Temperature to use now and where it comes from (measured while fresh, else the stale policy)."""
        if self.temperature_age_s(now_s) <= self.settings.temperature_timeout_s:
            return self.last_temperature_c, 'measured'
        policy = self.settings.stale_policy
        if policy == 'hold_last' and self.last_temperature_c is not None:
            return self.last_temperature_c, 'hold_last'
        if policy == 'zero':
            return None, 'zero'
        return self.settings.fallback_temperature_c, 'fallback_temperature'

    def smooth_sign(self, velocity_rad_s: float) -> float:
        """tanh(v / v_th) [-]."""
        return math.tanh(velocity_rad_s / self.settings.velocity_threshold_rad_s)

    def joint_torque(self, name: str, velocity_rad_s: float, temperature_c: float | None) -> JointTorque:
        """Feedforward of one configured joint at ``velocity_rad_s`` [rad/s] and ``temperature_c`` [°C]."""
        if not math.isfinite(velocity_rad_s):
            return JointTorque(name, 0.0, 0.0, 0.0, 0.0, 0.0, False, False)
        if temperature_c is None:
            return JointTorque(name, 0.0, 0.0, 0.0, 0.0, 0.0, False, True)
        comp = self.tables[name].components(temperature_c, velocity_rad_s * RPM_PER_RAD_S)
        magnitude = 1e-3 * comp.m_total_nmm
        params = self.axes[name]
        k_dir = params.scale_positive if velocity_rad_s >= 0.0 else params.scale_negative
        torque = self.smooth_sign(velocity_rad_s) * k_dir * magnitude
        limit = self.settings.max_torque_nm
        saturated = abs(torque) > limit
        if saturated:
            torque = math.copysign(limit, torque)
            self.counters.saturated[name] = self.counters.saturated.get(name, 0) + 1
        return JointTorque(name, torque, magnitude, 1e-3 * comp.m_rolling_nmm, 1e-3 * comp.m_sliding_nmm,
                           1e-3 * comp.m_viscous_nmm, saturated, True)

    def torques_in_order(self, names: Sequence[str], velocities: Sequence[float],
                         now_s: float) -> list[float] | None:
        """Fast path of :meth:`compute` for the common message: exactly the configured joints, in configured order,
        finite velocities. Returns the torques [N·m] (same numbers and counters as :meth:`compute`), or None when
        the message is not of that kind (then call :meth:`compute`)."""
        axes = self.axes
        if len(names) != len(axes) or len(velocities) != len(names) or list(names) != list(axes):
            return None
        temperature, _ = self.effective_temperature(now_s)
        out = []
        limit = self.settings.max_torque_nm
        v_th = self.settings.velocity_threshold_rad_s
        for name, v in zip(names, velocities):
            if not math.isfinite(v):
                return None
            if temperature is None:
                out.append(0.0)
                continue
            params = axes[name]
            magnitude = 1e-3 * self.tables[name].components(temperature, v * RPM_PER_RAD_S).m_total_nmm
            k_dir = params.scale_positive if v >= 0.0 else params.scale_negative
            torque = math.tanh(v / v_th) * k_dir * magnitude
            if abs(torque) > limit:
                torque = math.copysign(limit, torque)
                self.counters.saturated[name] = self.counters.saturated.get(name, 0) + 1
            out.append(torque)
        self.counters.published += 1
        return out

    def compute(self, names: Sequence[str], velocities: Sequence[float], now_s: float) -> FeedforwardOutput | None:
        """Feedforward for one joint-state message (``names``, ``velocities`` [rad/s]) at ``now_s`` [s].

        Returns None (and counts the reason) when the message cannot be used: arrays of different length, or
        none of the configured joints present. Unknown joint names are ignored (counted).
        """
        if len(velocities) != len(names):
            self._count(self.counters.joint_state_rejected, 'velocity/name length mismatch')
            return None
        index = {n: i for i, n in enumerate(names)}
        if any(n not in self.axes for n in names):
            self._count(self.counters.joint_state_rejected, 'unknown joint name')
        present = [n for n in self.axes if n in index]
        if not present:
            self._count(self.counters.joint_state_rejected, 'no configured joint')
            return None
        temperature, source = self.effective_temperature(now_s)
        joints = [self.joint_torque(n, float(velocities[index[n]]), temperature) for n in present]
        for j in joints:
            if not j.valid_velocity:
                self._count(self.counters.joint_state_rejected, 'non-finite velocity')
        s = self.settings
        in_range = temperature is not None and s.temperature_min_c <= temperature <= s.temperature_max_c
        self.counters.published += 1
        return FeedforwardOutput(joints, temperature, source, in_range)

    def command_vector(self, output: FeedforwardOutput) -> list[float]:
        """Torques [N·m] in configured joint order (0.0 for joints absent from the message)."""
        by_name = {j.name: j.torque_nm for j in output.joints}
        return [by_name.get(n, 0.0) for n in self.axes]
