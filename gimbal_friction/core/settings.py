"""Settings dataclasses of the nodes: fields with unit and description, built from parameter values.

Shared by the nodes (ROS parameters with descriptors) and the offline tools (parameter files), so both accept
and refuse the same values. The settings of the logic live next to it (``FeedforwardSettings`` in
:mod:`gimbal_friction.core.feedforward`, ``EstimatorSettings`` in :mod:`gimbal_friction.core.estimator`); the
node-level settings (periods, rate limit, log files) are here, so that the whole set of parameter names of the suite
is known without starting a node (:func:`gimbal_friction.config.check_parameter_names`).

>>> settings_from(FeedforwardNodeSettings, {'max_rate_hz': 500}).max_rate_hz
500.0
>>> settings_from(LoggerSettings, {'chunk_kib': 64.5})
Traceback (most recent call last):
...
gimbal_friction.core.errors.ConfigError: parameter 'chunk_kib' = 64.5: must be a whole number
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from gimbal_friction.core.errors import ConfigError, check_rules

T = TypeVar('T')

__all__ = ['EstimatorNodeSettings', 'FeedforwardNodeSettings', 'LoggerSettings', 'setting',
           'settings_from', 'settings_from_parameters']


def setting(default: Any, unit: str, description: str) -> Any:
    """A settings field with its unit and description (turned into ROS parameter descriptors by the nodes)."""
    return field(default=default, metadata={'unit': unit, 'description': description})


def _coerce(name: str, value: Any, default: Any) -> Any:
    """``value`` as the type of the field's ``default``; ConfigError naming ``name`` if it is not one."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(name, 'must be true or false', value)
        return value
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(name, f'must be a number, not {type(value).__name__}', value)
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(name, 'must be a finite number', value)
        if isinstance(default, int):
            if value != int(value):
                raise ConfigError(name, 'must be a whole number', value)
            return int(value)
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(name, f'must be a string, not {type(value).__name__}', value)
        return value
    if isinstance(default, (list, tuple)):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(name, f'must be a list, not {type(value).__name__}', value)
        return type(default)(value)
    return value


def settings_from(cls: type[T], values: Mapping[str, Any], base: T | None = None) -> T:
    """Settings dataclass from parameter values, coerced to the field types and validated.

    Raises:
        ConfigError: wrong type (a float where a whole number is needed, a string where a number is, NaN or
            inf) or a value its ``validate()`` refuses.
    """
    kwargs = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name in values:
            kwargs[f.name] = _coerce(f.name, values[f.name], f.default)
    obj = dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)  # type: ignore[type-var]
    validate = getattr(obj, 'validate', None)
    if validate is not None:
        validate()
    return obj


def settings_from_parameters(cls: type[T], params: Mapping[str, Any]) -> T:
    """Settings of ``cls`` from a merged ``ros__parameters`` mapping (unknown keys ignored), validated."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    return settings_from(cls, {k: v for k, v in params.items() if k in names})


# ---------------------------------------------------------------------------------------------------- node settings
@dataclass(frozen=True)
class FeedforwardNodeSettings:
    """Node-level parameters of friction_feedforward (besides FeedforwardSettings and the model; the velocity
    source is a FeedforwardSettings, since replay and in-process callers apply it too)."""

    max_rate_hz: float = setting(0.0, 'Hz', 'publish at most this often; 0 = for every joint-state message')
    diagnostics_period_s: float = setting(1.0, 's', 'period of /diagnostics')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        check_rules(self, [
            ('max_rate_hz', 0.0 <= self.max_rate_hz <= 1e6, 'must lie in [0, 1e6] [Hz]'),
            ('diagnostics_period_s', 0.05 <= self.diagnostics_period_s <= 60.0, 'must lie in [0.05, 60] [s]'),
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
