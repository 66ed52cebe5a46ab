"""The allowed values of every node parameter of the suite, as one declarative table: numeric ranges (closed, open
or half-open, in interval notation) and the names a string parameter takes.

The nodes build their parameter descriptors from it (:func:`parameter_rule`: ``ros2 param describe`` shows the
range and the allowed values), ``scripts/param_tables.py`` prints the "allowed" column of docs/ros.md from it, and
``test/test_config.py`` checks it against the ``validate()`` rules of each settings class (a value at an included
bound is accepted, one beyond a bound or at an excluded one refused), so the table and the validation cannot drift
apart. The model parameters' ranges are the :class:`~gimbal_friction.physics.params.Bound` of each
:class:`~gimbal_friction.physics.params.AxisParams` field (that table is the one the model validates with).

A rule between two parameters (``fallback_temperature_c`` within ``[temperature_min_c, temperature_max_c]``) is not
a range: it is given in words (:attr:`Rule.note`) beside the range of the value alone.

>>> rule = parameter_rule('friction_feedforward', 'max_torque_nm')
>>> rule.text('N*m'), rule.low, rule.high, rule.low_open
('(0, 100] N*m', 0.0, 100.0, True)
>>> parameter_rule('friction_feedforward', 'stale_policy').text()
'one of hold_last, fallback_temperature, zero'
"""

from __future__ import annotations

import math
import re
from typing import NamedTuple

from gimbal_friction.estimation.gating import METHODS
from gimbal_friction.feedforward.correction.settings import FIT_WORKERS, JUDGE_MODES
from gimbal_friction.feedforward.rule import STALE_POLICIES, VELOCITY_SOURCES
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, Bound, parameter_specs
from gimbal_friction.sim.config import PRESLIDING_MODELS, PROFILES


class Rule(NamedTuple):
    """The allowed values of one parameter: a range (``None`` = no bound on that side) or a set of names."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False      #: the lower bound itself is not allowed
    high_open: bool = False     #: the upper bound itself is not allowed
    choices: tuple[str, ...] = ()
    note: str = ''              #: a rule involving other parameters, in words

    def text(self, unit: str = '') -> str:
        """The rule in interval notation with the unit: ``(0, 100] N*m``, ``> 0 mm``, ``one of a, b``."""
        if self.choices:
            out = 'one of ' + ', '.join(self.choices)
        elif self.low is None and self.high is None:
            return self.note or 'any finite value'
        elif self.high is None:
            out = f'{">" if self.low_open else ">="} {_num(self.low)}'
        elif self.low is None:
            out = f'{"<" if self.high_open else "<="} {_num(self.high)}'
        else:
            out = f'{"(" if self.low_open else "["}{_num(self.low)}, {_num(self.high)}{")" if self.high_open else "]"}'
        if unit not in ('', '-') and not self.choices:
            out += f' {unit}'
        return f'{out}; {self.note}' if self.note else out

    def allows(self, value: float | str) -> bool:
        """Whether ``value`` satisfies the rule of the value alone (the note is not checked)."""
        if self.choices:
            return value in self.choices
        if isinstance(value, str) or not math.isfinite(value):
            return False
        if self.low is not None and (value < self.low or (self.low_open and value == self.low)):
            return False
        return not (self.high is not None and (value > self.high or (self.high_open and value == self.high)))


def _num(value: float | None) -> str:
    """A bound as the docs write it: ``1e6``, ``1e-5``, ``0.05``, ``3.14159``."""
    return f'{value:g}'.replace('e+0', 'e').replace('e+', 'e').replace('e-0', 'e-')


_INTERVAL = re.compile(r'([\[(])\s*(\S+)\s*,\s*(\S+)\s*([\])])')
_HALF = re.compile(r'(>=|>|<=|<)\s*(\S+)')


def rule(spec: str | tuple[str, ...], note: str = '') -> Rule:
    """A :class:`Rule` from interval notation (``'(0, 100]'``, ``'[1e-6, 10]'``, ``'>= 0'``, ``'> 0'``,
    ``'<= 400'``) or a tuple of allowed names.

    >>> rule('(0, 1)')
    Rule(low=0.0, high=1.0, low_open=True, high_open=True, choices=(), note='')
    """
    if isinstance(spec, tuple):
        return Rule(choices=spec, note=note)
    m = _INTERVAL.fullmatch(spec.strip())
    if m:
        return Rule(float(m.group(2)), float(m.group(3)), m.group(1) == '(', m.group(4) == ')', note=note)
    m = _HALF.fullmatch(spec.strip())
    if not m:
        raise ValueError(f'not a rule: {spec!r}')
    value = float(m.group(2))
    if m.group(1).startswith('>'):
        return Rule(low=value, low_open=m.group(1) == '>', note=note)
    return Rule(high=value, high_open=m.group(1) == '<', note=note)


def from_bound(bound: Bound | None, choices: tuple[str, ...] | None) -> Rule | None:
    """The :class:`Rule` of a model parameter's bound or choices (:mod:`gimbal_friction.physics.params`)."""
    if choices:
        return Rule(choices=tuple(choices))
    if bound is None:
        return None
    return Rule(bound.low, bound.high, not bound.low_inclusive, not bound.high_inclusive)


_T_MIN = f'>= {MODEL_T_MIN_C:g}'
_T_ABOVE_MIN = f'({MODEL_T_MIN_C:g}, {MODEL_T_MAX_C:g}]'   # above temperature_min_c, itself >= the model's lowest
_LAYOUT = 'layout of the learned cells: read at start only'

#: settings class name -> parameter (field) name -> its rule; a field not named has no range (a bool, a path, a
#: free number) or only a rule of its own in words (the list parameters of the simulator)
SETTINGS_RULES: dict[str, dict[str, Rule]] = {
    'FeedforwardSettings': {
        'velocity_threshold_rad_s': rule('[1e-6, 10]'),
        'max_torque_nm': rule('(0, 100]'),
        'temperature_timeout_s': rule('(0, 86400]'),
        'stale_policy': rule(STALE_POLICIES),
        'fallback_temperature_c': rule(f'[{MODEL_T_MIN_C:g}, {MODEL_T_MAX_C:g}]',
                                       'within [temperature_min_c, temperature_max_c]'),
        'temperature_min_c': rule(_T_MIN),
        'temperature_max_c': rule(_T_ABOVE_MIN, 'must exceed temperature_min_c'),
        'table_step_c': rule('[0.001, 5]'),
        'velocity_source': rule(VELOCITY_SOURCES),
        'reference_timeout_s': rule('(0, 3600]'),
    },
    'FeedforwardNodeSettings': {
        'max_rate_hz': rule('[0, 1e6]', '0 = for every joint-state message'),
        'diagnostics_period_s': rule('[0.05, 60]'),
        'learning_save_period_s': rule('[0.1, 86400]'),
        'correction_publish_period_s': rule('[0.05, 3600]'),
    },
    'CorrectionSettings': {
        'prior_samples': rule('(0, 1e9]'),
        'max_relative': rule('[0, 10]'),
        'floor_nm': rule('[0, 1]'),
        'max_independent_nm': rule('[0, 1]'),
        'min_speed_rad_s': rule('[1e-4, 10]', _LAYOUT),
        'max_speed_rad_s': rule('(1e-4, 1000]', 'must exceed correction_min_speed_rad_s'),
        'max_residual_relative': rule('(0, 1000]'),
        'max_residual_floor_nm': rule('[0, 100]'),
        'temperature_min_c': Rule(note=_LAYOUT),
        'temperature_max_c': Rule(note=f'{_LAYOUT}; 2 to 10000 whole correction_temperature_bin_c above '
                                  'correction_temperature_min_c'),
        'temperature_bin_c': rule('> 0', _LAYOUT),
        'speed_bins': rule('[2, 40]', _LAYOUT),
        'speed_smoothing': rule('(0, 1e6]'),
        'position_resolution_rad': rule('[1e-5, 0.05]', _LAYOUT),
        'ripple_periods_max': rule('[0, 16]'),
        'ripple_period_max_rad': rule(f'[8e-5, {math.pi!r}]', 'at least 8 x correction_position_resolution_rad'),
        'ripple_min_z': rule('[2, 100]'),
        'ripple_min_relative': rule('[0, 1]'),
        'guard_min_samples': rule('[0, 1e9]'),
        'guard_block_samples': rule('[1, 1e7]'),
        'guard_memory_samples': rule('[10, 1e9]'),
        'guard_z': rule('[0, 100]'),
    },
    'LearningSettings': {
        'max_rate_nm_per_min': rule('(0, 1]'),
        'step_period_s': rule('(0, 3600]'),
        'fit_worker': rule(FIT_WORKERS, 'read at start only'),
        'fit_timeout_s': rule('(0, 3600]'),
        'judge': rule(JUDGE_MODES),
    },
    'JudgeSettings': {   # (read at start)
        'block_s': rule('[0.01, 3600]', 'read at start only'),
        'on_share': rule('[0.01, 0.5]', 'read at start only'),
        'z': rule('(0, 100]', 'read at start only'),
        'stop_z': rule('(0, 100]', 'read at start only'),
        'min_blocks': rule('[2, 1e6]', 'read at start only'),
        'max_blocks': rule('[2, 1e9]', 'at least min_blocks; read at start only'),
        'applied_off_share': rule('[0.01, 0.5]', 'read at start only'),
        'settle_s': rule('[0, 3600)', 'below block_s; read at start only'),
        'error_cap_rad_s': rule('[1e-6, 1000]', 'read at start only'),
        'min_block_samples': rule('[1, 1e9]', 'read at start only'),
        'memory_groups': rule('[2, 1e9]', 'read at start only'),
        'restart_relative': rule('(0, 10]', 'read at start only'),
        'seed': rule('>= 0', 'a whole number below 2^31; read at start only'),
    },
    'EstimatorSettings': {
        'method': rule(METHODS),
        'commanded_speed_rad_s': rule('(0, 100]'),
        'speed_tolerance': rule('(0, 1)'),
        'min_dwell_s': rule('[0, 3600]'),
        'position_min_rad': Rule(note='below position_max_rad'),
        'position_max_rad': Rule(note='must exceed position_min_rad'),
        'max_accel_rad_s2': rule('(0, 1e6]'),
        'pairing_tolerance_s': rule('[0, 10]'),
        'max_current_a': rule('(0, 1e4]'),
        'max_opposing_torque_nm': rule('[0, 100]'),
        'temperature_bin_c': rule('[0.001, 1000]'),
        'temperature_timeout_s': rule('(0, 86400]'),
        'temperature_wait_s': rule('[0, 60]'),
        'temperature_min_c': rule(_T_MIN),
        'temperature_max_c': rule(_T_ABOVE_MIN, 'must exceed temperature_min_c'),
        'ripple_bins': rule('[1, 10000]'),
        'stamp_reset_s': rule('(0, 1e6]'),
        'acceleration_window_s': rule('[1e-4, 10]'),
        'observer_min_speed_rad_s': rule('(0, 100]'),
        'observer_max_accel_rad_s2': rule('(0, 1e6]'),
        'observer_max_accel_noise_rad_s2': rule('(0, 1e6]'),
    },
    'EstimatorNodeSettings': {
        'batch_period_s': rule('[0.001, 1]'),
        'statistics_period_s': rule('[0.05, 3600]'),
        'diagnostics_period_s': rule('[0.05, 3600]'),
    },
    'LoggerSettings': {
        'flush_period_s': rule('(0, 3600]'),
        'chunk_kib': rule('[1, 65536]'),
        'max_file_mb': rule('[0, 1e9]', '0 = never'),
        'max_file_duration_s': rule('[0, 1e9]', '0 = never'),
        'pairing_timeout_s': rule('(0, 3600]'),
        'residual_bin_c': rule('(0, 1000]'),
        'retry_period_s': rule('(0, 3600]'),
        'diagnostics_period_s': rule('(0, 3600]'),
    },
    'SimConfig': {
        'inertia_truth_ratio': rule('(0, 100]'),
        'unbalance_torque_nm': rule('[-1, 1]'),
        'unbalance_phase_rad': rule('[-100, 100]'),
        'plant_substeps': rule('[1, 1000]'),
        'current_limit_a': rule('> 0'),
        'current_loop_time_constant_s': rule('>= 0'),
        'current_noise_a': rule('>= 0'),
        'rate_loop_hz': rule('[10, 100000]'),
        'rate_bandwidth_hz': rule('(0, 25000]', 'at most rate_loop_hz / 4'),
        'rate_integral_hz': rule('[0, 25000)', 'below rate_bandwidth_hz'),
        'track_loop_hz': rule('(0, 100000]', 'at most rate_loop_hz'),
        'track_bandwidth_hz': rule('[0, 6250]', 'at most min(track_loop_hz, rate_bandwidth_hz) / 4'),
        'track_noise_rad': rule('>= 0'),
        'gyro_noise_rad_s': rule('>= 0'),
        'resolver_noise_rad': rule('>= 0'),
        'resolver_velocity_noise_rad_s': rule('>= 0'),
        'resolver_velocity_time_constant_s': rule('>= 0'),
        'temperature_rate_hz': rule('(0, 100000]', 'at most rate_loop_hz'),
        'temperature_noise_c': rule('>= 0'),
        'temperature_sensor_time_constant_s': rule('>= 0'),
        'thermal_time_constant_s': rule('>= 0'),
        'truth_walther_a': rule('(0, 100]'),
        'truth_walther_b': rule('[-1000, 0)'),
        'lubricant_walther_a_shift': rule('[-1, 1]'),
        'truth_palmgren_factor': rule('(0, 100]'),
        'truth_torque_constant_nm_per_a': rule('(0, 100]'),
        'truth_no_load_current_a': rule('>= 0', 'at most current_limit_a'),
        'sigma0_nm_per_rad': rule('> 0'),
        'sigma1_nm_s_per_rad': rule('>= 0'),
        'stribeck_velocity_rad_s': rule('> 0'),
        'breakaway_ratio': rule('[1, 10]'),
        'presliding_model': rule(PRESLIDING_MODELS),
        'gms_attraction_nm_per_s': rule('>= 0'),
        'ripple_cold_gain': rule('>= 0'),
        'feedforward_latency_s': rule('[0, 1]'),
        'feedforward_timeout_s': rule('(0, 10]'),
        'tracking_speed_rpm': rule('(0, 100]'),
        'tracking_reversal_s': rule('> 0', 'speed x tracking_reversal_s shorter than the travel'),
        'tracking_duration_s': rule('(0, 3600]'),
        'scan_amplitude_deg': rule('(0, 90]'),
        'scan_frequency_hz': rule('(0, 6250]', 'at most rate_bandwidth_hz / 4'),
        'scan_duration_s': rule('(0, 3600]'),
        'pointing_duration_s': rule('(0, 3600]'),
        'weave_duration_s': rule('(0, 3600]'),
        'settle_s': rule('>= 0'),
        'reversal_window_s': rule('> 0'),
        'seed': rule('>= 0'),
        'base_motion_amplitudes_rad_s': Rule(note='every value >= 0; as many as base_motion_frequencies_hz'),
        'base_motion_frequencies_hz': Rule(note='every value in (0, rate_loop_hz / 2)'),
        'base_motion_phases_rad': Rule(note='as many as base_motion_frequencies_hz'),
        'base_motion_profiles': Rule(note='names among ' + ', '.join(PROFILES)),
        'gms_stiffness_nm_per_rad': Rule(note='1 to 20 values > 0'),
        'gms_weights': Rule(note='one share > 0 per gms_stiffness_nm_per_rad, summing to 1'),
        'ripple_amplitudes': Rule(note='values >= 0 with sum x (1 + ripple_cold_gain) < 1'),
        'ripple_periods_deg': Rule(note='values > 0; as many as ripple_amplitudes'),
        'ripple_phases_rad': Rule(note='as many as ripple_amplitudes'),
        'asymmetry_temperatures_c': Rule(note='[cold, warm] with cold < warm'),
        'asymmetry_cw_nmm': Rule(note='one value > 0 per asymmetry temperature'),
        'asymmetry_ccw_nmm': Rule(note='one value > 0 per asymmetry temperature'),
        'tracking_travel_deg': Rule(note='[low, high] with low < high'),
    },
    'RealtimeSettings': {
        'environment_temperature_c': rule('[-60, 120]'),
        'profile': rule(PROFILES),
        'duration_s': rule('[0, 86400]', "0 = the profile's <profile>_duration_s"),
        'realtime_factor': rule('[0.01, 100]'),
        'publish_every_ticks': rule('[1, 10000]'),
        'los_error_every_ticks': rule('[1, 100000]'),
        'wait_for_subscribers': rule('[0, 100]'),
        'start_timeout_s': rule('(0, 3600]'),
        'run_seed': rule('>= 0'),
        'diagnostics_period_s': rule('[0.05, 60]'),
    },
    'chamber_replay': {
        'rate': rule('> 0'),
        'start_offset_s': rule('>= 0', "at most the bag's duration"),
        'wait_for_subscribers': rule('>= 0', '0 = do not wait'),
        'wait_timeout_s': rule('> 0'),
    },
}

#: executable -> the settings classes whose fields it declares (with their prefix), in declaration order
NODE_SETTINGS: dict[str, tuple[tuple[str, str], ...]] = {
    'friction_feedforward': (('', 'FeedforwardSettings'), ('', 'FeedforwardNodeSettings'),
                             ('correction_', 'CorrectionSettings'), ('learning_', 'LearningSettings'),
                             ('judge_', 'JudgeSettings')),
    'friction_estimator': (('', 'EstimatorSettings'), ('', 'EstimatorNodeSettings')),
    'residual_logger': (('', 'LoggerSettings'),),
    'gimbal_sim': (('', 'SimConfig'), ('', 'RealtimeSettings')),
    'chamber_replay': (('', 'chamber_replay'),),
}
#: executables that declare the model parameters (``model.*``, ``axis.<joint>.*``)
MODEL_NODES = frozenset(('friction_feedforward', 'friction_estimator', 'gimbal_sim'))


def model_rule(field: str) -> Rule | None:
    """The rule of model parameter ``field`` (an AxisParams field name, without ``model.``)."""
    for spec in parameter_specs():
        if spec['name'] == field:
            return from_bound(spec['bound'], spec['choices'])
    return None


def parameter_rule(node: str, name: str) -> Rule | None:
    """The rule of parameter ``name`` of executable ``node`` (``model.x`` and ``axis.<joint>.x`` included), or
    None when it has none (a bool, a path, an unbounded number)."""
    parts = name.split('.')
    if node in MODEL_NODES and parts[0] in ('model', 'axis') and len(parts) in (2, 3):
        return model_rule(parts[-1])
    for prefix, owner in NODE_SETTINGS.get(node, ()):
        if name.startswith(prefix) and name[len(prefix):] in SETTINGS_RULES[owner]:
            return SETTINGS_RULES[owner][name[len(prefix):]]
    return None


def _settings_classes() -> dict[str, type]:
    from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
    from gimbal_friction.estimation.gating import EstimatorSettings
    from gimbal_friction.feedforward.correction.settings import CorrectionSettings, JudgeSettings, LearningSettings
    from gimbal_friction.feedforward.rule import FeedforwardSettings
    from gimbal_friction.sim.config import RealtimeSettings, SimConfig

    classes: tuple[type, ...] = (FeedforwardSettings, FeedforwardNodeSettings, CorrectionSettings, LearningSettings,
                                 JudgeSettings,
                                 EstimatorSettings, EstimatorNodeSettings, LoggerSettings, SimConfig,
                                 RealtimeSettings)
    return {cls.__name__: cls for cls in classes}


def field_default(node: str, name: str) -> object:
    """The default of parameter ``name`` of executable ``node`` as its settings field declares it (its type is the
    parameter's fixed type: a float default is a double even where a parameter file writes ``2``), or None for a
    name the node does not declare from a settings field (``axes``, a retired parameter)."""
    import dataclasses

    parts = name.split('.')
    if node in MODEL_NODES and parts[0] in ('model', 'axis') and len(parts) in (2, 3):
        return next((spec['default'] for spec in parameter_specs() if spec['name'] == parts[-1]), None)
    if node == 'chamber_replay':
        from gimbal_friction.config.loader import CHAMBER_REPLAY_SPECS
        return next((spec['default'] for spec in CHAMBER_REPLAY_SPECS if spec['name'] == name), None)
    classes = _settings_classes()
    for prefix, owner in NODE_SETTINGS.get(node, ()):
        if name.startswith(prefix):
            for f in dataclasses.fields(classes[owner]):
                if f.name == name[len(prefix):]:
                    return f.default
    return None
