"""Physics core of gimbal_friction: pure Python + numpy/scipy. Never imports rclpy (a test enforces it)."""

from __future__ import annotations

from gimbal_friction.core.errors import ConfigError, FitError, GimbalFrictionError, ModelDomainError
from gimbal_friction.core.model import CONTRACT_FIELDS, FrictionResult, friction_torque, viscosity_cst
from gimbal_friction.core.params import AxisParams

__all__ = ['CONTRACT_FIELDS', 'AxisParams', 'ConfigError', 'FitError', 'FrictionResult', 'GimbalFrictionError',
           'ModelDomainError', 'friction_torque', 'viscosity_cst']
