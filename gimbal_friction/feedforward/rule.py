r"""The feedforward of ``friction_feedforward`` as one object: the node, the offline replay, the closed-loop study
and a controller in the same process all use :class:`Feedforward` (pure: no rclpy, no I/O).

One job in one module: the feedforward rule (its settings, the rules on floats and arrays and the object that
applies them per message and per bag must change together).

Torque of a joint = model friction magnitude at the bearing temperature and speed (the tabulated fast path,
:class:`~gimbal_friction.physics.table.FrictionTable`) × a smooth sign of the velocity × the direction factor of the
joint at that temperature (:func:`~gimbal_friction.physics.direction.direction_factor`: ``scale_positive`` /
``scale_negative`` and the temperature-dependent CW/CCW asymmetry), clamped to ``max_torque_nm``
(:func:`feedforward_torque_nm`):

.. math:: \tau = \operatorname{clamp}\left(\tanh(v / v_{th})\; \big(k_{dir}\; M(t, |v|) + c_{odd}\big)
          + c_{even},\ \pm\tau_{max}\right)

``tanh`` reaches 0.995 at |v| = 3 v_th, so the output does not chatter around zero speed. ``c_odd`` and ``c_even``
[N·m] are the optional learned correction (:class:`~gimbal_friction.feedforward.correction.Correction`,
:meth:`Feedforward.set_correction`): its part along the motion and its part independent of the direction of motion
(an unbalance: not switched off at a reversal), looked up at the temperature used, the velocity used, the joint
position and the model friction ``k_dir M``; the position is the reference position when the velocity used is the
reference's and the reference message carried a finite one, else the joint state's (NaN: no position terms).
Without a correction, or for a joint the correction has no value for, the torque is exactly the model's (the same
floating-point operations as without the correction).

Temperature (the rules of :mod:`gimbal_friction.streams.inputs`): the latest valid temperature received is used
while it is fresh, i.e. while the time of the sample (joint-state stamp; arrival time if the stamp is zero) and the
time of the temperature differ by at most ``temperature_timeout_s``; otherwise the stale policy decides
(:func:`temperature_used`): ``hold_last`` keeps the last valid temperature (the fallback temperature before any),
``fallback_temperature`` uses ``fallback_temperature_c``, ``zero`` outputs 0 N·m. Inputs that cannot be trusted
(non-finite or out-of-range temperature, unknown or repeated joint names, mismatched arrays, non-finite velocity)
never reach the output; the reason is counted (:attr:`Feedforward.counters`).

The model's validity range (:mod:`gimbal_friction.physics.validity`, −40…+60 °C with the paper's parameters): each
joint's table spans the credible range ``[temperature_min_c, temperature_max_c]`` within it (:func:`model_range`,
:attr:`Feedforward.model_ranges`); a credible temperature outside is used at the edge of that range (the table
clamps) and counted per joint (``counters.temperature_clamped``), so the feedforward never extrapolates the model.

Every rule is written once against the namespace ``xp`` (:mod:`gimbal_friction.common.xp`): on Python floats for a
message or a controller tick (:meth:`Feedforward.torque_nm`, :meth:`Feedforward.message`, under 1 µs per joint) and
on numpy arrays for a whole bag (:meth:`Feedforward.bag_torques`).

>>> ff = Feedforward({'elevation': AxisParams()}, FeedforwardSettings())
>>> ff.update_temperature(-40.0, time_s=0.0) is None
True
>>> round(ff.torque_nm('elevation', 0.0349066, time_s=0.01) * 1e3, 3)   # N*mm at 1/3 rpm, -40 degC
3.143
>>> round(ff.torque_nm('elevation', -0.0349066, time_s=10.0) * 1e3, 3)  # stale: fallback 20 degC
-1.046
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError, check_rules
from gimbal_friction.common.settings import setting
from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.common.xp import ARRAY, SCALAR, BoolOrArray, Namespace, X
from gimbal_friction.feedforward.correction import Correction, CorrectionError, ModelIdentity, model_identity
from gimbal_friction.feedforward.correction.judge import LoopJudge
from gimbal_friction.feedforward.correction.lookup import Lookup, ScalarTerms
from gimbal_friction.physics.direction import direction_factors, select_direction
from gimbal_friction.physics.friction import PALMGREN_THRESHOLD_CST_RPM
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, AxisParams
from gimbal_friction.physics.table import FrictionTable, TemperatureTerms, magnitude_from_terms
from gimbal_friction.physics.validity import ValidityRange, validity_range
from gimbal_friction.streams.arrays import ChamberArrays, JointStateArrays
from gimbal_friction.streams.inputs import (
    J_DUPLICATE,
    J_MISMATCH,
    J_NONE,
    J_UNKNOWN,
    JointIndex,
    effective_time,
    index_joints,
    is_fresh,
    latest_before,
    temperature_rejection,
    temperature_valid,
)

STALE_POLICIES = ('hold_last', 'fallback_temperature', 'zero')
#: where the temperature of an output came from (codes of :func:`temperature_used`)
SOURCE_MEASURED, SOURCE_HOLD_LAST, SOURCE_FALLBACK, SOURCE_ZERO = 0, 1, 2, 3
SOURCE_NAMES = ('measured', 'hold_last', 'fallback_temperature', 'zero')
#: Velocities the torque may use (the node's ``velocity_source``): the joint state's, the reference's, or the
#: reference while it is fresh and the joint state's otherwise.
VELOCITY_SOURCES = ('measured', 'reference', 'auto')
NON_FINITE_VELOCITY = 'non-finite velocity'
_NO_REFERENCE = (math.nan, math.nan)  # (velocity [rad/s], time [s]) of a joint without a reference yet
_tanh, _log2, _cbrt = math.tanh, math.log2, SCALAR.cbrt   # (module globals: one lookup each on the scalar path)
#: what the scalar call :meth:`Feedforward.torque_nm` keeps per joint (:meth:`Feedforward._terms_at`)
_ScalarPlan = tuple[float, Lookup | None, float, float, float, float, float, ScalarTerms | None]


@dataclass(frozen=True)
class FeedforwardSettings:
    """Settings of the feedforward (ROS parameters of ``friction_feedforward``; units in the names)."""

    velocity_threshold_rad_s: float = setting(0.002, 'rad/s', 'v_th of the smooth sign tanh(v/v_th); keep it '
                                              "above ~5x the velocity noise; the paper's test speed 1/3 rpm is "
                                              '0.0349 rad/s')
    max_torque_nm: float = setting(0.02, 'N*m', "output clamp on the torque magnitude (the paper's largest friction is "
                                   '3.2e-3 N*m)')
    temperature_timeout_s: float = setting(5.0, 's', 'a temperature whose stamp differs from the joint-state stamp '
                                           'by more than this is stale')
    stale_policy: str = setting('fallback_temperature', '-', 'with no fresh valid temperature: hold_last (keep '
                                'the last valid one), fallback_temperature (use fallback_temperature_c) or zero '
                                '(publish 0 N*m)')
    fallback_temperature_c: float = setting(20.0, 'degC', 'temperature used by the fallback_temperature policy')
    temperature_min_c: float = setting(-60.0, 'degC', 'lowest credible bearing temperature (lower ones are '
                                       'refused); the model table spans the part of [temperature_min_c, '
                                       "temperature_max_c] inside the model's validity range (-40..60 degC): a "
                                       "credible temperature outside it is used at the range's edge and counted")
    temperature_max_c: float = setting(120.0, 'degC', 'highest credible bearing temperature')
    table_step_c: float = setting(0.1, 'degC', 'temperature step of the model table')
    velocity_source: str = setting('auto', '-', 'velocity used for the torque: measured (joint_states velocity, '
                                   'relative to the base), reference (reference_velocity topic; 0 N*m when it is '
                                   'stale) or auto (reference while fresh, else measured)')
    reference_timeout_s: float = setting(0.5, 's', 'a reference velocity whose stamp differs from the joint '
                                         "state's by more than this is stale")

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        checks = [
            ('velocity_threshold_rad_s', 1e-6 <= self.velocity_threshold_rad_s <= 10.0,
             'must lie in [1e-6, 10] [rad/s]'),
            ('max_torque_nm', 0.0 < self.max_torque_nm <= 100.0, 'must lie in (0, 100] [N*m]'),
            ('temperature_timeout_s', 0.0 < self.temperature_timeout_s <= 86400.0, 'must lie in (0, 86400] [s]'),
            ('stale_policy', self.stale_policy in STALE_POLICIES, f'must be one of {", ".join(STALE_POLICIES)}'),
            ('temperature_min_c', self.temperature_min_c >= MODEL_T_MIN_C, f'must be >= {MODEL_T_MIN_C:g} [degC]'),
            ('temperature_max_c', self.temperature_max_c <= MODEL_T_MAX_C, f'must be <= {MODEL_T_MAX_C:g} [degC]'),
            ('temperature_max_c', self.temperature_max_c > self.temperature_min_c,
             'must exceed temperature_min_c [degC]'),
            ('fallback_temperature_c', self.temperature_min_c <= self.fallback_temperature_c
             <= self.temperature_max_c, 'must lie within [temperature_min_c, temperature_max_c] [degC]'),
            ('table_step_c', 0.001 <= self.table_step_c <= 5.0, 'must lie in [0.001, 5] [degC]'),
            ('velocity_source', self.velocity_source in VELOCITY_SOURCES,
             f'must be one of {", ".join(VELOCITY_SOURCES)}'),
            ('reference_timeout_s', 0.0 < self.reference_timeout_s <= 3600.0, 'must lie in (0, 3600] [s]'),
        ]
        check_rules(self, checks)


def model_range(settings: FeedforwardSettings, validity: ValidityRange, joint: str = '') -> tuple[float, float]:
    """The temperatures [°C] a joint's model table spans: the credible range ``[temperature_min_c,
    temperature_max_c]`` of ``settings`` within the model's ``validity`` range (the one rule the node, the replay,
    the simulator and the in-process API share: the table never reaches past the range where the model holds).

    Raises:
        ConfigError: the two ranges do not overlap.

    >>> model_range(FeedforwardSettings(), ValidityRange(-40.0, 60.0, ''))
    (-40.0, 60.0)
    """
    low = max(settings.temperature_min_c, validity.low_c)
    high = min(settings.temperature_max_c, validity.high_c)
    if not low < high:
        of = f' of joint {joint}' if joint else ''
        raise ConfigError('temperature_min_c', f'the credible range {settings.temperature_min_c:g}..'
                          f"{settings.temperature_max_c:g} degC leaves nothing of the model's validity range "
                          f'{validity.text}{of}', settings.temperature_min_c)
    return low, high


# ---------------------------------------------------------------------------------------------------- the rules
def feedforward_torque_nm(terms: TemperatureTerms[X], k_positive: X, k_negative: X, velocity_rad_s: X,
                          v_th: float, max_torque_nm: float, xp: Namespace[X]) -> X:
    """``clamp(tanh(v/v_th) · k_dir · M, ±τ_max)``: the feedforward torque [N·m] at velocity ``velocity_rad_s``
    [rad/s] from what depends on temperature only: the table's ``terms`` (:meth:`FrictionTable.temperature_terms`,
    giving the magnitude M [N·m] with :func:`~gimbal_friction.physics.table.magnitude_from_terms`) and the direction
    factors ``k_positive``, ``k_negative`` [-] (:func:`~gimbal_friction.physics.direction.direction_factors`);
    ``tanh(v / v_th)`` [-] is the sign of motion without a discontinuity at zero speed."""
    magnitude_nm = magnitude_from_terms(terms, velocity_rad_s, xp)
    k_dir = select_direction(velocity_rad_s, k_positive, k_negative, xp)
    return xp.clip(xp.tanh(velocity_rad_s / v_th) * k_dir * magnitude_nm, -max_torque_nm, max_torque_nm)


def model_friction_nm(terms: TemperatureTerms[X], k_positive: X, k_negative: X, velocity_rad_s: X,
                      xp: Namespace[X]) -> X:
    """``k_dir · M``: the model friction along the motion [N·m] at velocity ``velocity_rad_s`` [rad/s] (arguments
    as :func:`feedforward_torque_nm`); what a learned correction is added to."""
    return select_direction(velocity_rad_s, k_positive, k_negative, xp) * magnitude_from_terms(terms, velocity_rad_s,
                                                                                               xp)


def corrected_torque_nm(model_nm: X, odd_nm: X, even_nm: X, velocity_rad_s: X, v_th: float, max_torque_nm: float,
                        xp: Namespace[X]) -> X:
    """``clamp(tanh(v/v_th) · (k_dir M + c_odd) + c_even, ±τ_max)`` [N·m]: the feedforward torque with a learned
    correction's part along the motion ``odd_nm`` [N·m] added to the model friction ``model_nm`` = k_dir M [N·m]
    (:func:`model_friction_nm`) and its part independent of the direction ``even_nm`` [N·m], at velocity
    ``velocity_rad_s`` [rad/s]."""
    return xp.clip(xp.tanh(velocity_rad_s / v_th) * (model_nm + odd_nm) + even_nm, -max_torque_nm, max_torque_nm)


def velocity_used(source: str, measured_rad_s: X, reference_rad_s: X, reference_fresh: BoolOrArray,
                  xp: Namespace[X]) -> X:
    """The velocity [rad/s] the torque uses under ``velocity_source`` = ``source`` (:data:`VELOCITY_SOURCES`).

    ``measured``: the joint state's velocity (relative to the base); ``reference``: the reference joint velocity
    while it is fresh, else 0 (no torque); ``auto``: the reference while it is fresh, else the measured one.

    >>> velocity_used('auto', 0.1, 0.2, True, SCALAR), velocity_used('auto', 0.1, 0.2, False, SCALAR)
    (0.2, 0.1)
    >>> velocity_used('reference', 0.1, 0.2, False, SCALAR)
    0.0
    """
    if source == 'measured':
        return measured_rad_s
    return xp.where(reference_fresh, reference_rad_s, measured_rad_s if source == 'auto' else 0.0)


def check_velocity_source(source: str) -> None:
    """Raise :class:`ConfigError` unless ``source`` is one of :data:`VELOCITY_SOURCES`."""
    if source not in VELOCITY_SOURCES:
        raise ConfigError('velocity_source', f'must be one of {", ".join(VELOCITY_SOURCES)}', source)


def temperature_used(last_c: X, fresh: BoolOrArray, settings: FeedforwardSettings, xp: Namespace[X]) -> tuple[X, X]:
    """The temperature [°C] to use and its source code (``SOURCE_*``), from the latest valid temperature
    ``last_c`` (NaN: none yet) and whether it is ``fresh``. The ``zero`` policy gives NaN (output 0 N·m)."""
    s = settings
    have = last_c == last_c  # not NaN
    stale_c: X | float
    stale_source: X | float
    if s.stale_policy == 'hold_last':
        stale_c = xp.where(have, last_c, s.fallback_temperature_c)
        stale_source = xp.where(have, SOURCE_HOLD_LAST, SOURCE_FALLBACK)
    elif s.stale_policy == 'zero':
        stale_c, stale_source = math.nan, SOURCE_ZERO
    else:
        stale_c, stale_source = s.fallback_temperature_c, SOURCE_FALLBACK
    return xp.where(fresh, last_c, stale_c), xp.where(fresh, SOURCE_MEASURED, stale_source)


# ---------------------------------------------------------------------------------------------------- the object
@dataclass
class FeedforwardCounters:
    """What happened to the inputs (for ``/diagnostics``)."""

    temperature_rejected: dict[str, int] = field(default_factory=dict)
    joint_state_rejected: dict[str, int] = field(default_factory=dict)
    reference_rejected: dict[str, int] = field(default_factory=dict)
    saturated: dict[str, int] = field(default_factory=dict)
    #: per joint, valid temperatures outside the joint's model range (:attr:`Feedforward.model_ranges`), used at
    #: its edge
    temperature_clamped: dict[str, int] = field(default_factory=dict)
    published: int = 0

    def add(self, bucket: dict[str, int], reason: str, n: int = 1) -> None:
        if n:
            bucket[reason] = bucket.get(reason, 0) + n


class MessageTorques(NamedTuple):
    """The feedforward of one joint-state message."""

    names: list[str]          #: configured joints present in the message, in configured order
    torques_nm: list[float]   #: signed feedforward torque of each [N·m]
    commands_nm: list[float]  #: torque of every configured joint in configured order (0 where absent) [N·m]
    temperature_c: float      #: temperature used [°C] (NaN: zero policy)
    source: int               #: SOURCE_* code


_new_tuple = tuple.__new__  # MessageTorques from a tuple of its fields, without the NamedTuple's keyword handling


class BagTorques(NamedTuple):
    """The feedforward of every joint-state message of a bag (what the node would have published)."""

    msg_index: NDArray[np.int64]      #: joint-state message of each output message
    joints: tuple[str, ...]           #: the configured joints (columns of ``present`` and ``commands_nm``)
    present: NDArray[np.bool_]        #: (messages, joints): the joint is in the output message
    stamp_ns: NDArray[np.int64]       #: header stamp, as received [ns]
    log_time_ns: NDArray[np.int64]    #: arrival (log) time of the joint state [ns]
    commands_nm: NDArray[np.float64]  #: (messages, joints) torques in configured order, 0 where absent [N·m]
    temperature_c: NDArray[np.float64]  #: temperature used per message [°C] (NaN: zero policy)
    source: NDArray[np.int8]          #: SOURCE_* per message

    def __len__(self) -> int:
        """Number of output messages [-]."""
        return int(self.msg_index.shape[0])

    def names(self, k: int) -> list[str]:
        """Joints of output message ``k`` (configured order)."""
        return [j for j, p in zip(self.joints, self.present[k].tolist(), strict=True) if p]

    def torques(self, k: int) -> list[float]:
        """Torques of output message ``k`` [N·m], as published (effort of the JointState)."""
        return self.commands_nm[k][self.present[k]].tolist()


class Feedforward:
    """Model-based friction feedforward of the configured joints (the object ``friction_feedforward`` runs).

    Parameters
    ----------
    axes : Mapping[str, AxisParams]
        Configured joints, in order, and their model parameters.
    settings : FeedforwardSettings
        Validated settings.
    correction : Correction, optional
        A learned correction added to the model friction (:meth:`set_correction`); None or an empty one: the
        pure model.

    Raises
    ------
    ConfigError
        Invalid settings.
    CorrectionError
        ``correction`` was learned against other joints or parameters.
    ModelDomainError
        Parameters for which the model cannot be tabulated over the temperature range (the whole model is built
        and checked here, so a broken model is refused before it is used).
    """

    def __init__(self, axes: dict[str, AxisParams], settings: FeedforwardSettings,
                 correction: Correction | None = None) -> None:
        settings.validate()
        if not axes:
            raise ConfigError('axes', 'must name at least one joint')
        self.settings = settings
        # (settings read per scalar call, as attributes: one lookup instead of two)
        self._v_th, self._max_torque_nm = settings.velocity_threshold_rad_s, settings.max_torque_nm
        self._timeout_s = settings.temperature_timeout_s
        self._velocity_source, self._reference_timeout_s = settings.velocity_source, settings.reference_timeout_s
        self.axes = dict(axes)
        self.order = tuple(self.axes)
        s = settings
        #: per joint, the model's validity range for its parameters (:func:`~gimbal_friction.physics.validity.
        #: validity_range`)
        self.validity: dict[str, ValidityRange] = {name: validity_range(p) for name, p in self.axes.items()}
        #: per joint, the temperatures its table spans [°C]: the credible range within the validity range; a valid
        #: temperature outside is used at the edge (the table clamps) and counted in ``temperature_clamped``
        self.model_ranges = {name: model_range(s, r, name) for name, r in self.validity.items()}
        self.tables = {name: FrictionTable(p, *self.model_ranges[name], s.table_step_c)
                       for name, p in self.axes.items()}
        self.counters = FeedforwardCounters()
        #: per (names, number of velocities) of a message: its index, (column, joint, entry) of each configured
        #: joint in it in configured order, and whether the index found anything to count (mismatch, unknown or
        #: repeated names)
        self._index_cache: dict[tuple[tuple[str, ...], int],
                                tuple[JointIndex, tuple[tuple[int, str, int], ...], bool]] = {}
        #: per joint, what the scalar call reads at the last temperature of a scalar call (:meth:`_terms_at`; the
        #: temperature changes at the sensor's rate, not the joints')
        self._scalar_terms: dict[str, _ScalarPlan] = {}
        #: latest reference joint velocity per joint: (velocity [rad/s], time [s])
        self._reference: dict[str, tuple[float, float]] = {}
        #: the reference position [rad] of the same message as ``_reference`` (NaN: none)
        self._reference_position: dict[str, float] = {}
        self._correction: Correction | None = None
        if correction is not None:
            self.set_correction(correction)
        #: the loop's judge of the correction (None: the correction wherever it is applied): :meth:`message` asks it
        #: per joint whether to use the correction or the plain model
        #: (:meth:`~gimbal_friction.feedforward.correction.judge.LoopJudge.use_candidate`)
        self.judge: LoopJudge | None = None
        #: :func:`temperature_used` of the latest valid temperature when stale and when fresh (index: fresh)
        self._used: tuple[tuple[float, int], tuple[float, int]] = ((math.nan, SOURCE_ZERO),) * 2
        self._used_c: tuple[float, float] = (math.nan, math.nan)
        self.last_temperature_c = math.nan   #: latest valid temperature [°C] (NaN: none)
        self.last_temperature_time_s = math.nan  #: its time [s]

    @property
    def last_temperature_c(self) -> float:
        """Latest valid temperature [°C] (NaN: none)."""
        return self._last_temperature_c

    @last_temperature_c.setter
    def last_temperature_c(self, value: float) -> None:
        self._last_temperature_c = value
        self._used = tuple((float(t), int(source)) for t, source in  # type: ignore[assignment]
                           (temperature_used(value, fresh, self.settings, SCALAR) for fresh in (False, True)))
        #: the temperatures of ``_used`` alone [°C] (the scalar call's index: fresh)
        self._used_c = (self._used[0][0], self._used[1][0])

    def take_state(self, old: Feedforward) -> None:
        """Continue from ``old`` after a parameter change: its counters and its latest valid temperature (if that
        is still inside this object's credible range)."""
        self.counters = old.counters
        self._reference = {j: r for j, r in old._reference.items() if j in self.axes}
        self._reference_position = {j: p for j, p in old._reference_position.items() if j in self.axes}
        s = self.settings
        if s.temperature_min_c <= old.last_temperature_c <= s.temperature_max_c:
            self.last_temperature_c, self.last_temperature_time_s = old.last_temperature_c, old.last_temperature_time_s

    # ------------------------------------------------------------------ learned correction
    @property
    def correction(self) -> Correction | None:
        """The learned correction added to the model friction (None: the pure model)."""
        return self._correction

    def model_identity(self) -> ModelIdentity:
        """The identity of this object's model (:func:`~gimbal_friction.feedforward.correction.model_identity`):
        what a correction must have been learned against."""
        return model_identity(self.axes)

    def set_correction(self, correction: Correction | None, expected: ModelIdentity | None = None) -> None:
        """Use ``correction`` from the next call on (None: back to the pure model). The object is used as it is,
        not copied: a :class:`~gimbal_friction.feedforward.correction.Learner` updating it in place is followed at
        once.

        Raises CorrectionError (one line) unless it was learned against ``expected`` (default: this object's model,
        :meth:`model_identity`; pass the identity of the whole configuration when this object runs a subset of its
        joints).
        """
        if correction is not None:
            correction.check_identity(self.model_identity() if expected is None else expected)
            unknown = [j for j in self.order if j not in correction.identity.joints]
            if unknown:
                raise CorrectionError(f'the correction has no joint {", ".join(unknown)}: relearn it for these joints')
        self._correction = correction

    # ------------------------------------------------------------------ temperature
    def update_temperature(self, temperature_c: float, time_s: float) -> str | None:
        """A bearing temperature [°C] of time ``time_s`` [s] (its stamp; the arrival time if the stamp is zero).
        Returns the rejection reason (counted) or None."""
        s = self.settings
        reason = temperature_rejection(temperature_c, s.temperature_min_c, s.temperature_max_c)
        if reason is not None:
            self.counters.add(self.counters.temperature_rejected, reason)
            return reason
        self.last_temperature_c = float(temperature_c)
        self.last_temperature_time_s = float(time_s)
        for joint, (low, high) in self.model_ranges.items():
            if not low <= temperature_c <= high:   # used at the edge of the joint's model range
                self.counters.add(self.counters.temperature_clamped, joint)
        return None

    # ------------------------------------------------------------------ reference velocity
    @property
    def references(self) -> dict[str, tuple[float, float]]:
        """The latest finite reference per configured joint: (velocity [rad/s], time [s]) (a copy)."""
        return dict(self._reference)

    def update_reference(self, names: list[str], velocities: list[float], time_s: float,
                         positions: list[float] | None = None) -> str | None:
        """A reference joint-velocity message (``/gimbal/reference_velocity``: ``names``, ``velocities`` [rad/s],
        optionally ``positions`` [rad], ignored unless as long as ``names``) of time ``time_s`` [s]. The first entry
        of each configured joint is kept if its velocity is finite (with its position: the reference position a
        learned correction's position map is looked up at). Returns the reason (counted) when the message is refused
        whole."""
        if len(velocities) != len(names):
            self.counters.add(self.counters.reference_rejected, J_MISMATCH)
            return J_MISMATCH
        have_positions = positions is not None and len(positions) == len(names)
        seen: set[str] = set()
        for k, (name, v) in enumerate(zip(names, velocities, strict=True)):
            if name in seen or name not in self.axes:
                continue
            seen.add(name)
            value = float(v)
            if math.isfinite(value):
                self._reference[name] = (value, float(time_s))
                self._reference_position[name] = float(positions[k]) if have_positions else math.nan  # type: ignore[index]
            else:
                self.counters.add(self.counters.reference_rejected, NON_FINITE_VELOCITY)
        return None

    def velocity(self, joint: str, measured_rad_s: float, time_s: float) -> float:
        """The velocity [rad/s] the torque of ``joint`` uses at time ``time_s`` [s] under ``velocity_source``
        (:func:`velocity_used`), from its measured velocity and the latest reference."""
        source = self._velocity_source
        if source == 'measured':
            return measured_rad_s
        reference = self._reference.get(joint)
        # (floats in, a float out: the measured or the reference velocity, or 0.0)
        used: float
        if reference is None:  # none yet: never fresh (is_fresh of a NaN time), without evaluating is_fresh
            used = velocity_used(source, measured_rad_s, math.nan, False, SCALAR)
        else:
            used = velocity_used(source, measured_rad_s, reference[0],
                                 is_fresh(time_s, reference[1], self._reference_timeout_s, SCALAR), SCALAR)
        return used

    def position(self, joint: str, measured_rad: float, time_s: float) -> float:
        """The position [rad] a learned correction of ``joint`` is looked up at, for a sample of time ``time_s``
        [s] whose measured position is ``measured_rad`` [rad]: the reference position when the velocity used is the
        reference's (:meth:`velocity`) and that reference carried a finite position, else the measured one."""
        if self._velocity_source == 'measured':
            return measured_rad
        _, t = self._reference.get(joint, _NO_REFERENCE)
        p = self._reference_position.get(joint, math.nan)
        if p == p and is_fresh(time_s, t, self._reference_timeout_s, SCALAR):
            return p
        return measured_rad

    def temperature(self, time_s: float) -> tuple[float, int]:
        """Temperature [°C] to use for a sample of time ``time_s`` [s] (NaN: zero policy) and its source code."""
        # temperature_used of the latest valid temperature, evaluated when it arrived (last_temperature_c)
        return self._used[is_fresh(time_s, self.last_temperature_time_s, self._timeout_s, SCALAR)]

    def temperature_age_s(self, time_s: float) -> float:
        """``time_s`` minus the time of the latest valid temperature [s] (NaN if none)."""
        return time_s - self.last_temperature_time_s

    # ------------------------------------------------------------------ one joint (a controller tick)
    def rule(self, joint: str, velocity_rad_s: X, temperature_c: X, xp: Namespace[X],
             terms: TemperatureTerms[X] | None = None, position_rad: X | float = math.nan) -> X:
        """The torque rule of ``joint`` [N·m] at velocities [rad/s], temperatures [°C] (finite) and positions [rad]
        (for the learned correction's position map; NaN: none), floats (``xp`` = SCALAR) or arrays (ARRAY);
        ``terms`` may carry the table's temperature terms already computed for these temperatures. No counting
        (but the correction's clipped lookups), no input checks: the callers below do those."""
        table = self.tables[joint]
        if terms is None:
            terms = table.temperature_terms(temperature_c, xp)
        k_positive, k_negative = direction_factors(self.axes[joint], temperature_c, xp)
        correction = self._correction
        # (the correction's lookup lists: None for a joint without a learned value, where the torque is the model's)
        if correction is None or correction.lookups.get(joint) is None:
            return feedforward_torque_nm(terms, k_positive, k_negative, velocity_rad_s, self._v_th,
                                         self._max_torque_nm, xp)
        model_nm = model_friction_nm(terms, k_positive, k_negative, velocity_rad_s, xp)
        # SCALAR's rule takes floats, ARRAY's arrays: xp is SCALAR exactly when X is float
        split: Callable[[str, X, X, X | float, X], tuple[X, X]] = (
            correction.split_nm if xp is SCALAR else correction.split_nm_array)  # type: ignore[assignment]  # see above
        odd_nm, even_nm = split(joint, temperature_c, velocity_rad_s, position_rad, model_nm)
        return corrected_torque_nm(model_nm, odd_nm, even_nm, velocity_rad_s, self._v_th, self._max_torque_nm, xp)

    def model_nm(self, joint: str, velocity_rad_s: X, temperature_c: X, xp: Namespace[X]) -> X:
        """``k_dir · M``: the model friction of ``joint`` along the motion [N·m] (>= 0) at velocities [rad/s] and
        temperatures [°C] (finite), as the torque rule evaluates it (the table); what a learned correction is added
        to and what residuals for learning one are taken against (model friction signed like the motion =
        ``sign(v)`` × this)."""
        terms = self.tables[joint].temperature_terms(temperature_c, xp)
        k_positive, k_negative = direction_factors(self.axes[joint], temperature_c, xp)
        return model_friction_nm(terms, k_positive, k_negative, velocity_rad_s, xp)

    def torque_at(self, joint: str, velocity_rad_s: float, temperature_c: float,
                  position_rad: float = math.nan) -> float:
        """Feedforward torque [N·m] of ``joint`` at ``velocity_rad_s`` [rad/s], ``temperature_c`` [°C] (NaN:
        zero policy, 0 N·m) and position ``position_rad`` [rad] (the learned correction's position map; NaN: none).
        Non-finite velocity gives 0 N·m. Counts saturation. (:meth:`torque_nm` with the temperature given.)"""
        return self.torque_nm(joint, velocity_rad_s, math.nan, position_rad, temperature_c)

    def _terms_at(self, joint: str, temperature_c: float, lut: Lookup | None) -> _ScalarPlan:
        """What the scalar call (:meth:`torque_nm`) reads of ``joint`` at ``temperature_c`` [°C] (finite) with the
        correction's lookup ``lut`` (None: the model), kept for the next scalar calls at the same temperature and
        lookup: (temperature [°C], the lookup, the table's contact torque [N·m], its viscous coefficient [N·m], ν ×
        rpm per rad/s, k_+ [-], k_- [-], the lookup's
        :meth:`~gimbal_friction.feedforward.correction.lookup.Lookup.scalar_terms` or None)."""
        terms = self.tables[joint].temperature_terms(temperature_c, SCALAR)
        k_positive, k_negative = direction_factors(self.axes[joint], temperature_c, SCALAR)
        plan: _ScalarPlan = (temperature_c, lut, terms.contact_nm, terms.viscous_nm, terms.nu_rpm_per_rad_s,
                             k_positive, k_negative, None if lut is None else lut.scalar_terms(temperature_c))
        self._scalar_terms[joint] = plan
        return plan

    def torque_nm(self, joint: str, velocity_rad_s: float, time_s: float, position_rad: float = math.nan,
                  temperature_c: float | None = None) -> float:
        """Feedforward torque [N·m] of ``joint`` for a velocity [rad/s] relative to the base at time ``time_s``
        [s], with the temperature rules (or at ``temperature_c`` [°C] when given, ``time_s`` then unused: NaN is
        the zero policy's 0 N·m); ``position_rad`` [rad] is where a learned correction's position map is looked up
        (pass the reference position with a reference velocity; NaN: no position map). Non-finite velocity gives
        0 N·m; saturation is counted. The in-process controller call.

        The scalar fast path: :meth:`temperature` and :meth:`rule` on floats (``xp`` = SCALAR) with their
        operations written out in one function, in the same order on the same values (the same torque to the last
        bit; test/feedforward/test_feedforward_fast_path.py compares them); what depends on temperature only (the
        table's terms, both direction factors, the correction's lists at that temperature,
        :meth:`Lookup.scalar_terms <gimbal_friction.feedforward.correction.lookup.Lookup.scalar_terms>`) is kept
        per joint between calls (:meth:`_terms_at`).

        Raises:
            KeyError: ``joint`` is not configured.
        """
        if temperature_c is None:   # (self.temperature(time_s)[0] with is_fresh written out)
            age_s = time_s - self.last_temperature_time_s
            temperature_c = self._used_c[(age_s if age_s >= 0.0 else -age_s) <= self._timeout_s]
        v = velocity_rad_s
        if v - v != 0.0 or temperature_c != temperature_c:  # v not finite, or NaN °C
            return 0.0
        correction = self._correction
        # (every configured joint is in the correction: set_correction checks; no learned value: the model, as rule)
        lut = None if correction is None else correction.lookups[joint]
        plan = self._scalar_terms.get(joint)
        if plan is None or plan[0] != temperature_c or plan[1] is not lut:
            plan = self._terms_at(joint, temperature_c, lut)
        _, _, contact_nm, viscous_nm, nu_rpm, k_positive, k_negative, cterms = plan
        # magnitude_from_terms (viscous_torque_from_coefficient: Palmgren's Eq. 9 above its threshold, else 160)
        a = v if v >= 0.0 else -v
        vn = nu_rpm * a
        if vn >= PALMGREN_THRESHOLD_CST_RPM:
            c = _cbrt(vn)
            magnitude_nm = contact_nm + viscous_nm * (c * c)
        else:
            magnitude_nm = contact_nm + viscous_nm * 160.0
        k_dir = k_positive if v >= 0.0 else k_negative   # select_direction
        if cterms is None:   # feedforward_torque_nm
            x = _tanh(v / self._v_th) * k_dir * magnitude_nm
        else:                # model_friction_nm, Lookup.split_nm, corrected_torque_nm
            model_nm = k_dir * magnitude_nm
            if model_nm - model_nm != 0.0:   # (an absurd speed's infinite model: no correction)
                odd = even = 0.0
            else:
                odd_l, even_l, hi, vmin, rel, floor_nm, independent_nm, position_terms = cterms
                if hi > 0:
                    y = _log2(a / vmin) - 0.5 if a > vmin else -1.0
                    if y <= 0.0:
                        odd, even = odd_l[0], even_l[0]
                    elif y >= hi:
                        odd, even = odd_l[hi], even_l[hi]
                    else:
                        k = int(y)
                        f = y - k
                        o0, e0 = odd_l[k], even_l[k]
                        odd = o0 + f * (odd_l[k + 1] - o0)
                        even = e0 + f * (even_l[k + 1] - e0)
                else:
                    odd, even = odd_l[0], even_l[0]
                m = model_nm if model_nm >= 0.0 else -model_nm
                if position_terms is not None and position_rad == position_rad:
                    rip, todd, teven, grid0, inv_step, last = position_terms
                    y = (position_rad - grid0) * inv_step
                    if y <= 0.0:
                        j, h = 0, 0.0
                    elif y >= last:
                        j, h = last - 1, 1.0
                    else:
                        j = int(y)
                        h = y - j
                    if rip is not None:
                        r0 = rip[j]
                        odd += (r0 + h * (rip[j + 1] - r0)) * m
                    if todd is not None and teven is not None:
                        a0 = todd[j]
                        odd += a0 + h * (todd[j + 1] - a0)
                        b0 = teven[j]
                        even += b0 + h * (teven[j + 1] - b0)
                if a < vmin:
                    odd *= a / vmin
                bound = rel * m + floor_nm
                if not (-bound <= odd <= bound):
                    lut.saturations += 1   # type: ignore[union-attr]  # (cterms is set with lut)
                    odd = bound if odd > 0.0 else -bound
                if bound < independent_nm:   # noqa: PLR1730  # max(bound, independent): the builtin costs ~0.1 µs
                    bound = independent_nm
                if not (-bound <= even <= bound):
                    lut.saturations += 1   # type: ignore[union-attr]
                    even = bound if even > 0.0 else -bound
            x = _tanh(v / self._v_th) * (model_nm + odd) + even
        max_nm = self._max_torque_nm
        if -max_nm < x < max_nm:
            return x
        torque = -max_nm if x < -max_nm else (max_nm if max_nm < x else x)   # noqa: FURB136  # clip (NaN stays NaN)
        if torque >= max_nm or torque <= -max_nm:   # (abs(torque) >= max_nm)
            self.counters.add(self.counters.saturated, joint)
        return torque

    def model_torque_nm(self, joint: str, velocity_rad_s: float, temperature_c: float) -> float:
        """The plain model's torque [N·m] of ``joint`` at ``velocity_rad_s`` [rad/s] (finite) and
        ``temperature_c`` [°C] (NaN: the zero policy's 0 N·m), whatever correction is set (:meth:`rule` without
        it); saturation is counted."""
        if temperature_c != temperature_c:
            return 0.0
        terms = self.tables[joint].temperature_terms(temperature_c, SCALAR)
        k_positive, k_negative = direction_factors(self.axes[joint], temperature_c, SCALAR)
        x: float = feedforward_torque_nm(terms, k_positive, k_negative, velocity_rad_s, self._v_th,
                                         self._max_torque_nm, SCALAR)
        if x >= self._max_torque_nm or x <= -self._max_torque_nm:
            self.counters.add(self.counters.saturated, joint)
        return x

    # ------------------------------------------------------------------ one message (the node)
    def message(self, names: Sequence[str], velocities: Sequence[float], time_s: float,
                positions: Sequence[float] | None = None) -> MessageTorques | None:
        """The feedforward of one joint-state message (``names``, ``velocities`` [rad/s], optionally
        ``positions`` [rad], used by a learned correction and ignored unless as long as ``names``; see
        :meth:`position`) of time ``time_s`` [s] (stamp, or arrival if the stamp is zero). None (reason counted)
        when the message is unusable. The sequences may be lists or ``array.array`` (a ROS message's fields as
        they are)."""
        key = (tuple(names), len(velocities))
        plan = self._index_cache.get(key)
        if plan is None:  # the same names in every message: index them once
            idx = index_joints(names, (len(velocities),), self.order)
            plan = (idx, tuple((j, joint, idx.position[joint]) for j, joint in enumerate(self.order)
                               if joint in idx.position), idx.mismatch or idx.unknown > 0 or idx.duplicate > 0)
            if len(self._index_cache) < 64:
                self._index_cache[key] = plan
        idx, present, odd = plan
        c = self.counters
        bucket = c.joint_state_rejected
        if odd:
            if idx.mismatch:
                c.add(bucket, J_MISMATCH)
                return None
            c.add(bucket, J_UNKNOWN, idx.unknown)
            c.add(bucket, J_DUPLICATE, idx.duplicate)
        # (self.temperature(time_s) with is_fresh written out, two calls less)
        age_s = time_s - self.last_temperature_time_s
        temperature, source = self._used[(age_s if age_s >= 0.0 else -age_s) <= self._timeout_s]
        measured = self._velocity_source == 'measured'
        torque_nm = self.torque_nm   # (torque_at without its call)
        # the correction's lookup lists per joint (None: no learned value, the model's torque and no position)
        luts = None if self._correction is None else self._correction.lookups
        judge = self.judge
        if luts is not None and (positions is None or len(positions) != len(names)):
            positions = None
        out_names: list[str] = []
        torques: list[float] = []
        commands = [0.0] * len(self.order)
        for j, joint, i in present:  # configured joints in the message, in configured order
            v = float(velocities[i])
            if not measured:
                v = self.velocity(joint, v, time_s)
            if v - v != 0.0:  # not finite (inf - inf and NaN - NaN are NaN)
                c.add(bucket, NON_FINITE_VELOCITY)
                continue
            if luts is not None and luts[joint] is not None and judge is not None and not judge.use_candidate(
                    joint, temperature, v, time_s):
                torque = self.model_torque_nm(joint, v, temperature)   # the loop's judge: the model here, now
            elif luts is not None and luts[joint] is not None:
                p = math.nan if positions is None else float(positions[i])
                torque = torque_nm(joint, v, time_s, p if measured else self.position(joint, p, time_s), temperature)
            else:
                torque = torque_nm(joint, v, time_s, math.nan, temperature)
            out_names.append(joint)
            torques.append(torque)
            commands[j] = torque
        if not out_names:
            c.add(bucket, J_NONE)
            return None
        c.published += 1
        # (tuple.__new__: the NamedTuple's own __new__ costs ~0.1 µs more, per message)
        return _new_tuple(MessageTorques, (out_names, torques, commands, temperature, source))

    # ------------------------------------------------------------------ a whole bag (the offline replay)
    def bag_torques(self, arrays: ChamberArrays) -> BagTorques:
        """What the node would publish for every joint-state message of ``arrays`` (messages in log-time order;
        a temperature logged at the same time as a joint state arrived before it). The same rules as
        :meth:`message` (with the joint states' and the references' positions), evaluated on arrays; counters are
        updated the same way (a NaN position and velocity means the joint is absent from that message)."""
        s = self.settings
        c = self.counters
        temp, js = arrays.temperature, arrays.joint_states
        valid, rejected = temperature_valid(temp.temperature_c, s.temperature_min_c, s.temperature_max_c)
        for reason, n in rejected.items():
            c.add(c.temperature_rejected, reason, n)
        t_log = np.asarray(temp.log_time_ns, dtype=np.int64)[valid]
        t_val = np.asarray(temp.temperature_c, dtype=np.float64)[valid]
        for joint, (low, high) in self.model_ranges.items():
            c.add(c.temperature_clamped, joint, int(np.count_nonzero((t_val < low) | (t_val > high))))
        t_time = effective_time(np.asarray(temp.stamp_ns, dtype=np.int64)[valid], t_log) / NS_PER_S
        js_log = np.asarray(js.log_time_ns, dtype=np.int64)
        js_stamp = np.asarray(js.stamp_ns, dtype=np.int64)
        js_time = effective_time(js_stamp, js_log) / NS_PER_S
        last_c, last_time = latest_before(t_log, js_log, (t_val, t_time), inclusive=True)
        fresh = is_fresh(js_time, last_time, s.temperature_timeout_s, ARRAY)
        used_c, used_source = temperature_used(last_c, fresh, s, ARRAY)
        t_used = np.broadcast_to(np.asarray(used_c, dtype=np.float64), js_log.shape)
        source = np.broadcast_to(np.asarray(used_source, dtype=np.int8), js_log.shape)

        ref = arrays.reference_velocity
        if ref is not None:  # as update_reference: a configured joint's non-finite reference is counted
            for joint in self.order:
                if joint in ref.velocity:
                    rv = np.asarray(ref.velocity[joint], dtype=np.float64)
                    rp = np.asarray(ref.position.get(joint, np.full(rv.shape, np.nan)), dtype=np.float64)
                    c.add(c.reference_rejected, NON_FINITE_VELOCITY,
                          int(np.count_nonzero(~np.isfinite(rv) & ~(np.isnan(rv) & np.isnan(rp)))))
        n_msg = js_log.shape[0]
        commands = np.zeros((n_msg, len(self.order)))
        present = np.zeros((n_msg, len(self.order)), dtype=bool)
        unknown = np.zeros(n_msg, dtype=np.int64)
        for name in js.names:
            if name not in self.axes:
                unknown += ~(np.isnan(js.position[name]) & np.isnan(js.velocity[name]))
        c.add(c.joint_state_rejected, J_UNKNOWN, int(unknown.sum()))
        for j, joint in enumerate(self.order):
            if joint not in js.velocity:
                continue
            v = np.asarray(js.velocity[joint], dtype=np.float64)
            p = np.asarray(js.position[joint], dtype=np.float64)
            in_message = ~(np.isnan(p) & np.isnan(v))
            if s.velocity_source != 'measured':
                v, p = self._bag_velocity(joint, v, p, arrays.reference_velocity, js_log, js_time)
            finite = np.isfinite(v)
            c.add(c.joint_state_rejected, NON_FINITE_VELOCITY, int(np.count_nonzero(~finite & in_message)))
            rows = np.flatnonzero(finite & in_message)
            tt = t_used[rows]
            live = np.flatnonzero(~np.isnan(tt))   # the others: zero policy, 0 N*m
            torque = np.zeros(rows.shape)
            with np.errstate(over='ignore', invalid='ignore'):  # absurd speeds saturate, as on floats
                torque[live] = self.rule(joint, v[rows[live]], tt[live], ARRAY, position_rad=p[rows[live]])
            c.add(c.saturated, joint, int(np.count_nonzero(np.abs(torque) >= s.max_torque_nm)))
            commands[rows, j] = torque
            present[rows, j] = True
        out = np.flatnonzero(present.any(axis=1))
        c.add(c.joint_state_rejected, J_NONE, int(n_msg - out.size))
        c.published += int(out.size)
        return BagTorques(out.astype(np.int64), self.order, present[out], js_stamp[out], js_log[out], commands[out],
                          t_used[out], source[out])

    def _bag_velocity(self, joint: str, measured: NDArray[np.float64], measured_position: NDArray[np.float64],
                      reference: JointStateArrays | None, js_log: NDArray[np.int64], js_time: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`velocity` and :meth:`position` for every joint state of a bag: the latest finite reference of
        ``joint`` logged up to each joint state (one logged at the same time arrived before it), fresh within
        ``reference_timeout_s``, and its position where finite."""
        s = self.settings
        ref_v = np.full(measured.shape, np.nan)
        ref_p = np.full(measured.shape, np.nan)
        ref_time = np.full(measured.shape, np.nan)
        if reference is not None and joint in reference.velocity and len(reference):
            values = np.asarray(reference.velocity[joint], dtype=np.float64)
            usable = np.isfinite(values)
            r_log = np.asarray(reference.log_time_ns, dtype=np.int64)[usable]
            r_time = effective_time(np.asarray(reference.stamp_ns, dtype=np.int64)[usable], r_log) / NS_PER_S
            r_pos = np.asarray(reference.position.get(joint, np.full(values.shape, np.nan)), dtype=np.float64)[usable]
            if r_log.size:
                ref_v, ref_p, ref_time = latest_before(r_log, js_log, (values[usable], r_pos, r_time), inclusive=True)
        fresh = is_fresh(js_time, ref_time, s.reference_timeout_s, ARRAY)
        velocity = np.asarray(velocity_used(s.velocity_source, measured, ref_v, fresh, ARRAY), dtype=np.float64)
        position = np.where(fresh & ~np.isnan(ref_p), ref_p, measured_position)
        return velocity, np.asarray(position, dtype=np.float64)
