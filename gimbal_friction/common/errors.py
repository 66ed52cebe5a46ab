"""Error types of the physics core: one small type per area, all under :class:`GimbalFrictionError`."""

from __future__ import annotations

import math
from collections.abc import Iterable


class GimbalFrictionError(Exception):
    """Root of every error raised on purpose by gimbal_friction."""


class ConfigError(GimbalFrictionError):
    """A configuration value is missing, of the wrong type, or physically impossible.

    ``parameter`` names the offending parameter and ``rule`` the rule it breaks, so a tool can print a one-line
    reason and a node can refuse a parameter change with it.
    """

    def __init__(self, parameter: str, rule: str, value: object = None) -> None:
        self.parameter = parameter
        self.rule = rule
        self.value = value
        shown = '' if value is None else f' = {value!r}'
        super().__init__(f'parameter {parameter!r}{shown}: {rule}')


class ConfigFileError(ConfigError):
    """A parameter file cannot be read or is not a parameter file (``parameter`` is the file's path)."""

    def __init__(self, path: str, rule: str) -> None:
        super().__init__(path, rule)
        self.args = (f'parameter file {path}: {rule}',)


class ModelDomainError(GimbalFrictionError):
    """The model was asked for a state it cannot represent (e.g. temperature below absolute zero)."""


class FitError(GimbalFrictionError):
    """A fit could not be made or did not converge (too few points, non-finite data, divergence)."""


def check_rules(obj: object, checks: Iterable[tuple[str, bool, str]]) -> None:
    """Raise :class:`ConfigError` for the first broken rule of ``obj``'s settings.

    ``checks`` holds ``(name, ok, rule)``: the attribute, whether its rule holds and the rule in words (with the
    unit). A float attribute that is not finite is refused as such before its own rule is looked at.

    >>> class S:
    ...     step = float('nan')
    >>> check_rules(S(), [('step', S.step > 0, 'must be > 0 [s]')])
    Traceback (most recent call last):
    ...
    gimbal_friction.common.errors.ConfigError: parameter 'step' = nan: must be a finite number
    """
    for name, ok, rule in checks:
        value = getattr(obj, name)
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(name, 'must be a finite number', value)
        if not ok:
            raise ConfigError(name, rule, value)
