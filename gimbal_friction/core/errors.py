"""Error types of the physics core: one small type per area, all under :class:`GimbalFrictionError`."""

from __future__ import annotations


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


class ModelDomainError(GimbalFrictionError):
    """The model was asked for a state it cannot represent (e.g. temperature below absolute zero)."""


class FitError(GimbalFrictionError):
    """A fit could not be made or did not converge (too few points, non-finite data, divergence)."""
