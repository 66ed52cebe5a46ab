"""The model without ROS under its first name, ``gimbal_friction.core`` (kept for users; the code is in physics).

The entry points here keep to the model's validity range (:mod:`gimbal_friction.physics.validity`: −40…+60 °C with the
paper's parameters): a temperature outside it is refused with one line (:class:`ModelDomainError`) unless
``extrapolate=True`` asks for the equations there anyway.

>>> from gimbal_friction.core import AxisParams, friction_torque
>>> round(float(friction_torque(AxisParams(), -40.0).m_total_nmm), 2)
3.14
>>> friction_torque(AxisParams(), -100.0)
Traceback (most recent call last):
...
gimbal_friction.common.errors.ModelDomainError: temperature -100 degC lies outside the model's validity range \
-40..60 degC (where the paper computed and measured the friction; the lubricant data reach -32..204 degC)
>>> round(float(friction_torque(AxisParams(), -50.0, extrapolate=True).m_total_nmm), 2)   # the equations past it
9.75
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ConfigError, FitError, GimbalFrictionError, ModelDomainError
from gimbal_friction.physics import model as _model
from gimbal_friction.physics.model import CONTRACT_FIELDS, FrictionResult
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.validity import (
    LUBRICANT_T_MAX_C,
    LUBRICANT_T_MIN_C,
    ValidityRange,
    check_temperatures,
    validity_range,
)

__all__ = ['CONTRACT_FIELDS', 'AxisParams', 'ConfigError', 'FitError', 'FrictionResult', 'GimbalFrictionError',
           'ModelDomainError', 'ValidityRange', 'friction_torque', 'validity_range', 'viscosity_cst']


def friction_torque(p: AxisParams, t_c: ArrayLike, speed_rpm: ArrayLike | None = None, *, direct: bool = False,
                    extrapolate: bool = False) -> FrictionResult:
    """Friction torque of the axis and its components at temperatures ``t_c`` [°C] and ``speed_rpm`` [rpm]
    (:func:`gimbal_friction.physics.model.friction_torque`), inside the model's validity range
    (:func:`validity_range`).

    Raises:
        ModelDomainError: a temperature outside the validity range (unless ``extrapolate``), or a state the model
            cannot represent.
    """
    if not extrapolate:
        check_temperatures(p, t_c)
    return _model.friction_torque(p, t_c, speed_rpm, direct=direct)


def viscosity_cst(p: AxisParams, t_c: ArrayLike, *, extrapolate: bool = False) -> NDArray[np.float64]:
    """Kinematic viscosity of the configured lubricant at ``t_c`` [°C], Eq. (20)/(21), [mm²/s], inside the range its
    fit is used over (the data of Table 2, −32…204 °C, and down to −40 °C as the paper uses it).

    Raises:
        ModelDomainError: a temperature outside that range (unless ``extrapolate``).
    """
    if not extrapolate:
        check_temperatures(p, t_c, LUBRICANT_T_MIN_C, LUBRICANT_T_MAX_C)
    return _model.viscosity_cst(p, t_c)
