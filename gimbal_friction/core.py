"""The model without ROS under its first name, ``gimbal_friction.core`` (kept for users; the code is in physics).

>>> from gimbal_friction.core import AxisParams, friction_torque
>>> round(float(friction_torque(AxisParams(), -40.0).m_total_nmm), 2)
3.14
"""

from __future__ import annotations

from gimbal_friction.common.errors import ConfigError, FitError, GimbalFrictionError, ModelDomainError
from gimbal_friction.physics.model import CONTRACT_FIELDS, FrictionResult, friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams

__all__ = ['CONTRACT_FIELDS', 'AxisParams', 'ConfigError', 'FitError', 'FrictionResult', 'GimbalFrictionError',
           'ModelDomainError', 'friction_torque', 'viscosity_cst']
