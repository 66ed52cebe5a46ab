"""The friction estimator's rules as data: limits, rejection reasons, its settings (gates of the steady-state and
observer measurements, Eq. 23 constants) and its counters. The logic that applies them is
:mod:`gimbal_friction.estimation.estimator`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gimbal_friction.common.errors import ConfigError, check_rules
from gimbal_friction.common.settings import setting
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C

#: accepted joint states kept per joint for currents that arrive late [-]
HISTORY_LENGTH = 256
#: currents waiting for their joint state, per joint [-]
WAIT_LENGTH = 256
#: most joint states used in one acceleration window [-]
OBSERVER_MAX_SAMPLES = 64
#: a friction sample waits for its temperature at most this many joint states of its joint [-] (with
#: ``temperature_wait_s``: the wait is bounded in memory whatever the rate)
TEMPERATURE_WAIT_STATES = 16384
#: joint states of an acceleration window spanning more than this (or ten windows) straddle a gap [ns]
MAX_GAP_NS = 250_000_000
#: joint key of rejections that belong to no configured joint (unknown names)
UNKNOWN_JOINT = '*'
METHODS = ('steady_state', 'observer', 'both')

R_LENGTH = 'length mismatch'
R_UNKNOWN = 'unknown joint'
R_DUPLICATE = 'duplicate joint name'
R_NON_FINITE_JS = 'non-finite joint state'
R_STAMP = 'stamp not increasing'
R_RESET = 'stream restarted (stamp jumped back)'
R_NON_FINITE = 'non-finite'
R_OVER_CURRENT = 'over current rating'
R_UNPAIRED = 'unpaired'
R_WINDOW = 'outside position window'
R_SPEED = 'speed off command'
R_ACCEL = 'acceleration'
R_DWELL = 'dwell'
R_OBS_SPEED = 'observer: speed near zero'
R_OBS_WINDOW = 'observer: window'
R_OBS_ACCEL = 'observer: acceleration'
R_OBS_NOISE = 'observer: acceleration noise'
R_OPPOSES = 'friction opposes motion'
#: steady-state verdict codes 1..4 (0 = steady)
STEADY_STATE_REASONS = (R_WINDOW, R_SPEED, R_ACCEL, R_DWELL)
#: observer verdict codes 1..4 (0 = accepted)
OBSERVER_REASONS = (R_OBS_SPEED, R_OBS_WINDOW, R_OBS_ACCEL, R_OBS_NOISE)
#: reasons that mean a bad or unusable input (as opposed to "not in steady state")
INPUT_REASONS = (R_LENGTH, R_UNKNOWN, R_DUPLICATE, R_NON_FINITE_JS, R_STAMP, R_RESET, R_NON_FINITE, R_OVER_CURRENT,
                 R_UNPAIRED, R_OPPOSES)

_I64_MAX = np.iinfo(np.int64).max


@dataclass(frozen=True)
class EstimatorSettings:
    """Settings of the estimator (ROS parameters of ``friction_estimator``; units in the names)."""

    method: str = setting('steady_state', '-', "steady_state (the paper's constant-speed protocol), observer "
                          '(friction while the gimbal works: Eq. 23 minus J*alpha) or both')
    commanded_speed_rad_s: float = setting(2.0 * math.pi / 180.0, 'rad/s', 'commanded constant test speed '
                                           '(paper: 1/3 rpm = 0.0349 rad/s); samples must move at this speed')
    speed_tolerance: float = setting(0.1, '-', 'accepted relative deviation of |velocity| from the commanded '
                                     'speed')
    min_dwell_s: float = setting(0.5, 's', 'speed continuously within tolerance, same sign, for at least this '
                                 'long (joint-state stamps) before a sample is accepted')
    position_min_rad: float = setting(math.radians(-5.0), 'rad', 'lower end of the accepted position window '
                                      '(paper: swept from -6 deg, kept from -5 deg)')
    position_max_rad: float = setting(math.radians(10.0), 'rad', 'upper end of the accepted position window '
                                      '(paper: swept to +11 deg, kept to +10 deg)')
    max_accel_rad_s2: float = setting(0.1, 'rad/s^2', 'largest |acceleration| (see acceleration_window_s) for a '
                                      'sample to count as steady')
    pairing_tolerance_s: float = setting(0.005, 's', 'a current pairs with the joint state nearest its own stamp '
                                         'within this')
    max_current_a: float = setting(2.0, 'A', 'motor current rating; larger |current| is rejected as bad input')
    max_opposing_torque_nm: float = setting(0.01, 'N*m', 'a sample whose torque opposes the motion (a torque '
                                            'independent of the direction, an unbalance, larger than the friction) '
                                            'is kept up to this; beyond it refused as "friction opposes motion" '
                                            '(0: none kept)')
    temperature_bin_c: float = setting(5.0, 'degC', 'width of the temperature plateau bins of the statistics '
                                       '(plateau = round(t/bin)*bin)')
    temperature_timeout_s: float = setting(5.0, 's', "a temperature whose stamp differs from the sample's by more "
                                           'than this is stale: sample kept, plateau "unknown"')
    temperature_wait_s: float = setting(5.0, 's', 'a sample waits for a temperature stamped at or after its own '
                                        '(so that its temperature is the one at its stamp whatever the arrival '
                                        'order) for at most this much joint-state time, and at most '
                                        f'{TEMPERATURE_WAIT_STATES} joint states (0: no wait)')
    temperature_min_c: float = setting(-60.0, 'degC', 'lowest credible bearing temperature (lower ones are '
                                       'rejected)')
    temperature_max_c: float = setting(120.0, 'degC', 'highest credible bearing temperature')
    ripple_bins: int = setting(15, '-', 'position bins across the window for the ripple statistic')
    stamp_reset_s: float = setting(1.0, 's', 'a joint-state stamp earlier than the last accepted one by more than '
                                   "this restarts the joint's stream (time source jumped back)")
    acceleration_window_s: float = setting(0.01, 's', 'the acceleration of a joint state is the least-squares '
                                           'slope of the velocities of this last time span (at least the last 3)')
    observer_min_speed_rad_s: float = setting(0.01, 'rad/s', 'observer: |velocity| must be at least this (away '
                                              'from the Stribeck/pre-sliding region around zero speed)')
    observer_max_accel_rad_s2: float = setting(2.0, 'rad/s^2', 'observer: largest |acceleration| accepted (keeps '
                                               'the J*alpha correction small next to the friction)')
    observer_max_accel_noise_rad_s2: float = setting(1.0, 'rad/s^2', 'observer: largest standard error of the '
                                                     'acceleration estimate accepted')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        for f in self.__dataclass_fields__:
            value = getattr(self, f)
            if isinstance(value, float) and not math.isfinite(value):
                raise ConfigError(f, 'must be a finite number', value)
        bins = self.ripple_bins
        checks = [
            ('method', self.method in METHODS, f'must be one of {", ".join(METHODS)}'),
            ('commanded_speed_rad_s', 0.0 < self.commanded_speed_rad_s <= 100.0, 'must lie in (0, 100] [rad/s]'),
            ('speed_tolerance', 0.0 < self.speed_tolerance < 1.0, 'must lie in (0, 1) [-]'),
            ('min_dwell_s', 0.0 <= self.min_dwell_s <= 3600.0, 'must lie in [0, 3600] [s]'),
            ('position_max_rad', self.position_max_rad > self.position_min_rad,
             'must exceed position_min_rad [rad]'),
            ('max_accel_rad_s2', 0.0 < self.max_accel_rad_s2 <= 1e6, 'must lie in (0, 1e6] [rad/s^2]'),
            ('pairing_tolerance_s', 0.0 <= self.pairing_tolerance_s <= 10.0, 'must lie in [0, 10] [s]'),
            ('max_current_a', 0.0 < self.max_current_a <= 1e4, 'must lie in (0, 1e4] [A]'),
            ('max_opposing_torque_nm', 0.0 <= self.max_opposing_torque_nm <= 100.0, 'must lie in [0, 100] [N*m]'),
            ('temperature_bin_c', 0.001 <= self.temperature_bin_c <= 1000.0, 'must lie in [0.001, 1000] [degC]'),
            ('temperature_timeout_s', 0.0 < self.temperature_timeout_s <= 86400.0, 'must lie in (0, 86400] [s]'),
            ('temperature_wait_s', 0.0 <= self.temperature_wait_s <= 60.0, 'must lie in [0, 60] [s]'),
            ('temperature_min_c', self.temperature_min_c >= MODEL_T_MIN_C, f'must be >= {MODEL_T_MIN_C:g} [degC]'),
            ('temperature_max_c', self.temperature_max_c <= MODEL_T_MAX_C, f'must be <= {MODEL_T_MAX_C:g} [degC]'),
            ('temperature_max_c', self.temperature_max_c > self.temperature_min_c,
             'must exceed temperature_min_c [degC]'),
            ('ripple_bins', isinstance(bins, int) and not isinstance(bins, bool) and 1 <= bins <= 10000,
             'must be an integer in [1, 10000]'),
            ('stamp_reset_s', 0.0 < self.stamp_reset_s <= 1e6, 'must lie in (0, 1e6] [s]'),
            ('acceleration_window_s', 1e-4 <= self.acceleration_window_s <= 10.0, 'must lie in [1e-4, 10] [s]'),
            ('observer_min_speed_rad_s', 0.0 < self.observer_min_speed_rad_s <= 100.0,
             'must lie in (0, 100] [rad/s]'),
            ('observer_max_accel_rad_s2', 0.0 < self.observer_max_accel_rad_s2 <= 1e6,
             'must lie in (0, 1e6] [rad/s^2]'),
            ('observer_max_accel_noise_rad_s2', 0.0 < self.observer_max_accel_noise_rad_s2 <= 1e6,
             'must lie in (0, 1e6] [rad/s^2]'),
        ]
        check_rules(self, checks)


@dataclass
class EstimatorCounters:
    """What happened to the inputs. ``rejected[joint][reason]``; joint ``'*'`` = not a configured joint."""

    accepted: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    temperature_rejected: dict[str, int] = field(default_factory=dict)

    def reject(self, joint: str, reason: str, n: int = 1) -> None:
        if n:
            bucket = self.rejected.setdefault(joint, {})
            bucket[reason] = bucket.get(reason, 0) + int(n)

    def rejected_count(self, joint: str, reason: str) -> int:
        return self.rejected.get(joint, {}).get(reason, 0)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready copy."""
        return {'accepted': dict(self.accepted),
                'rejected': {j: dict(r) for j, r in self.rejected.items()},
                'temperature_rejected': dict(self.temperature_rejected)}
