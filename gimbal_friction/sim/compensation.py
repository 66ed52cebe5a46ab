"""Friction compensations the closed loop can run with, and the hook they plug into.

At every controller tick the simulator hands a compensation what the real feedforward node would receive
(:class:`ControllerInputs`: the latest bearing temperature the sensor published and its stamp, the resolver's joint
angle and rate relative to the base, the reference joint velocity, the gyro) as arrays over the runs of its case,
and adds the torque [N·m] it returns, as current τ/K_T, to the controller's output, delayed by the transport
latency for the cases that run as a separate node (:class:`Compensator` ``delayed``).

Cases of the loop study (the default five):

``none``
    no compensation.
``constant``
    :func:`constant_coulomb`: a temperature-blind Coulomb compensation tuned at +20 °C (what users do today): the
    suite's own torque rule evaluated at +20 °C whatever the temperature, on the same velocity as the feedforward.
    It lives in the seeker controller, so no transport latency.
``feedforward``
    :func:`suite_feedforward`: the suite's feedforward (:class:`~gimbal_friction.feedforward.rule.Feedforward`,
    its torque rule and its temperature rules, as configured), delayed by the transport latency.
``refit``
    the same feedforward with parameters refitted from the residuals the suite's estimator collected in the
    same simulation (see :mod:`gimbal_friction.sim.study`).
``learned``
    the same feedforward carrying a learned correction (:class:`~gimbal_friction.feedforward.correction.Correction`,
    looked up at the resolver's joint angle): one correction learned online over a service history, then frozen and
    scored on another seed and on every profile (see :mod:`gimbal_friction.sim.study`).
``dynamic``
    :func:`dynamic_feedforward`: case ``learned`` plus a pre-sliding term
    (:class:`~gimbal_friction.feedforward.presliding.PreslidingTerm`, a Dahl state in place of the smooth sign where
    its guard applies it) identified from the same service history (see :mod:`gimbal_friction.sim.study`).
``chamber``
    the same feedforward carrying the correction learned from the chamber test alone (the suite's chamber path).
``bound``
    :func:`truth_bound`: the truth's own static friction map (temperature, direction, position, speed) delivered
    through the same latency, current loop and smooth sign as the feedforward: what a perfect static feedforward
    achieves.
``ideal``
    the truth friction torque of the current true state, without delay (handled inside the plant).

Optional cases (not in the default study) run the feedforward on one velocity source whatever the configuration:
``feedforward_measured`` (the joint state's velocity) and ``feedforward_reference`` (the reference joint velocity,
``/gimbal/reference_velocity``), for before/after comparisons of the wiring. ``dynamic_unguarded`` is case
``dynamic`` with its pre-sliding term applied at the fitted distance in every temperature bin with data, whatever
its guard says (what the guard holds back).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.xp import ARRAY
from gimbal_friction.feedforward.correction import Correction
from gimbal_friction.feedforward.presliding import PreslidingTerm, dahl_step, presliding_torque_nm
from gimbal_friction.feedforward.rule import (
    VELOCITY_SOURCES,
    Feedforward,
    FeedforwardSettings,
    check_velocity_source,
    temperature_used,
    velocity_used,
)
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import TemperatureTerms
from gimbal_friction.streams.inputs import is_fresh, temperature_valid

if TYPE_CHECKING:
    from gimbal_friction.sim.config import SimConfig
    from gimbal_friction.sim.truth import TruthTerms

Array = NDArray[np.float64]

__all__ = ['CASES', 'CASE_CHAMBER', 'CASE_IDEAL', 'CASE_NONE', 'DEFAULT_CASES', 'EXTRA_CASES', 'JOINT',
           'VELOCITY_SOURCES', 'Compensator', 'ControllerInputs', 'TorqueHook', 'constant_coulomb',
           'dynamic_feedforward', 'model_friction', 'suite_feedforward', 'truth_bound']

#: The cases of the loop study, in report order.
CASES = ('none', 'constant', 'feedforward', 'refit', 'learned', 'dynamic', 'chamber', 'bound', 'ideal')
#: The cases run when none are named (all of :data:`CASES` but ``dynamic``, asked for by name).
DEFAULT_CASES = tuple(c for c in CASES if c != 'dynamic')
#: Optional cases the study also knows (not run by default).
EXTRA_CASES = ('feedforward_measured', 'feedforward_reference', 'dynamic_unguarded')
CASE_NONE = 'none'
CASE_IDEAL = 'ideal'
CASE_CHAMBER = 'chamber'
#: Temperature a constant (temperature-blind) compensation is tuned at [°C].
CONSTANT_TUNING_C = 20.0
#: Joint name of the simulated axis (the suite's default axis).
JOINT = 'elevation'


class ControllerInputs(NamedTuple):
    """What a compensation receives at a controller tick, as arrays over its runs (shape (runs,))."""

    time_s: float                     #: controller time = stamp of the joint state of this tick [s]
    temperature_c: Array              #: latest bearing temperature the sensor published [°C] (NaN: none yet)
    temperature_time_s: Array         #: its stamp [s] (NaN: none yet)
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


def _velocity(inputs: ControllerInputs, source: str) -> Array:
    # the simulated reference is computed at the tick it is used: always fresh ('auto' = 'reference')
    return velocity_used(source, inputs.joint_velocity_rad_s, inputs.reference_velocity_rad_s, True, ARRAY)


class _TermsCache:
    """The table's temperature terms of the last temperatures asked for (they change at the sensor's rate)."""

    def __init__(self, ff: Feedforward, joint: str) -> None:
        self.table = ff.tables[joint]
        self.at: Array | None = None
        self.terms: TemperatureTerms[Array] | None = None

    def get(self, t_c: Array) -> TemperatureTerms[Array]:
        if self.terms is None or self.at is None or self.at.shape != t_c.shape or not np.array_equal(self.at, t_c):
            self.at = np.array(t_c, dtype=float)
            self.terms = self.table.temperature_terms(self.at, ARRAY)
        return self.terms


def constant_coulomb(axis: AxisParams, settings: FeedforwardSettings | None = None, *,
                     velocity_source: str = 'measured') -> Compensator:
    """Case (b): the suite's torque rule at a fixed +20 °C (temperature-blind), not delayed.

    τ = clamp(tanh(v / v_th) k_dir M(+20 °C, |v|), ±τ_max) (:meth:`Feedforward.rule`): below about 2.4 rad/s the
    model at +20 °C does not depend on speed (Palmgren's lower branch, ν n < 2000), so this is the Coulomb
    compensation a user tunes at room temperature.

    Parameters
    ----------
    axis : AxisParams
        Configured model (the user tuned the constant on it at +20 °C).
    settings : FeedforwardSettings, optional
        For the smooth-sign width v_th and the clamp (the suite's defaults).
    velocity_source : str
        ``measured`` (the resolver's joint rate) or ``reference`` (the reference joint velocity).

    >>> hook = constant_coulomb(AxisParams()).torque
    >>> x = hook(ControllerInputs(0.0, np.array([-40.0]), np.zeros(1), np.zeros(1), np.array([0.1]), np.zeros(1),
    ...                           np.zeros(1)))
    >>> round(float(x[0]) * 1e3, 3)   # N*mm: the +20 degC level whatever the temperature
    1.046
    """
    check_velocity_source(velocity_source)
    ff = Feedforward({JOINT: axis}, settings if settings is not None else FeedforwardSettings())
    cache = _TermsCache(ff, JOINT)

    def torque(inputs: ControllerInputs) -> Array:
        v = _velocity(inputs, velocity_source)
        t = np.full(v.shape, CONSTANT_TUNING_C)
        return np.asarray(ff.rule(JOINT, v, t, ARRAY, terms=cache.get(t)), dtype=float)

    return Compensator(torque, delayed=False)


def suite_feedforward(axis: AxisParams, settings: FeedforwardSettings | None = None, *,
                      velocity_source: str = 'measured', correction: Correction | None = None) -> Compensator:
    """Case (c)/(d): the suite's feedforward over arrays of runs, delayed by the transport latency.

    The torque is :meth:`Feedforward.rule` of a :class:`~gimbal_friction.feedforward.rule.Feedforward` of ``axis``
    and ``settings``; the temperature is chosen by the node's rules on the sensor's stamps: a published sample is
    kept if valid (:func:`~gimbal_friction.streams.inputs.temperature_valid`), it is used while fresh for the joint
    state's stamp (:func:`~gimbal_friction.streams.inputs.is_fresh`), otherwise the stale policy decides
    (:func:`~gimbal_friction.feedforward.rule.temperature_used`; ``zero`` gives 0 N·m). The velocity is the
    resolver's joint rate relative to the base (``velocity_source='measured'``) or the reference joint velocity
    (``'reference'``), as the node's ``velocity_source``.

    With ``correction`` (case ``learned``) the feedforward carries it (:meth:`Feedforward.rule`:
    ``τ = clamp(tanh(v/v_th) (k_dir M + c), ±τ_max)``, looked up at the resolver's joint angle; read at every tick,
    so a learner updating the correction in place acts at once); an empty correction gives exactly the plain
    feedforward.

    >>> hook = suite_feedforward(AxisParams()).torque
    >>> x = hook(ControllerInputs(0.0, np.array([-40.0, 20.0]), np.zeros(2), np.zeros(2), np.full(2, -0.0349066),
    ...                           np.zeros(2), np.zeros(2)))
    >>> [round(float(v) * 1e3, 3) for v in x]   # N*mm, tanh(7) = 0.999998
    [-3.143, -1.046]
    >>> x = hook(ControllerInputs(10.0, np.array([-40.0, 20.0]), np.zeros(2), np.zeros(2), np.full(2, -0.0349066),
    ...                           np.zeros(2), np.zeros(2)))
    >>> [round(float(v) * 1e3, 3) for v in x]   # 10 s later the temperature is stale: fallback +20 degC
    [-1.046, -1.046]
    """
    check_velocity_source(velocity_source)
    s = settings if settings is not None else FeedforwardSettings()
    ff = Feedforward({JOINT: axis}, s, correction=correction)
    cache = _TermsCache(ff, JOINT)
    temperatures = _TemperatureRules(s)

    def torque(inputs: ControllerInputs) -> Array:
        t_eval, zero = temperatures.used(inputs)
        tau = ff.rule(JOINT, _velocity(inputs, velocity_source), t_eval, ARRAY, terms=cache.get(t_eval),
                      position_rad=inputs.joint_position_rad)
        return np.where(zero, 0.0, tau)

    return Compensator(torque, delayed=True)


class _TemperatureRules:
    """The node's temperature rules over arrays of runs: a published sample kept if valid, used while fresh for the
    joint state's stamp, else the stale policy (``zero``: no torque)."""

    def __init__(self, settings: FeedforwardSettings) -> None:
        self.s = settings
        self.state: dict[str, Array] = {}

    def used(self, inputs: ControllerInputs) -> tuple[Array, NDArray[np.bool_]]:
        """(temperature to evaluate the rule at [°C], runs whose policy gives 0 N·m)."""
        s, state = self.s, self.state
        t_in = np.asarray(inputs.temperature_c, dtype=float)
        stamp = np.asarray(inputs.temperature_time_s, dtype=float)
        if not state or state['last_c'].shape != t_in.shape:
            state['last_c'] = np.full(t_in.shape, math.nan)
            state['last_time'] = np.full(t_in.shape, math.nan)
            state['seen'] = np.full(t_in.shape, math.nan)
        new = np.isfinite(stamp) & ~(stamp == state['seen'])
        if new.any():   # a newly published sample: kept if valid (a rejected one leaves the last valid one)
            state['seen'] = np.where(new, stamp, state['seen'])
            valid, _ = temperature_valid(np.where(new, t_in, math.nan), s.temperature_min_c, s.temperature_max_c)
            state['last_c'] = np.where(valid, t_in, state['last_c'])
            state['last_time'] = np.where(valid, stamp, state['last_time'])
        fresh = is_fresh(inputs.time_s, state['last_time'], s.temperature_timeout_s, ARRAY)
        t_used, _ = temperature_used(state['last_c'], fresh, s, ARRAY)
        t_used = np.broadcast_to(np.asarray(t_used, dtype=float), t_in.shape)
        zero = np.isnan(t_used)
        return np.where(zero, s.fallback_temperature_c, t_used), zero


def dynamic_feedforward(axis: AxisParams, settings: FeedforwardSettings | None = None, *,
                        velocity_source: str = 'measured', correction: Correction | None = None,
                        presliding: PreslidingTerm | None = None) -> Compensator:
    """Case ``dynamic``: :func:`suite_feedforward` (with ``correction``) whose smooth sign is replaced, in the
    temperature bins where ``presliding`` is applied, by its Dahl state
    (:mod:`gimbal_friction.feedforward.presliding`): ``τ = clamp(s (k_d M + c_odd) + c_even, ±τ_max)``, the state
    of each run driven by the feedforward's velocity (``velocity_source``) between ticks. Where the term is off (or
    without one) the torque is exactly :func:`suite_feedforward`'s. Delayed by the transport latency.
    """
    check_velocity_source(velocity_source)
    s = settings if settings is not None else FeedforwardSettings()
    ff = Feedforward({JOINT: axis}, s, correction=correction)
    cache = _TermsCache(ff, JOINT)
    temperatures = _TemperatureRules(s)
    state: dict[str, Array] = {}

    def torque(inputs: ControllerInputs) -> Array:
        t_eval, zero = temperatures.used(inputs)
        v = _velocity(inputs, velocity_source)
        tau = ff.rule(JOINT, v, t_eval, ARRAY, terms=cache.get(t_eval), position_rad=inputs.joint_position_rad)
        static_sign = np.tanh(v / s.velocity_threshold_rad_s)
        if presliding is None or not presliding.active:
            return np.where(zero, 0.0, tau)
        delta = presliding.distance_rad(JOINT, t_eval)
        on = np.isfinite(delta)
        if 'sign' not in state or state['sign'].shape != v.shape:
            state['sign'] = static_sign.copy()
            state['time'] = np.full(v.shape, inputs.time_s)
        step = inputs.time_s - state['time']
        moved = dahl_step(state['sign'], v, step, np.where(on, delta, 1.0))
        restart = ~on | (step > presliding.settings.max_step_s)
        sign = np.where(restart, static_sign, moved)
        state['sign'], state['time'] = sign, np.full(v.shape, inputs.time_s)
        if not on.any():
            return np.where(zero, 0.0, tau)
        model = np.asarray(ff.model_nm(JOINT, v, t_eval, ARRAY), dtype=float)
        if correction is not None:
            odd, even = correction.split_nm_array(JOINT, t_eval, v, inputs.joint_position_rad, model)
        else:
            odd, even = np.zeros(v.shape), np.zeros(v.shape)
        dyn = presliding_torque_nm(sign, model + odd, even, s.max_torque_nm)
        return np.where(zero, 0.0, np.where(on, dyn, tau))

    return Compensator(torque, delayed=True)


def model_friction(axis: AxisParams) -> Callable[[ArrayLike, ArrayLike], Array]:
    """The configured model's friction k_dir M [N·m], signed like the motion, as a function of temperatures [°C] and
    velocities [rad/s] (what a residual is taken against: measured − model; NaN in, NaN out).

    >>> f = model_friction(AxisParams())
    >>> [round(float(x) * 1e3, 3) for x in f([-40.0, 20.0], [-0.0349066, 0.0349066])]   # N*mm
    [-3.143, 1.046]
    """
    ff = Feedforward({JOINT: axis}, FeedforwardSettings())

    def friction(temperature_c: ArrayLike, velocity_rad_s: ArrayLike) -> Array:
        t = np.asarray(temperature_c, dtype=float)
        v = np.asarray(velocity_rad_s, dtype=float)
        known = np.isfinite(t)
        out = np.sign(v) * ff.model_nm(JOINT, v, np.where(known, t, 20.0), ARRAY)
        return np.asarray(np.where(known, out, np.nan), dtype=float)

    return friction


def truth_bound(config: SimConfig, settings: FeedforwardSettings | None = None, *,
                velocity_source: str = 'measured') -> Compensator:
    """Case ``bound``: the truth's own static friction map through the feedforward's delivery, delayed.

    τ = clamp(tanh(v / v_th) |F_ss(t, v, θ)|, ±τ_max) with ``F_ss`` the truth's steady-state friction
    (:meth:`~gimbal_friction.sim.truth.TruthFriction.static_torque_nm`: the truth lubricant, direction asymmetry,
    mean factor, position ripple at the resolver's joint angle θ, LuGre Stribeck level and no-load torque) at the
    measured temperature less the sensor's known bias (a perfect static map keyed on what the feedforward sees),
    ``v`` the feedforward's velocity (same ``velocity_source``), the same smooth sign, clamp and transport latency.
    No temperature: no torque. ``config`` is the simulator's :class:`~gimbal_friction.sim.config.SimConfig`.
    """
    from gimbal_friction.sim.truth import TruthFriction, ripple
    check_velocity_source(velocity_source)
    s = settings if settings is not None else FeedforwardSettings()
    truth = TruthFriction(config)
    cached: list[tuple[Array, TruthTerms]] = []   # the last temperatures asked for and their terms

    def torque(inputs: ControllerInputs) -> Array:
        t_in = np.asarray(inputs.temperature_c, dtype=float) - config.temperature_bias_c
        have = np.isfinite(t_in)
        t_eval = np.where(have, t_in, s.fallback_temperature_c)
        if not cached or not np.array_equal(cached[0][0], t_eval):
            cached[:] = [(t_eval.copy(), truth.terms(t_eval))]
        v = _velocity(inputs, velocity_source)
        g = truth.stribeck_level_nm(cached[0][1], v, 1.0 + ripple(config, inputs.joint_position_rad, t_eval))
        tau = np.clip(np.tanh(v / s.velocity_threshold_rad_s) * g, -s.max_torque_nm, s.max_torque_nm)
        return np.where(have, tau, 0.0)

    return Compensator(torque, delayed=True)
