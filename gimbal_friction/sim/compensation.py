"""Friction compensations the closed loop can run with, and the hook they plug into.

At every controller tick the simulator hands a compensation what the real feedforward node would receive
(:class:`ControllerInputs`: the *measured* bearing temperature, the resolver's joint angle and rate relative to
the base, the reference joint velocity, the gyro) as arrays over the runs of its case, and adds the torque
[N·m] it returns, as current τ/K_T, to the controller's output, delayed by the transport latency for the
cases that run as a separate node (:class:`Compensator` ``delayed``).

Cases of the loop study (issue 9):

``none``
    no compensation.
``constant``
    :func:`constant_coulomb`: a temperature-blind Coulomb compensation tuned at +20 °C (what users do today):
    the configured model's M(+20 °C, profile speed) × the smooth sign tanh(v/v_th) of the joint's relative
    rate. It lives in the seeker controller, so no transport latency.
``feedforward``
    :func:`suite_feedforward`: the suite's feedforward with its defaults (velocity source ``measured``,
    v_th = 0.005 rad/s, clamp 0.02 N·m), delayed by the transport latency.
``refit``
    the same feedforward with parameters refitted from the residuals the suite's estimator collected in the
    same simulation (see :mod:`gimbal_friction.sim.study`).
``ideal``
    the truth friction torque of the current true state, without delay (handled inside the plant).

An optional extra case, ``feedforward_reference`` (not in the default study), runs the suite's feedforward with
``velocity_source: reference`` (the node's option): the torque follows the reference joint velocity instead of
the measured one, so it is not a feedback through the friction (see the study notes in the README draft).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.core.feedforward import FeedforwardSettings
from gimbal_friction.core.params import AxisParams
from gimbal_friction.sim.truth import ModelMagnitude, TemperatureTerms

Array = NDArray[np.float64]

__all__ = ['CASES', 'CASE_IDEAL', 'CASE_NONE', 'EXTRA_CASES', 'Compensator', 'ControllerInputs', 'TorqueHook',
           'constant_coulomb', 'suite_feedforward']

#: The cases of the loop study, in report order.
CASES = ('none', 'constant', 'feedforward', 'refit', 'ideal')
#: Optional cases the study also knows (not run by default).
EXTRA_CASES = ('feedforward_reference',)
CASE_NONE = 'none'
CASE_IDEAL = 'ideal'
#: Temperature a constant (temperature-blind) compensation is tuned at [°C].
CONSTANT_TUNING_C = 20.0


class ControllerInputs(NamedTuple):
    """What a compensation receives at a controller tick, as arrays over its runs (shape (runs,))."""

    time_s: float                     #: controller time [s]
    temperature_c: Array              #: measured bearing temperature (sensor, held between samples) [°C]
    joint_position_rad: Array         #: resolver: gimbal angle relative to the base [rad]
    joint_velocity_rad_s: Array       #: resolver (RDC): gimbal rate relative to the base [rad/s]
    reference_velocity_rad_s: Array   #: reference joint velocity: commanded LOS rate − base rate estimate [rad/s]
    gyro_rate_rad_s: Array            #: LOS rate gyro (inertial) [rad/s]


#: A compensation: inputs of one tick -> feedforward torque [N·m] per run.
TorqueHook = Callable[[ControllerInputs], ArrayLike]


class Compensator(NamedTuple):
    """A compensation case: its torque hook and whether the transport latency applies."""

    torque: TorqueHook
    delayed: bool = True


def _smooth_sign(v: Array, v_th: float) -> Array:
    return np.asarray(np.tanh(v / v_th))


def constant_coulomb(axis: AxisParams, speed_rad_s: float,
                     settings: FeedforwardSettings | None = None) -> Compensator:
    """Case (b): constant Coulomb compensation M(+20 °C, ``speed_rad_s``) × tanh(v / v_th), not delayed.

    Parameters
    ----------
    axis : AxisParams
        Configured model (the user tuned the constant on it at +20 °C).
    speed_rad_s : float
        The profile's speed the constant is tuned at [rad/s] (at +20 °C the model does not depend on speed below
        ≈ 2.4 rad/s: ν n < 2000, the lower Palmgren branch).
    settings : FeedforwardSettings, optional
        For the smooth-sign width v_th (the suite's default 0.005 rad/s).

    >>> hook = constant_coulomb(AxisParams(), 0.0349).torque
    >>> x = hook(ControllerInputs(0.0, np.array([-40.0]), np.zeros(1), np.array([0.1]), np.zeros(1), np.zeros(1)))
    >>> round(float(x[0]) * 1e3, 3)   # N*mm: the +20 degC level whatever the temperature
    1.046
    """
    s = settings if settings is not None else FeedforwardSettings()
    mm = ModelMagnitude(axis)
    level = float(mm.magnitude_nm(mm.terms(np.array([CONSTANT_TUNING_C])), np.array([speed_rad_s]))[0])
    v_th = s.velocity_threshold_rad_s

    def torque(inputs: ControllerInputs) -> Array:
        return level * _smooth_sign(inputs.joint_velocity_rad_s, v_th)

    return Compensator(torque, delayed=False)


def suite_feedforward(axis: AxisParams, settings: FeedforwardSettings | None = None, *,
                      velocity_source: str = 'measured') -> Compensator:
    """Case (c)/(d): the suite's feedforward rule over arrays of runs, delayed by the transport latency.

    τ = clamp(tanh(v / v_th) · k_dir · M(t, |v|), ±max_torque_nm) with M the tabulated model of ``axis`` at the
    measured temperature t, k_dir = ``scale_positive`` / ``scale_negative``, v the joint's relative rate from the
    resolver (``velocity_source='measured'``, the node's default) or the reference joint velocity
    (``'reference'``). Temperatures are always fresh in the simulation, so the stale policy never acts.

    >>> hook = suite_feedforward(AxisParams()).torque
    >>> x = hook(ControllerInputs(0.0, np.array([-40.0, 20.0]), np.zeros(2), np.full(2, -0.0349066),
    ...                           np.zeros(2), np.zeros(2)))
    >>> [round(float(v) * 1e3, 3) for v in x]   # N*mm, tanh(7) = 0.999998
    [-3.143, -1.046]
    """
    # replaced by core feedforward at integration: the lead's xp-generic rule of core/feedforward.py takes this
    # adapter's place (same inputs, same torque); until then it restates the node's rule over arrays.
    s = settings if settings is not None else FeedforwardSettings()
    if velocity_source not in ('measured', 'reference'):
        msg = f'velocity_source must be measured or reference, not {velocity_source!r}'
        raise ValueError(msg)
    mm = ModelMagnitude(axis, s.temperature_min_c, s.temperature_max_c, s.table_step_c)
    v_th, limit = s.velocity_threshold_rad_s, s.max_torque_nm
    k_pos, k_neg = axis.scale_positive, axis.scale_negative
    cache: list[TemperatureTerms] = []

    def torque(inputs: ControllerInputs) -> Array:
        t = inputs.temperature_c
        if not cache or cache[0].temperature_c.shape != t.shape or not np.array_equal(cache[0].temperature_c, t):
            cache[:] = [mm.terms(t)]
            cache[0] = cache[0]._replace(temperature_c=np.array(t, dtype=float))
        v = inputs.joint_velocity_rad_s if velocity_source == 'measured' else inputs.reference_velocity_rad_s
        k = np.where(v >= 0.0, k_pos, k_neg)
        tau = _smooth_sign(v, v_th) * k * mm.magnitude_nm(cache[0], v)
        return np.clip(tau, -limit, limit)

    return Compensator(torque, delayed=True)
