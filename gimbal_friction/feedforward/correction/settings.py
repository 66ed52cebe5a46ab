"""Settings of a learned correction and of its in-service learning, the model identity and the error type.

One job in one module: the names, units, defaults and rules of every setting (the node's ``correction_*`` and
``learning_*`` parameters, the file's ``settings``), so the node, the file, the chamber path and the loop study
accept and refuse the same values.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from gimbal_friction.common.errors import GimbalFrictionError, check_rules
from gimbal_friction.common.settings import setting

__all__ = ['DIRECTIONS', 'FIT_WORKERS', 'JUDGE_MODES', 'LAYOUT', 'RETIRED', 'CorrectionError', 'CorrectionSettings',
           'JudgeSettings', 'LearningSettings', 'ModelIdentity', 'model_identity']

#: the two directions of motion: ``cw`` (v > 0, the paper's clockwise) and ``ccw`` (v < 0)
DIRECTIONS = ('cw', 'ccw')
#: settings that lay out what a correction holds (its cells and rows): a file keeps them; a node refuses a file with
#: other values (they cannot change while the node runs)
LAYOUT = ('temperature_min_c', 'temperature_max_c', 'temperature_bin_c', 'min_speed_rad_s', 'speed_term',
          'speed_bins', 'position_resolution_rad')
#: where in-service refits run (``fit_worker``): a child process, a thread, or inline in the learner's step
FIT_WORKERS = ('process', 'thread', 'inline')
#: when the loop's error judges the correction (``learning_judge``): ``auto`` while a loop-error input has a
#: publisher, ``on`` always (cells wait for loop error), ``off`` never (the residual guard alone)
JUDGE_MODES = ('auto', 'on', 'off')
#: settings of earlier versions that no longer exist, and why (a parameter file naming one still loads; the node
#: says once that it has no effect)
RETIRED = {
    'position_bins': 'ripple periods are now found in the data (ripple_periods_max)',
    'position_period_rad': 'ripple periods are now found in the data (ripple_periods_max)',
    'harmonics': 'ripple periods are now found in the data (ripple_periods_max)',
    'speed_reference_rad_s': 'the speed dependence is now a profile over speed octaves (speed_bins)',
    'speed_prior_spread': 'the speed profile is now smoothed by speed_smoothing',
}


class CorrectionError(GimbalFrictionError, ValueError):
    """A correction file or correction input cannot be used; the message is one line naming cause and fix."""


@dataclass(frozen=True)
class CorrectionSettings:
    """Layout, shrinkage, bound, gate and guard of a correction (stored in its file; units in the names)."""

    temperature_min_c: float = setting(-62.5, 'degC', 'lower edge of the first temperature bin')
    temperature_max_c: float = setting(122.5, 'degC', 'upper edge of the last temperature bin')
    temperature_bin_c: float = setting(5.0, 'degC', 'width of a temperature bin (default: centred on multiples of 5)')
    prior_samples: float = setting(50.0, '-', 'n0: every learned term is shrunk towards 0 like n0 samples of zero '
                                   'residual, so thin data stays near the model')
    max_relative: float = setting(4.0, '-', 'bound: |correction| <= this x |model| + floor_nm, for the part along the '
                                  'motion and for the direction-independent part each (this one at least '
                                  'max_independent_nm)')
    floor_nm: float = setting(2e-5, 'N*m', 'absolute part of the bound')
    max_independent_nm: float = setting(0.005, 'N*m', 'the part independent of the direction (an unbalance) may reach '
                                        'this [N*m] where the bound of the model friction is lower')
    min_speed_rad_s: float = setting(0.005, 'rad/s', 'samples slower than this (near a reversal) are not learned; the '
                                     'first speed octave starts here')
    max_speed_rad_s: float = setting(20.0, 'rad/s', 'samples faster than this are refused as implausible')
    max_residual_relative: float = setting(20.0, '-', 'samples whose |measured - model| exceeds this x |model| + '
                                           'max_residual_floor_nm are refused as implausible')
    max_residual_floor_nm: float = setting(0.005, 'N*m', 'absolute part of the plausibility gate of a residual')
    speed_term: bool = setting(True, '-', 'learn a profile over speed per cell (octaves from min_speed_rad_s: '
                               "Palmgren's viscous rise, a Stribeck fall, a branch switch); false: one value per cell")
    speed_bins: int = setting(12, '-', 'speed octaves of the profile from min_speed_rad_s (12: up to 20 rad/s)')
    falling_friction: bool = setting(False, '-', 'apply a friction that falls with speed (a Stribeck curve) as '
                                     'learned; false: it is learned and reported, and the feedforward holds the '
                                     'friction it adds to the lowest it learned at any higher speed')
    speed_smoothing: float = setting(50.0, '-', 'neighbouring speed octaves are tied like this x prior_samples '
                                     "samples: the part along the motion to the model's own shape over speed, the "
                                     'part independent of the direction to a constant')
    position_resolution_rad: float = setting(8.7266e-4, 'rad', 'width of the position bins residuals are kept in '
                                             '(0.05 deg): the shortest ripple period found is 4 bins')
    ripple_periods_max: int = setting(4, '-', 'most ripple periods found in the residuals and learned (0: no ripple)')
    ripple_period_max_rad: float = setting(0.2, 'rad', 'longest ripple period looked for (11.5 deg; slower changes '
                                           'with the angle are the trend); also at most half the travel seen')
    ripple_min_z: float = setting(8.0, '-', 'a period is kept when its amplitude is this many standard errors')
    ripple_min_relative: float = setting(0.005, '-', '... and at least this fraction of the model friction')
    trend: bool = setting(True, '-', 'learn a slow change with the angle (sin, cos of the joint angle) along the '
                          'motion and one independent of the direction (an unbalance torque)')
    guard_min_samples: int = setting(3000, '-', 'a cell or term is applied once this many samples scored it out of '
                                     'sample (each sample is scored before it is learned)')
    guard_block_samples: int = setting(250, '-', 'the scores are judged over blocks of this many consecutive samples '
                                       '(batch means: neighbouring samples are not independent); at least two '
                                       'blocks before a cell is applied')
    guard_memory_samples: int = setting(20000, '-', 'the out-of-sample scores forget with this many samples')
    guard_z: float = setting(3.0, '-', 'a cell is applied where its cut of the squared residual is this many '
                             'standard errors above 0, a term where dropping it would cost two thirds of that')

    @property
    def n_temperature(self) -> int:
        """Number of temperature bins [-]."""
        return int(round((self.temperature_max_c - self.temperature_min_c) / self.temperature_bin_c))

    @property
    def n_speed(self) -> int:
        """Speed octaves of a cell's profile [-] (1 without the speed term)."""
        return self.speed_bins if self.speed_term else 1

    @property
    def n_position(self) -> int:
        """Position bins over a turn [-]."""
        return int(math.ceil(2.0 * math.pi / self.position_resolution_rad))

    def edges_c(self) -> list[float]:
        """Temperature bin edges [°C]."""
        return [self.temperature_min_c + k * self.temperature_bin_c for k in range(self.n_temperature + 1)]

    def centre_c(self, b: int) -> float:
        """Centre of temperature bin ``b`` [°C]."""
        return self.temperature_min_c + (b + 0.5) * self.temperature_bin_c

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        span = (self.temperature_max_c - self.temperature_min_c) / self.temperature_bin_c \
            if self.temperature_bin_c > 0.0 else 0.0
        check_rules(self, [
            ('temperature_bin_c', self.temperature_bin_c > 0.0, 'must be > 0 [degC]'),
            ('temperature_max_c', 2 <= round(span) <= 10000 and abs(span - round(span)) < 1e-6,
             'must exceed temperature_min_c by 2 to 10000 whole temperature_bin_c [degC]'),
            ('prior_samples', 0.0 < self.prior_samples <= 1e9, 'must lie in (0, 1e9] [-]'),
            ('max_relative', 0.0 <= self.max_relative <= 10.0, 'must lie in [0, 10] [-]'),
            ('floor_nm', 0.0 <= self.floor_nm <= 1.0, 'must lie in [0, 1] [N*m]'),
            ('max_independent_nm', 0.0 <= self.max_independent_nm <= 1.0, 'must lie in [0, 1] [N*m]'),
            ('min_speed_rad_s', 1e-4 <= self.min_speed_rad_s <= 10.0, 'must lie in [1e-4, 10] [rad/s]'),
            ('max_speed_rad_s', self.min_speed_rad_s < self.max_speed_rad_s <= 1000.0,
             'must lie in (min_speed_rad_s, 1000] [rad/s]'),
            ('max_residual_relative', 0.0 < self.max_residual_relative <= 1000.0, 'must lie in (0, 1000] [-]'),
            ('max_residual_floor_nm', 0.0 <= self.max_residual_floor_nm <= 100.0, 'must lie in [0, 100] [N*m]'),
            ('speed_term', isinstance(self.speed_term, bool), 'must be true or false'),
            ('speed_bins', 2 <= self.speed_bins <= 40, 'must be an integer in [2, 40] [-]'),
            ('speed_smoothing', 0.0 < self.speed_smoothing <= 1e6, 'must lie in (0, 1e6] [-]'),
            ('position_resolution_rad', 1e-5 <= self.position_resolution_rad <= 0.05,
             'must lie in [1e-5, 0.05] [rad]'),
            ('ripple_periods_max', 0 <= self.ripple_periods_max <= 16, 'must be an integer in [0, 16] [-]'),
            ('ripple_period_max_rad', 8.0 * self.position_resolution_rad <= self.ripple_period_max_rad <= math.pi,
             'must lie in [8 x position_resolution_rad, pi] [rad]'),
            ('ripple_min_z', 2.0 <= self.ripple_min_z <= 100.0, 'must lie in [2, 100] [-]'),
            ('ripple_min_relative', 0.0 <= self.ripple_min_relative <= 1.0, 'must lie in [0, 1] [-]'),
            ('trend', isinstance(self.trend, bool), 'must be true or false'),
            ('falling_friction', isinstance(self.falling_friction, bool), 'must be true or false'),
            ('guard_min_samples', 0 <= self.guard_min_samples <= 10**9, 'must be an integer in [0, 1e9] [-]'),
            ('guard_block_samples', 1 <= self.guard_block_samples <= 10**7, 'must be an integer in [1, 1e7] [-]'),
            ('guard_memory_samples', 10 <= self.guard_memory_samples <= 10**9,
             'must be an integer in [10, 1e9] [-]'),
            ('guard_z', 0.0 <= self.guard_z <= 100.0, 'must lie in [0, 100] [-]'),
        ])


@dataclass(frozen=True)
class LearningSettings:
    """Settings of in-service learning (:class:`~gimbal_friction.feedforward.correction.learner.Learner`)."""

    max_rate_nm_per_min: float = setting(3e-4, 'N*m/min', 'largest change of the applied correction per minute')
    step_period_s: float = setting(1.0, 's', 'the published values move towards the learned ones this often')
    fit_worker: str = setting('process', '-', 'where a node runs its refits: process (a child process of lower '
                              'priority), thread, or inline (in the step, delaying the feedforward)')
    fit_timeout_s: float = setting(30.0, 's', 'a refit still running after this long is counted as timed out '
                                   '(a process worker is stopped and restarted)')
    judge: str = setting('auto', '-', "the loop's error judges each cell of the correction in randomised on/off "
                         'blocks (/gimbal/loop_error): auto (while that topic has a publisher), on, or off (the '
                         'residual guard alone)')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        check_rules(self, [('max_rate_nm_per_min', 0.0 < self.max_rate_nm_per_min <= 1.0,
                            'must lie in (0, 1] [N*m/min]'),
                           ('step_period_s', 0.0 < self.step_period_s <= 3600.0, 'must lie in (0, 3600] [s]'),
                           ('fit_worker', self.fit_worker in FIT_WORKERS, f'must be one of {", ".join(FIT_WORKERS)}'),
                           ('fit_timeout_s', 0.0 < self.fit_timeout_s <= 3600.0, 'must lie in (0, 3600] [s]'),
                           ('judge', self.judge in JUDGE_MODES, f'must be one of {", ".join(JUDGE_MODES)}')])


@dataclass(frozen=True)
class JudgeSettings:
    """Settings of the loop's judge of the correction
    (:class:`~gimbal_friction.feedforward.correction.judge.LoopJudge`; the node's ``judge_*`` parameters)."""

    block_s: float = setting(0.2, 's', 'time is cut into blocks this long; the candidate of a cell in test is on or '
                             'off for a whole block')
    on_share: float = setting(0.5, '-', 'share of the blocks a cell in test has its candidate on (one block on in '
                              'every group of round(1/this) blocks, chosen at random): bounds the cost of a test')
    z: float = setting(2.5, '-', 'a cell is applied when the loop error with its candidate on is lower than off by '
                       'this many standard errors (ln mean squared LOS rate error, on - off)')
    stop_z: float = setting(2.0, '-', 'a test is stopped (the cell withdrawn to the model) when the loop error with '
                            'the candidate on is higher by this many standard errors; an applied cell likewise')
    min_blocks: int = setting(4, '-', 'blocks on and off each a cell needs before a verdict')
    max_blocks: int = setting(200, '-', 'a test that has not shown a gain after this many blocks on is withdrawn')
    applied_off_share: float = setting(0.1, '-', 'an applied cell keeps its candidate off for this share of the '
                                       'blocks, so later data can withdraw it')
    settle_s: float = setting(0.05, 's', 'loop error of the first this long of every block is not counted (the loop '
                              'settling after a switch)')
    error_cap_rad_s: float = setting(0.05, 'rad/s', 'a loop-error sample counts at most this large (a slew or a '
                                     "target's jump makes errors no friction feedforward causes; a worse candidate "
                                     'still shows: its errors count up to this)')
    min_block_samples: int = setting(20, '-', 'loop-error samples a block needs in a cell and speed octave to count')
    memory_groups: int = setting(200, '-', 'the contrast forgets with this many groups of blocks')
    restart_relative: float = setting(0.25, '-', "a cell's test restarts when its candidate moved by this fraction "
                                      'of its size since the test began (a new fit)')
    seed: int = setting(0, '-', 'seed of the random choice of the blocks on')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        check_rules(self, [
            ('block_s', 0.01 <= self.block_s <= 3600.0, 'must lie in [0.01, 3600] [s]'),
            ('on_share', 0.01 <= self.on_share <= 0.5, 'must lie in [0.01, 0.5] [-]'),
            ('z', 0.0 < self.z <= 100.0, 'must lie in (0, 100] [-]'),
            ('stop_z', 0.0 < self.stop_z <= 100.0, 'must lie in (0, 100] [-]'),
            ('min_blocks', 2 <= self.min_blocks <= 10**6, 'must be an integer in [2, 1e6] [-]'),
            ('max_blocks', self.min_blocks <= self.max_blocks <= 10**9,
             'must be an integer in [min_blocks, 1e9] [-]'),
            ('applied_off_share', 0.01 <= self.applied_off_share <= 0.5, 'must lie in [0.01, 0.5] [-]'),
            ('settle_s', 0.0 <= self.settle_s < self.block_s, 'must lie in [0, block_s) [s]'),
            ('error_cap_rad_s', 1e-6 <= self.error_cap_rad_s <= 1000.0, 'must lie in [1e-6, 1000] [rad/s]'),
            ('min_block_samples', 1 <= self.min_block_samples <= 10**9, 'must be an integer in [1, 1e9] [-]'),
            ('memory_groups', 2 <= self.memory_groups <= 10**9, 'must be an integer in [2, 1e9] [-]'),
            ('restart_relative', 0.0 < self.restart_relative <= 10.0, 'must lie in (0, 10] [-]'),
            ('seed', 0 <= self.seed <= 2**31 - 1, 'must be an integer in [0, 2^31 - 1] [-]'),
        ])


class ModelIdentity(NamedTuple):
    """The model a correction was learned against: the joints, in order, and a hash of their parameters."""

    joints: tuple[str, ...]
    params_sha256: str


def model_identity(axes: Mapping[str, Any]) -> ModelIdentity:
    """Identity of ``axes`` (joint → AxisParams, or any mapping of parameter name → value).

    Numbers are compared as floats (``1`` and ``1.0`` hash alike); key order does not matter; the joint order does.

    >>> a = model_identity({'elevation': {'walther_a': 8.6195, 'ball_count': 7}})
    >>> a == model_identity({'elevation': {'ball_count': 7.0, 'walther_a': 8.6195}}), a.params_sha256[:12]
    (True, '88c61a634b86')
    """
    def norm(v: Any) -> Any:
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v

    canon = []
    for joint, params in axes.items():
        values = params.to_mapping() if hasattr(params, 'to_mapping') else dict(params)
        canon.append([joint, {str(k): norm(v) for k, v in values.items()}])
    text = json.dumps(canon, sort_keys=True, separators=(',', ':'))
    return ModelIdentity(tuple(axes), hashlib.sha256(text.encode()).hexdigest())
