"""Node-level settings of friction_feedforward, friction_estimator and residual_logger (periods, rate limit, log files).

The settings of the logic live with the logic (``FeedforwardSettings`` in :mod:`gimbal_friction.feedforward.rule`,
``EstimatorSettings`` in :mod:`gimbal_friction.estimation.estimator`); these are the nodes' own, kept here so the whole
set of parameter names of the suite is known without starting a node.
"""

from __future__ import annotations

from dataclasses import dataclass

from gimbal_friction.common.errors import ConfigError, check_rules
from gimbal_friction.common.settings import setting
from gimbal_friction.feedforward.correction import LAYOUT, RETIRED, CorrectionSettings, JudgeSettings, LearningSettings

#: prefixes of the learned correction's settings and of the in-service learner's among friction_feedforward's
#: parameters (``correction_max_relative``, ``learning_max_rate_nm_per_min``, ...): (prefix, settings class)
FEEDFORWARD_PREFIXED: tuple[tuple[str, type], ...] = (('correction_', CorrectionSettings),
                                                      ('learning_', LearningSettings), ('judge_', JudgeSettings))
#: fields of CorrectionSettings that lay out the cells: a learned correction keeps them (a file with other values is
#: refused; they cannot change while the node runs)
CORRECTION_LAYOUT = LAYOUT
#: parameters of earlier versions that no longer exist (``correction_position_bins``, ...), and why: a parameter file
#: that names one still loads (the node says once that it has no effect)
RETIRED_PARAMETERS = {f'correction_{name}': why for name, why in RETIRED.items()}
#: their defaults when they had an effect (the node declares them with these; another value is warned about)
RETIRED_DEFAULTS = {'correction_position_bins': 0, 'correction_position_period_rad': 6.283185307179586,
                    'correction_harmonics': 4, 'correction_speed_reference_rad_s': 0.0349066,
                    'correction_speed_prior_spread': 0.2}


# ---------------------------------------------------------------------------------------------------- node settings
@dataclass(frozen=True)
class FeedforwardNodeSettings:
    """Node-level parameters of friction_feedforward (besides FeedforwardSettings and the model; the velocity
    source is a FeedforwardSettings, since replay and in-process callers apply it too)."""

    max_rate_hz: float = setting(0.0, 'Hz', 'publish at most this often; 0 = for every joint-state message')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')
    correction_file: str = setting('', '-', "learned correction file (YAML) loaded at start and saved to while "
                                   "learning; '' = none. A corrupt file or one learned against other model "
                                   'parameters is refused (reason in the log and /diagnostics): the node runs on the '
                                   'pure model')
    use_correction: bool = setting(True, '-', 'add the learned correction to the model; false = pure model output at '
                                   'once (the learned state is kept)')
    learning_enabled: bool = setting(False, '-', 'learn the correction in service from the accepted samples of '
                                     '/gimbal/friction/measured_detail')
    learning_frozen: bool = setting(False, '-', 'freeze learning: the correction stays as it is, samples are not '
                                    'used')
    learning_reset: bool = setting(False, '-', 'set true to empty the correction (back to the pure model); the node '
                                   'sets it back to false')
    learning_save_period_s: float = setting(60.0, 's', 'while learning, the correction is saved (atomically) this '
                                            'often and at shutdown')
    learning_output_file: str = setting('', '-', "where learning saves when correction_file is ''; '' with both "
                                        'empty = not saved')
    correction_publish_period_s: float = setting(5.0, 's', 'period of /gimbal/friction/correction')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        check_rules(self, [
            ('max_rate_hz', 0.0 <= self.max_rate_hz <= 1e6, 'must lie in [0, 1e6] [Hz]'),
            ('diagnostics_period_s', 0.05 <= self.diagnostics_period_s <= 60.0, 'must lie in [0.05, 60] [s]'),
            ('learning_save_period_s', 0.1 <= self.learning_save_period_s <= 86400.0,
             'must lie in [0.1, 86400] [s]'),
            ('correction_publish_period_s', 0.05 <= self.correction_publish_period_s <= 3600.0,
             'must lie in [0.05, 3600] [s]'),
            ('correction_file', '\n' not in self.correction_file
             and self.correction_file == self.correction_file.strip(),
             "must be a file path without surrounding spaces ('' = none)"),
            ('learning_output_file', '\n' not in self.learning_output_file
             and self.learning_output_file == self.learning_output_file.strip(),
             "must be a file path without surrounding spaces ('' = none)"),
        ])


@dataclass(frozen=True)
class EstimatorNodeSettings:
    """Node-level parameters of friction_estimator (besides EstimatorSettings and the model)."""

    batch_period_s: float = setting(0.02, 's', 'the messages received are processed together this often (the '
                                    'result does not depend on it; measurements are published this much later)')
    statistics_period_s: float = setting(2.0, 's', 'period of the statistics summary on '
                                         '/gimbal/friction/statistics')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        check_rules(self, [
            ('batch_period_s', 0.001 <= self.batch_period_s <= 1.0, 'must lie in [0.001, 1] [s]'),
            ('statistics_period_s', 0.05 <= self.statistics_period_s <= 3600.0, 'must lie in [0.05, 3600] [s]'),
            ('diagnostics_period_s', 0.05 <= self.diagnostics_period_s <= 3600.0, 'must lie in [0.05, 3600] [s]'),
        ])


@dataclass(frozen=True)
class LoggerSettings:
    """Parameters of residual_logger."""

    output_dir: str = setting('residuals', '-', 'folder of the residual log (created; if it already holds a log, '
                              'this run writes beside it in <output_dir>_<UTC yyyymmdd_HHMMSS>)')
    flush_period_s: float = setting(1.0, 's', 'completed data reaches the disk at least this often')
    chunk_kib: int = setting(64, 'KiB', 'MCAP chunk size; small chunks lose little when the process is killed')
    max_file_mb: float = setting(64.0, 'MB', 'rotate to a new file at this size; 0 = never')
    max_file_duration_s: float = setting(0.0, 's', 'rotate to a new file after this much log time; 0 = never')
    pairing_timeout_s: float = setting(1.0, 's', 'a measurement waits this long for its feedforward, then is '
                                       'logged without a prediction')
    log_inputs: bool = setting(True, '-', 'also log the raw input topics (temperature, joint states, current, '
                               'feedforward, measured, measured_detail)')
    residual_bin_c: float = setting(5.0, 'degC', 'temperature bin of the residual RMS on /diagnostics')
    retry_period_s: float = setting(5.0, 's', 'after a write error, try a new file this often')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        if not self.output_dir.strip():
            raise ConfigError('output_dir', 'must be a folder path', self.output_dir)
        for name, hi in (('flush_period_s', 3600.0), ('pairing_timeout_s', 3600.0), ('residual_bin_c', 1000.0),
                         ('retry_period_s', 3600.0), ('diagnostics_period_s', 3600.0)):
            if not 0.0 < getattr(self, name) <= hi:
                raise ConfigError(name, f'must lie in (0, {hi:g}]', getattr(self, name))
        if not 1 <= self.chunk_kib <= 65536:
            raise ConfigError('chunk_kib', 'must lie in [1, 65536] [KiB]', self.chunk_kib)
        for name in ('max_file_mb', 'max_file_duration_s'):
            if not 0.0 <= getattr(self, name) <= 1e9:
                raise ConfigError(name, 'must lie in [0, 1e9] (0 = never)', getattr(self, name))
