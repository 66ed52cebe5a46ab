"""Settings dataclasses of the nodes' logic: fields with unit and description, built from parameter values.

Shared by the nodes (ROS parameters with descriptors) and the offline tools (parameter files), so both accept
and refuse the same values.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import field
from typing import Any, TypeVar

from gimbal_friction.core.errors import ConfigError

T = TypeVar('T')


def setting(default: Any, unit: str, description: str) -> Any:
    """A settings field with its unit and description (turned into ROS parameter descriptors by the nodes)."""
    return field(default=default, metadata={'unit': unit, 'description': description})


def settings_from(cls: type[T], values: Mapping[str, Any], base: T | None = None) -> T:
    """Settings dataclass from parameter values, coerced to the field types and validated.

    Raises:
        ConfigError: wrong type or a value its ``validate()`` refuses.
    """
    kwargs = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in values:
            continue
        value = values[f.name]
        default = f.default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f.name, 'must be true or false', value)
        elif isinstance(default, (int, float)):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f.name, 'must be a number', value)
            value = int(value) if isinstance(default, int) and not isinstance(default, bool) else float(value)
            if isinstance(value, float) and not math.isfinite(value):
                raise ConfigError(f.name, 'must be a finite number', value)
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise ConfigError(f.name, 'must be a string', value)
        elif isinstance(default, (list, tuple)):
            value = type(default)(value)
        kwargs[f.name] = value
    obj = dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)  # type: ignore
    validate = getattr(obj, 'validate', None)
    if validate is not None:
        validate()
    return obj




def settings_from_parameters(cls: type[T], params: Mapping[str, Any]) -> T:
    """Settings of ``cls`` from a merged ``ros__parameters`` mapping (unknown keys ignored), validated."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    return settings_from(cls, {k: v for k, v in params.items() if k in names})
