"""Settings dataclasses: fields with unit and description, built from parameter values (one coercion rule).

Shared by the nodes (ROS parameters with descriptors), the simulator and the offline tools (parameter files), so all
accept and refuse the same values. Each feature declares its own settings class with :func:`setting`.

>>> from gimbal_friction.config.node_settings import FeedforwardNodeSettings, LoggerSettings
>>> settings_from(FeedforwardNodeSettings, {'max_rate_hz': 500}).max_rate_hz
500.0
>>> settings_from(LoggerSettings, {'chunk_kib': 64.5})
Traceback (most recent call last):
...
gimbal_friction.common.errors.ConfigError: parameter 'chunk_kib' = 64.5: must be a whole number
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import field
from typing import Any, TypeVar

from gimbal_friction.common.errors import ConfigError

T = TypeVar('T')

__all__ = ['coerce', 'setting', 'settings_from', 'settings_from_parameters']


def setting(default: Any, unit: str, description: str) -> Any:
    """A settings field with its unit and description (turned into ROS parameter descriptors by the nodes)."""
    return field(default=default, metadata={'unit': unit, 'description': description})


def coerce(name: str, value: Any, default: Any, *, names: bool = False) -> Any:
    """``value`` as the type of the field's ``default`` (the one coercion rule of every parameter: nodes,
    simulator, model parameters, offline tools); ConfigError naming ``name`` if it is not one.

    Numbers must be finite (NaN and inf refused); a whole number is needed where the default is an int. A list
    default takes a list (not a string): of names (``names=True``, or a default whose items are strings) or of
    finite numbers (a default whose items are numbers; returned as floats).

    >>> coerce('gain', 2, 1.0), coerce('count', 3.0, 1), coerce('speeds', [1, 2], (0.5,))
    (2.0, 3, (1.0, 2.0))
    >>> coerce('gain', float('nan'), 1.0)
    Traceback (most recent call last):
    ...
    gimbal_friction.common.errors.ConfigError: parameter 'gain' = nan: must be a finite number
    """
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
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise ConfigError(name, f'must be a list, not {type(value).__name__}', value)
        if names or any(isinstance(v, str) for v in default):
            if not all(isinstance(v, str) for v in value):
                raise ConfigError(name, 'must be a list of names', value)
            return type(default)(value)
        if default and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in default):
            if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
                raise ConfigError(name, 'must be a list of numbers', value)
            if not all(math.isfinite(v) for v in value):
                raise ConfigError(name, 'must be a list of finite numbers', value)
            return type(default)(float(v) for v in value)
        return type(default)(value)
    return value


def settings_from(cls: type[T], values: Mapping[str, Any], base: T | None = None) -> T:
    """Settings dataclass from parameter values, coerced to the field types and validated.

    Raises:
        ConfigError: wrong type (a float where a whole number is needed, a string where a number is, NaN or
            inf) or a value its ``validate()`` refuses.
    """
    kwargs = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]  # T is a settings dataclass: a TypeVar cannot be bound to "any dataclass"
        if f.name in values:
            kwargs[f.name] = coerce(f.name, values[f.name], f.default)
    obj = dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)  # type: ignore[type-var]  # T is a settings dataclass: a TypeVar cannot be bound to "any dataclass"
    validate = getattr(obj, 'validate', None)
    if validate is not None:
        validate()
    return obj


def settings_from_parameters(cls: type[T], params: Mapping[str, Any]) -> T:
    """Settings of ``cls`` from a merged ``ros__parameters`` mapping (unknown keys ignored), validated."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]  # T is a settings dataclass: a TypeVar cannot be bound to "any dataclass"
    return settings_from(cls, {k: v for k, v in params.items() if k in names})
