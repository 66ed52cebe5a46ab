"""``friction_feedforward``: model-predicted friction torque of every configured joint as a feedforward term.

A lifecycle node (``/<node>/change_state``, ``get_state``; docs/ros.md, Lifecycle): ``autostart`` (default true)
configures and activates it at start-up; ``autostart:=false`` waits for a lifecycle manager.

One job in one module: the ROS wrapper of :class:`~gimbal_friction.feedforward.rule.Feedforward` (its
subscriptions, parameters, learning service and diagnostics share the node's state).

Subscribes ``/gimbal/temperature`` (sensor_msgs/Temperature, °C) and ``/joint_states`` (sensor_msgs/JointState);
and ``/gimbal/reference_velocity`` (JointState, velocity = reference joint rate [rad/s]), used by ``velocity_source``
``auto`` (the default: while fresh) and ``reference``. Each input hears reliable and best-effort publishers (the
temperature is best-effort; the others follow their publishers' reliability), every publisher and subscription
takes ``qos_overrides.*`` parameters, and an input that delivers nothing is named on ``/diagnostics``
(:mod:`gimbal_friction.nodes._qos`).
Publishes, for each joint-state message (optionally rate-limited by ``max_rate_hz``):

- ``/gimbal/friction/feedforward`` (JointState): effort = torque [N·m] the motor must add, sign of motion, for the
  configured joints present in the message (configured order), stamped with the joint-state stamp that produced it;
- ``/gimbal/friction/feedforward_commands`` (Float64MultiArray): the torques of every configured joint in
  configured order (0 for a joint absent from the message);
- ``/diagnostics`` (every ``diagnostics_period_s``): per joint, temperature source and age, saturation, rejected
  inputs; and ``gimbal_friction/feedforward/learning``: learning off / active / frozen / saturated, samples used and
  refused by reason, the correction file and its last save (time or error);
- ``/gimbal/friction/correction`` (diagnostic_msgs/DiagnosticArray, every ``correction_publish_period_s``): the
  learned correction, one status per joint and one per (joint, direction, temperature bin) with data.

Learning in service (:class:`~gimbal_friction.feedforward.correction.keeper.CorrectionKeeper`, the library's: the
node only feeds it): the learned correction (:class:`gimbal_friction.feedforward.correction.Correction`, loaded
from ``correction_file``) is added to the model.
With ``learning_enabled`` it is learned from ``/gimbal/friction/measured_detail`` (the samples the estimator
accepted), in that callback, never in the joint-state path: residual = measured friction − the model along the
motion (the feedforward's own table and direction factors at the sample's speed and the node's temperature, which
must be fresh at the sample's stamp). The :class:`~gimbal_friction.feedforward.correction.Learner` gates, scores
each sample before it learns it (the guard: a cell or term that does not cut the residual out of sample holds back
to the model), bounds and rate-limits it; the file is saved atomically every ``learning_save_period_s`` and at
shutdown.

The logic is :class:`gimbal_friction.feedforward.rule.Feedforward`, the very object a controller can use in its own
process and the offline replay runs over a whole bag; the node only converts messages. Times are message stamps
(the receive time where a stamp is zero), the rule of :mod:`gimbal_friction.streams.inputs`.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64MultiArray

from gimbal_friction.common.errors import ConfigError, ModelDomainError
from gimbal_friction.common.settings import settings_from
from gimbal_friction.common.xp import SCALAR
from gimbal_friction.config.node_settings import (
    CORRECTION_LAYOUT,
    FEEDFORWARD_PREFIXED,
    RETIRED_DEFAULTS,
    RETIRED_PARAMETERS,
    FeedforwardNodeSettings,
)
from gimbal_friction.feedforward.correction import (
    CorrectionKeeper,
    CorrectionSettings,
    JudgeSettings,
    LearningSettings,
    model_identity,
)
from gimbal_friction.feedforward.correction.judge import LoopJudge
from gimbal_friction.feedforward.report import FeedforwardReport
from gimbal_friction.feedforward.rule import (
    SOURCE_MEASURED,
    Feedforward,
    FeedforwardSettings,
    model_friction_nm,
)
from gimbal_friction.nodes._common import (
    OK,
    WARN,
    InputCounter,
    ModelParameters,
    callback_error_values,
    declare_settings,
    diagnostic_array,
    field_names,
    parameter_guard,
    retime,
    run_node,
    settings_defaults,
    split_parameters,
    stamp_to_s,
    startup_model_error,
    status,
    to_msg,
)
from gimbal_friction.nodes._lifecycle import ManagedNode
from gimbal_friction.nodes._qos import Inputs, create_publisher
from gimbal_friction.physics.direction import direction_factors
from gimbal_friction.recording import topics
from gimbal_friction.recording.output_messages import OutputBytes as OutputBytes  # noqa: PLC0414 - re-exported
from gimbal_friction.streams.delivery import lost_key, received_key
from gimbal_friction.streams.input_health import SILENCE_TIMEOUT_S
from gimbal_friction.streams.inputs import effective_time
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, METHOD_NAMES

REFERENCE_VELOCITY = topics.REFERENCE_VELOCITY
#: the seeker's loop error (sensor_msgs/JointState per joint: position = LOS angle error [rad], velocity = LOS rate
#: error [rad/s]): the optional input of the loop's judge of the learned correction
LOOP_ERROR = '/gimbal/loop_error'
#: what /diagnostics and /gimbal/friction/correction say while the loop does not judge the correction
NOT_JUDGED = 'not judged by the loop'
#: the learned correction (diagnostic_msgs/DiagnosticArray): one status per joint and per cell with data
CORRECTION = topics.CORRECTION
#: period of the timer that takes a refit finished by the learning's worker in (it never waits for one) [s]
FIT_POLL_PERIOD_S = 0.02
#: subscription depth of the joint states: a burst of this many messages is buffered, not dropped
JOINT_STATE_DEPTH = 1000
NodeSettings = FeedforwardNodeSettings  # the node-level parameters (gimbal_friction.common.settings)

_FF_FIELDS = field_names(FeedforwardSettings)
_NODE_FIELDS = field_names(NodeSettings)
_CORRECTION_PREFIX, _LEARNING_PREFIX, _JUDGE_PREFIX = (prefix for prefix, _ in FEEDFORWARD_PREFIXED)
#: what /gimbal/friction/correction says of each cell with data (besides std_error_nm)
_CELL_KEYS = ('value_nm', 'samples', 'mean_nm', 'centre_c', 'state', 'held_back', 'scored', 'rms_model_nm',
              'rms_with_nm')
_CORRECTION_FIELDS = frozenset(_CORRECTION_PREFIX + n for n in field_names(CorrectionSettings))
_LEARNING_FIELDS = frozenset(_LEARNING_PREFIX + n for n in field_names(LearningSettings))
#: columns of measured_detail the learning reads (the layout of gimbal_friction.streams.measurement; read by index:
#: from_detail's arrays cost ~100 us a message, this ~1 us)
_STAMP_SEC, _STAMP_NANOSEC, _POSITION, _VELOCITY, _FRESH, _FRICTION, _METHOD = (
    MEASUREMENT_FIELDS.index(f) for f in ('stamp_sec', 'stamp_nanosec', 'position_rad', 'velocity_rad_s',
                                          'temperature_fresh', 'friction_nm', 'method'))


#: what /gimbal/friction/correction says, in place of a number, of a figure nothing has scored yet (never NaN)
NOT_SCORED = 'not scored'


def cell_values(rec: dict[str, Any]) -> dict[str, Any]:
    """The values of one cell's status on ``/gimbal/friction/correction`` from its record
    (:meth:`~gimbal_friction.feedforward.correction.learner.Learner.cells`): only finite numbers are published; a
    figure that is not a finite number (``rms_model_nm``, ``rms_with_nm`` of a cell no sample has scored yet, a
    ``z_<term>``) says :data:`NOT_SCORED`, a ``std_error_nm`` of a single sample ``none``."""
    def finite(x: Any) -> Any:
        return NOT_SCORED if isinstance(x, float) and not math.isfinite(x) else x
    values = {key: finite(rec[key]) for key in _CELL_KEYS}
    values['held_back'] = rec['held_back'] or 'no'
    values['terms'] = ','.join(rec['terms']) or 'none'
    se = rec['std_error_nm']
    values['std_error_nm'] = se if se is not None and math.isfinite(se) else 'none'
    values['speed_profile_nm'] = ' '.join(f'{x:.4g}' if math.isfinite(x) else NOT_SCORED for x in rec['speed_nm'])
    values |= {f'z_{t}': finite(z) for t, z in rec['z'].items()}
    return values


def judge_values(rec: dict[str, Any] | None, judging: bool) -> dict[str, Any]:
    """The loop judge's figures of one cell on ``/gimbal/friction/correction`` (its record of
    :meth:`~gimbal_friction.feedforward.correction.judge.LoopJudge.cells`, None: not tested yet): ``loop_state``
    and, once tested, the blocks on and off, the ratio of the loop's mean square error on/off and its z (finite
    numbers only)."""
    if not judging:
        return {'loop_state': NOT_JUDGED}
    if rec is None:
        return {'loop_state': 'untested'}
    out: dict[str, Any] = {'loop_state': rec['state'], 'loop_reason': rec['reason'] or 'none',
                           'loop_blocks_on': rec['blocks_on'], 'loop_blocks_off': rec['blocks_off']}
    for key in ('ratio', 'z'):
        x = rec[key]
        out[f'loop_{key}'] = x if math.isfinite(x) else NOT_SCORED
    return out


def prefixed_settings(cls: type[Any], prefix: str, values: dict[str, Any], base: Any = None) -> Any:
    """Settings of ``cls`` from parameters named ``prefix + field``; a ConfigError names the parameter."""
    try:
        return settings_from(cls, {k[len(prefix):]: v for k, v in values.items()}, base)
    except ConfigError as err:
        raise ConfigError(prefix + err.parameter, err.rule, err.value) from None


def model_along_nm(ff: Feedforward, joint: str, velocity_rad_s: float, temperature_c: float) -> float:
    """The model friction of ``joint`` signed like the motion, sign(v) k_dir(T) M(T, |v|) [N·m], at
    ``velocity_rad_s`` [rad/s] and ``temperature_c`` [°C]: the feedforward's own table, direction factors and
    :func:`~gimbal_friction.feedforward.rule.model_friction_nm` (what the learned correction is added to), without
    the smooth sign and the clamp."""
    terms = ff.tables[joint].temperature_terms(temperature_c, SCALAR)
    along: float = model_friction_nm(terms, *direction_factors(ff.axes[joint], temperature_c, SCALAR),
                                     velocity_rad_s, SCALAR)
    return along if velocity_rad_s >= 0.0 else -along


class FrictionFeedforward(ManagedNode):
    """The feedforward node (thin adapter around :class:`Feedforward`), a lifecycle node
    (:mod:`gimbal_friction.nodes._lifecycle`): with ``autostart`` (the default) configured and active once built."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('friction_feedforward', **kwargs)

    def parameter_steps(self) -> list[Callable[[], object]]:
        """The model, every settings group and the retired names (declared at construction and by configure)."""
        return [lambda: ModelParameters(self), lambda: declare_settings(self, FeedforwardSettings),
                lambda: declare_settings(self, NodeSettings),
                lambda: declare_settings(self, CorrectionSettings, _CORRECTION_PREFIX),
                lambda: declare_settings(self, LearningSettings, _LEARNING_PREFIX),
                lambda: declare_settings(self, JudgeSettings, _JUDGE_PREFIX), self._declare_retired]

    def _declare_retired(self) -> None:
        """The retired parameters: an old parameter file still loads; its value does nothing (a warning)."""
        for name, why in RETIRED_PARAMETERS.items():
            if self.has_parameter(name):   # (declared at construction or by an earlier configure)
                continue
            value: Any = self.declare_parameter(name, RETIRED_DEFAULTS[name], ParameterDescriptor(
                name=name, description=f'retired, no effect: {why}', read_only=True, dynamic_typing=True)).value
            if value != RETIRED_DEFAULTS[name]:
                self.get_logger().warning(f'parameter {name} = {value!r} is retired and has no effect: {why}')

    def configure_node(self) -> None:
        """The lifecycle's configure: parameters read and validated, the correction file loaded, the feedforward,
        subscriptions, publishers and timers made (a ConfigError or ModelDomainError refuses)."""
        self.model = ModelParameters(self)
        ff_settings = declare_settings(self, FeedforwardSettings)
        self.settings = declare_settings(self, NodeSettings)
        correction_settings = declare_settings(self, CorrectionSettings, _CORRECTION_PREFIX)
        learning_settings = declare_settings(self, LearningSettings, _LEARNING_PREFIX)
        judge_settings = declare_settings(self, JudgeSettings, _JUDGE_PREFIX)
        self._declare_retired()
        axes = self.model.current()
        self.ff = self._build(axes, ff_settings, startup=True)
        # (refits, the reports and saves of the correction run in the learning_fit_worker, off this executor)
        self.keeper = CorrectionKeeper(model_identity(axes), correction_settings, learning_settings, background=True)
        self.keeper.start(self.settings.correction_file)
        self.keeper.learner.freeze(self.settings.learning_frozen)
        if self.settings.learning_enabled:   # (the worker imports its modules while the node starts)
            self.keeper.learner.start()
        self._refused: dict[str, int] = {}  #: measured_detail messages not usable, per reason
        self._logged_save_error: str | None = None
        self._logged_fit_error: str | None = None
        #: the loop's judge of the correction (in use while _judging: learning_judge on, or auto with a publisher of
        #: /gimbal/loop_error)
        self.judge = LoopJudge(correction_settings, tuple(axes), judge_settings)
        self._judging = False
        self._loop_error_samples = 0
        self._use_correction()
        self._candidate: tuple[Feedforward | None, NodeSettings, dict[str, Any]] | None = None
        self._last_publish = -math.inf
        self._last_time_s = math.nan
        self._last_source = SOURCE_MEASURED
        self._rate_limited = 0
        self._last_warn: dict[str, float] = {}
        self.inputs = InputCounter()
        self.report = FeedforwardReport()   #: the /diagnostics statuses, report after report
        self._outputs = OutputBytes(len(self.ff.order))
        qos = QoSProfile(depth=100)
        # the outputs keep as many as a joint-state burst (a loaded subscriber catching up loses none)
        self.pub_ff = create_publisher(self, JointState, topics.FEEDFORWARD, JOINT_STATE_DEPTH)
        self.pub_cmd = create_publisher(self, Float64MultiArray, topics.FEEDFORWARD_COMMANDS, JOINT_STATE_DEPTH)
        self.pub_diag = create_publisher(self, DiagnosticArray, topics.DIAGNOSTICS, 10, managed=False)
        # every input hears reliable and best-effort publishers (nodes/_qos.py), the temperature too
        self.input_topics = ins = Inputs(self, self.inputs)
        ins.add(Temperature, topics.TEMPERATURE, self.on_temperature, 100, required=True,
                timeout_s=max(SILENCE_TIMEOUT_S, ff_settings.temperature_timeout_s))
        ins.add(JointState, topics.JOINT_STATES, self.on_joint_state, JOINT_STATE_DEPTH, required=True)
        ins.add(JointState, REFERENCE_VELOCITY, self.on_reference, qos)
        ins.add(JointState, LOOP_ERROR, self.on_loop_error, JOINT_STATE_DEPTH)
        self.pub_correction = create_publisher(self, DiagnosticArray, CORRECTION, 10)
        ins.add(Float64MultiArray, topics.MEASURED_DETAIL, self.on_measured_detail, JOINT_STATE_DEPTH)
        self._diag_timer = self.create_timer(self.settings.diagnostics_period_s, self.publish_diagnostics)
        self._save_timer = self.create_timer(self.settings.learning_save_period_s, self.save_correction)
        self._correction_timer = self.create_timer(self.settings.correction_publish_period_s,
                                                   self.publish_correction)
        self._step_timer = self.create_timer(learning_settings.step_period_s, self.step_learning)
        self._fit_timer = self.create_timer(FIT_POLL_PERIOD_S, self.poll_learning)
        self._reset_timer: Any = None
        parameter_guard(self, self._validate_params, self._apply_params)
        if self.settings.learning_reset:
            self.reset_learning()
        self.get_logger().info(f'friction_feedforward: joints {", ".join(self.model.axes)}, model table '
                               f'{ff_settings.temperature_min_c:g}..{ff_settings.temperature_max_c:g} degC')
        k = self.keeper
        if k.load_error is not None:
            self.get_logger().error(f'{k.load_error} (running on the pure model)')
        elif k.loaded_from is not None:
            summary = k.correction.summary()
            self.get_logger().info(f'correction loaded from {k.loaded_from}: {summary["cells_with_data"]} cells, '
                                   f'{summary["samples"]} samples')
        if k.load_note is not None:
            self.get_logger().warning(f'correction file {k.loaded_from}: {k.load_note}')
        if k.removed_temporaries:
            self.get_logger().info(f'removed {len(k.removed_temporaries)} stale temporary file(s) of an interrupted '
                                   f'save: {", ".join(k.removed_temporaries)}')
        if self.settings.learning_enabled:   # (YAML imported now, not by the first save)
            import yaml  # noqa: F401
        if self.settings.learning_enabled and not self._save_path():
            self.get_logger().warning('learning_enabled without correction_file or learning_output_file: what is '
                                      'learned is lost at shutdown')

    # ------------------------------------------------------------------ parameters
    def _build(self, axes: dict[str, Any], settings: FeedforwardSettings, startup: bool = False) -> Feedforward:
        """The whole feedforward (model tables included); a model that does not build is refused with the
        parameters to look at."""
        try:
            with np.errstate(all='ignore'):
                return Feedforward(axes, settings)
        except ModelDomainError as err:
            if not startup:
                raise
            defaults = {**self.model.defaults, **settings_defaults(FeedforwardSettings)}
            raise startup_model_error(self, err, defaults) from None

    def _validate_params(self, params: list[Parameter[Any]]) -> None:
        """Build the whole new feedforward (model tables included) from the proposed values, and the correction
        settings or file; kept for apply."""
        model, ff, node, corr, learn = split_parameters(params, _FF_FIELDS, _NODE_FIELDS, _CORRECTION_FIELDS,
                                                        _LEARNING_FIELDS)
        axes = self.model.current(model)
        ff_settings = settings_from(FeedforwardSettings, ff, self.ff.settings)
        node_settings = settings_from(NodeSettings, node, self.settings)
        k = self.keeper
        extra: dict[str, Any] = {}
        if corr:
            cs = prefixed_settings(CorrectionSettings, _CORRECTION_PREFIX, corr, k.settings)
            for name in CORRECTION_LAYOUT:
                if getattr(cs, name) != getattr(k.settings, name):
                    raise ConfigError(_CORRECTION_PREFIX + name, 'lays out the learned cells and cannot change while '
                                      'the node runs: restart with it (and an empty or matching correction file)',
                                      getattr(cs, name))
            extra['correction'] = cs
        if learn:
            extra['learning'] = prefixed_settings(LearningSettings, _LEARNING_PREFIX, learn, k.learner.settings)
            if extra['learning'].fit_worker != k.learner.settings.fit_worker:
                raise ConfigError(_LEARNING_PREFIX + 'fit_worker', 'cannot change while the node runs: restart with '
                                  'it', extra['learning'].fit_worker)
        path = node_settings.correction_file
        if path != self.settings.correction_file and path and Path(path).exists():
            probe = CorrectionKeeper(model_identity(axes), extra.get('correction', k.settings), k.learner.settings)
            extra['file'] = probe.read(path)   # CorrectionError refuses the change with its one line
        candidate = self._build(axes, ff_settings) if (model or ff) else None
        if model:
            extra['identity'] = model_identity(axes)
        self._candidate = (candidate, node_settings, extra)

    def _apply_params(self, params: list[Parameter[Any]]) -> None:
        if self._candidate is None:
            return
        candidate, node_settings, extra = self._candidate
        self._candidate = None
        log = self.get_logger()
        if candidate is not None:
            candidate.take_state(self.ff)
            self.ff = candidate
            log.info('feedforward rebuilt with the new parameters')
        k = self.keeper
        if 'identity' in extra and k.set_identity(extra['identity']):
            log.warning('model parameters changed: the learned correction belonged to the old model; it starts '
                        'empty (the file is rewritten at the next save)')
        if 'correction' in extra:
            k.set_settings(extra['correction'])
        if 'learning' in extra:
            old_step = k.learner.settings.step_period_s
            k.learner.settings = extra['learning']
            self._step_timer = retime(self, self._step_timer, old_step, extra['learning'].step_period_s,
                                      self.step_learning)
        if 'file' in extra:
            k.replace(extra['file'])
            k.loaded_from = node_settings.correction_file
            log.info(f'correction loaded from {node_settings.correction_file}')
        old = self.settings
        self.settings = node_settings
        k.learner.freeze(node_settings.learning_frozen)
        if node_settings.learning_reset and not old.learning_reset:
            self.reset_learning()
        self._use_correction()
        self._diag_timer = retime(self, self._diag_timer, old.diagnostics_period_s,
                                  node_settings.diagnostics_period_s, self.publish_diagnostics)
        self._save_timer = retime(self, self._save_timer, old.learning_save_period_s,
                                  node_settings.learning_save_period_s, self.save_correction)
        self._correction_timer = retime(self, self._correction_timer, old.correction_publish_period_s,
                                        node_settings.correction_publish_period_s, self.publish_correction)

    # ------------------------------------------------------------------ learning
    def _use_correction(self) -> None:
        """Give the feedforward the learned correction (use_correction) or none (the pure model), and the loop's
        judge while it judges."""
        use = self.settings.use_correction
        self.ff.set_correction(self.keeper.correction if use else None)
        self._positions = use
        self.update_judge()

    def update_judge(self) -> None:
        """Whether the loop judges the correction (``learning_judge``: on; auto: while /gimbal/loop_error has a
        publisher; off), and the judge told the correction's candidates (a cell whose candidate changed is tested
        again). Judging: the feedforward asks the judge per joint and call; otherwise the residual guard alone."""
        mode = self.keeper.learner.settings.judge
        judging = mode == 'on' or (mode == 'auto' and self.count_publishers(LOOP_ERROR) > 0)
        correction = self.ff.correction
        if judging and correction is not None:
            self.judge.update_candidates(correction)
        self._judging = judging
        self.ff.judge = self.judge if judging else None

    def on_loop_error(self, msg: JointState) -> None:
        """The seeker's loop error: each joint's LOS rate error (velocity [rad/s]) to the judge, in the cell the
        feedforward last computed that joint in (ignored while the loop does not judge)."""
        if not self._judging:
            return
        time_s = effective_time(stamp_to_s(msg.header.stamp), self._now_s())
        joints = self.judge.joints
        for name, rate_error in zip(msg.name, msg.velocity, strict=False):
            if name in joints:
                self._loop_error_samples += self.judge.observe_latest(name, time_s, float(rate_error))

    def _save_path(self) -> str:
        return self.settings.correction_file or self.settings.learning_output_file

    def reset_learning(self) -> None:
        """``learning_reset``: an empty correction at once (saved at the next save), then the parameter is set
        back to false."""
        self.keeper.learner.reset()
        self.keeper.dirty = True
        self.judge.reset()
        self.get_logger().info('learned correction reset: the feedforward is the pure model')

        def set_back() -> None:
            if self._reset_timer is not None:
                self._reset_timer.cancel()
                self.destroy_timer(self._reset_timer)
                self._reset_timer = None
            self.set_parameters([Parameter('learning_reset', value=False)])

        if self._reset_timer is None:
            self._reset_timer = self.create_timer(0.01, set_back)

    def on_measured_detail(self, msg: Float64MultiArray) -> None:
        """One sample the estimator accepted: learned (if learning is on) against the model at the node's
        temperature for the sample's stamp."""
        if not self.settings.learning_enabled:
            self._refuse('learning off')   # (counted: received = used + refused)
            return
        label = msg.layout.dim[0].label if msg.layout.dim else ''
        if len(msg.data) != len(MEASUREMENT_FIELDS) or not label:
            self._refuse(f'measured_detail not of {len(MEASUREMENT_FIELDS)} values with a joint label')
            return
        if label not in self.ff.axes:
            self._refuse('unknown joint')
            return
        d = msg.data
        if d[_METHOD] not in METHOD_NAMES:
            self._refuse('unknown method')
            return
        # (a non-finite or absurd stamp is never fresh: refused by the gate as a stale temperature)
        self.learn(label, d[_STAMP_SEC] + 1e-9 * d[_STAMP_NANOSEC], d[_VELOCITY], d[_POSITION], d[_FRICTION],
                   d[_FRESH] != 0.0)

    def learn(self, joint: str, stamp_s: float, velocity_rad_s: float, position_rad: float, friction_nm: float,
              estimator_fresh: bool) -> str | None:
        """Learn one measured friction [N·m] (signed like the motion) of ``joint`` at ``stamp_s`` [s]; the reason
        if the learner refused it."""
        temperature, source = self.ff.temperature(effective_time(stamp_s, self._now_s()))
        fresh = bool(estimator_fresh) and source == SOURCE_MEASURED
        if fresh and math.isfinite(velocity_rad_s):
            model = model_along_nm(self.ff, joint, velocity_rad_s, temperature)
            residual = friction_nm - model
        else:  # refused by the learner's gate (stale temperature; non-finite velocity): no model needed
            model, residual = 0.0, friction_nm
            temperature = temperature if math.isfinite(temperature) else 0.0   # (zero policy: NaN)
        k = self.keeper
        reason = k.learner.update(joint, temperature, velocity_rad_s, position_rad, residual, model, self._now_s(),
                                  temperature_fresh=fresh)
        if reason is None:
            k.dirty = True
        return reason

    def step_learning(self) -> None:
        if self.settings.learning_enabled and self.keeper.learner.step(self._now_s()):
            self.keeper.dirty = True
        self.update_judge()

    def poll_learning(self) -> None:
        """Take a refit the worker finished in whole (never waits for one); a timed-out or failed one is logged
        (and counted on /diagnostics)."""
        k = self.keeper
        k.poll()
        error = getattr(k.learner, 'last_fit_error', None)
        if error is not None and error != self._logged_fit_error:
            self.get_logger().error(f'learning: {error} (the feedforward keeps its correction)')
        self._logged_fit_error = error

    def save_correction(self, background: bool = True) -> None:
        """Save the correction if it changed (atomic, by a thread; errors in /diagnostics and the log)."""
        k = self.keeper
        if k.last_save_error is not None and k.last_save_error != self._logged_save_error:
            self.get_logger().error(k.last_save_error)   # (the previous save's, written by its thread)
        self._logged_save_error = k.last_save_error
        k.save(self._save_path(), background=background)

    def stop_output(self) -> None:
        """The lifecycle's deactivate: one zero feedforward for every configured joint (the motor command is left
        without friction torque, not with the last one), then the learned correction saved."""
        zero = JointState()
        zero.header.stamp = self.get_clock().now().to_msg()
        zero.name = list(self.ff.order)
        zero.effort = [0.0] * len(self.ff.order)
        self.pub_ff.publish(zero)
        self.pub_cmd.publish(self._outputs.commands([0.0] * len(self.ff.order)))
        self.save_at_stop()

    def release_node(self) -> None:
        """The lifecycle's cleanup and shutdown: what was learned saved (a configure that failed made nothing)."""
        if 'keeper' in vars(self):
            self.save_at_stop()

    def save_at_stop(self) -> None:
        """At deactivate, cleanup and shutdown (SIGINT/SIGTERM): save what was learned (waiting for it)."""
        self.save_correction(background=False)
        self.keeper.wait()
        self.keeper.close()
        if self.keeper.last_save_error is not None:
            self.get_logger().error(self.keeper.last_save_error)
        elif self.keeper.saves:
            self.get_logger().info(f'correction saved to {self.keeper.last_save_path}')

    def _refuse(self, reason: str) -> None:
        self._refused[reason] = self._refused.get(reason, 0) + 1

    def _judge_text(self) -> str:
        """The loop judge's state in words (``/diagnostics``, the correction topic)."""
        if not self._judging:
            return NOT_JUDGED
        js = self.judge.summary()
        return (f'judged by the loop: {js["cells_applied"]} cells applied, {js["cells_withdrawn"]} withdrawn, '
                f'{js["cells_testing"]} in test')

    def learning_state(self) -> str:
        """``off``, or the learner's state (``active``, ``frozen``, ``saturated``)."""
        return self.keeper.learner.state if self.settings.learning_enabled else 'off'

    def publish_correction(self) -> None:
        """``/gimbal/friction/correction``: per joint its summary, then one status per cell with data."""
        k = self.keeper
        learner, state = k.learner, self.learning_state()
        summary = learner.correction_summary()
        statuses = []
        for joint in k.identity.joints:
            js = dict(summary['joints'][joint])
            periods = js.pop('periods')
            level = WARN if js['saturated_cells'] else OK
            values = {'state': state, 'in_use': self.settings.use_correction, **js,
                      'ripple_periods': len(periods), 'file': k.loaded_from or self._save_path() or 'none',
                      'loop_judge': self._judge_text()}
            for i, q in enumerate(periods, 1):   # the ripple periods found and their evidence
                values |= {f'period_{i}_deg': q['period_deg'], f'period_{i}_amplitude': q['amplitude'],
                           f'period_{i}_z': q['z']}
            statuses.append(status(f'gimbal_friction/correction/{joint}', level, state, joint, values))
            judged = {(c['direction'], c['bin']): c for c in self.judge.cells(joint)} if self._judging else {}
            for rec in learner.cells(joint):
                name = f'gimbal_friction/correction/{joint}/{rec["direction"]}/{rec["centre_c"]:g}'
                statuses.append(status(name, WARN if rec['saturated'] else OK, rec['state'], joint,
                                       cell_values(rec) | judge_values(judged.get((rec['direction'], rec['bin'])),
                                                                       self._judging)))
        self.pub_correction.publish(diagnostic_array(self, statuses))

    # ------------------------------------------------------------------ callbacks
    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _warn(self, key: str, text: str, period_s: float = 5.0) -> None:
        now = self._now_s()
        if not now - self._last_warn.get(key, -math.inf) < period_s:
            self._last_warn[key] = now
            self.get_logger().warning(text)

    def on_temperature(self, msg: Temperature) -> None:
        time_s = effective_time(stamp_to_s(msg.header.stamp), self._now_s())
        reason = self.ff.update_temperature(float(msg.temperature), time_s)
        if reason is not None:
            self._warn('temperature', f'temperature {msg.temperature!r} degC rejected: {reason}')

    def on_reference(self, msg: JointState) -> None:
        time_s = effective_time(stamp_to_s(msg.header.stamp), self._now_s())
        reason = self.ff.update_reference(list(msg.name), list(msg.velocity), time_s)
        if reason is not None:
            self._warn('reference', f'reference_velocity message refused: {reason}')

    def on_joint_state(self, msg: JointState) -> None:
        if not self.active:   # (inactive: no output at all, as a lifecycle node)
            return
        if self.settings.max_rate_hz > 0.0:
            now = self._now_s()
            if now - self._last_publish < 1.0 / self.settings.max_rate_hz:
                self._rate_limited += 1
                return
            self._last_publish = now
        header = msg.header
        stamp_s = stamp_to_s(header.stamp)
        # the receive time is needed only for an unstamped message (reading the clock costs a few µs)
        time_s = effective_time(stamp_s, self._now_s() if stamp_s == 0.0 else 0.0)
        # the message's own sequences (a list of names, array.array of values; Feedforward.message copies nothing
        # it keeps), the positions only for a correction with a position map
        out = self.ff.message(msg.name, msg.velocity, time_s, msg.position if self._positions else None)
        self._last_time_s = time_s
        if out is None:
            self._warn('joint_state', 'joint_states message not used (see /diagnostics for the reason)')
            return
        self._last_source = out.source
        outputs = self._outputs
        self.pub_ff.publish(outputs.feedforward(header, out.names, out.torques_nm))  # the joint state's stamp
        self.pub_cmd.publish(outputs.commands(out.commands_nm))

    # ------------------------------------------------------------------ diagnostics
    def _new_since_report(self, key: str, counts: dict[str, int]) -> dict[str, int]:
        """Counts that grew since the previous diagnostics report (what keeps a status at WARN)."""
        return self.report.new_since_report(key, counts)

    def publish_diagnostics(self) -> None:
        """One status per joint (its rules: :class:`~gimbal_friction.feedforward.report.FeedforwardReport`), then
        the learning's."""
        now_s = self._last_time_s if math.isfinite(self._last_time_s) else self._now_s()
        statuses = [to_msg(one) for one in self.report.joint_statuses(
            self.ff, now_s, lost=self.inputs.new_losses(), input_problems=self.input_topics.problems(),
            input_values={**self.inputs.values(), **self.input_topics.values()}, errors=callback_error_values(self),
            rate_limited=self._rate_limited)]
        statuses.append(self._learning_status())
        self.pub_diag.publish(diagnostic_array(self, statuses))

    def _learning_status(self) -> Any:
        """``gimbal_friction/feedforward/learning``: state, samples used and refused, file, last save."""
        k = self.keeper
        learner, state = k.learner, self.learning_state()
        summary = learner.correction_summary()
        level, problems = OK, [f'learning {state}']
        if not self.settings.use_correction:
            problems.append('correction not used (pure model)')
        if k.load_error is not None:
            level = WARN
            problems.append(k.load_error)
        if k.load_note is not None:
            level = WARN
            problems.append(f'correction file {k.loaded_from}: {k.load_note}')
        if k.last_save_error is not None:
            level = WARN
            problems.append(k.last_save_error)
        if state == 'saturated':
            level = WARN
        refused = dict(learner.rejected)
        for reason, n in self._refused.items():
            refused[reason] = refused.get(reason, 0) + n
        values: dict[str, Any] = {
            'state': state, 'use_correction': self.settings.use_correction,
            received_key(topics.MEASURED_DETAIL): self.inputs.received.get(topics.MEASURED_DETAIL, 0),
            lost_key(topics.MEASURED_DETAIL): self.inputs.values().get(lost_key(topics.MEASURED_DETAIL), 0),
            'samples_used': learner.accepted, 'samples_refused': sum(refused.values()),
            **{f'refused: {r}': n for r, n in sorted(refused.items())}, 'samples_discarded': learner.discarded,
            'cells_with_data': summary['cells_with_data'], 'samples_in_correction': summary['samples'],
            'saturated_cells': summary['saturated_cells'], 'max_abs_correction_nm': summary['max_abs_correction_nm'],
            'cells_applied': summary['cells_applied'], 'cells_held_back': summary['cells_held_back'],
            'max_abs_unbalance_nm': summary['max_abs_unbalance_nm'], 'samples_pending': learner.pending,
            'lookup_saturations': summary['lookup_saturations'], 'load_note': k.load_note or 'none',
            'correction_file': self.settings.correction_file or 'none',
            'loaded_from': k.loaded_from or 'none', 'load_error': k.load_error or 'none',
            'save_file': self._save_path() or 'none (not saved)', 'saves': k.saves,
            'last_save_time': (time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(k.last_save_time))
                               if k.last_save_time is not None else 'never'),
            'last_save_error': k.last_save_error or 'none',
            'last_save_duration_s': k.last_save_duration_s if k.last_save_duration_s is not None else 'never',
            'unsaved_learning_s': k.unsaved_s(),   # what a crash now would lose
        }
        js = self.judge.summary()
        problems.append(self._judge_text())
        values |= {'loop_judge': self._judge_text(), 'learning_judge': learner.settings.judge,
                   received_key(LOOP_ERROR): self.inputs.received.get(LOOP_ERROR, 0),
                   'judge_samples': js['samples'], 'judge_late_samples': js['late_samples'],
                   'judge_cells_testing': js['cells_testing'], 'judge_cells_applied': js['cells_applied'],
                   'judge_cells_withdrawn': js['cells_withdrawn'], 'judge_tests_started': js['restarts']}
        fits = self._fit_values(learner)
        new_fit = self._new_since_report('fit', {key: fits[key] for key in ('fit_timeouts', 'fit_failures')})
        if new_fit:
            level = WARN
            problems.append('refits ' + ', '.join(f'{n} new {key[4:]}' for key, n in sorted(new_fit.items()))
                            + f': {fits["last_fit_error"]} (the feedforward keeps its correction)')
        values |= fits
        return status('gimbal_friction/feedforward/learning', level, '; '.join(problems), 'learning', values)

    def _fit_values(self, learner: Any) -> dict[str, Any]:
        """Where the refits run and how they went (counts [-], the last fit's duration [s])."""
        return {'fit_worker': learner.settings.fit_worker if hasattr(learner, 'fits') else 'inline',
                'fits': getattr(learner, 'fits', 0), 'fit_timeouts': getattr(learner, 'fit_timeouts', 0),
                'fit_failures': getattr(learner, 'fit_failures', 0),
                'samples_lost': getattr(learner, 'samples_lost', 0),
                'samples_in_fit': getattr(learner, 'in_flight', 0),
                'last_fit_s': (learner.last_fit_s if math.isfinite(getattr(learner, 'last_fit_s', math.nan))
                               else 'none'),
                'last_fit_error': getattr(learner, 'last_fit_error', None) or 'none',
                'fit_worker_pid': getattr(learner, 'worker_pid', None) or 'none'}


def main(args: Sequence[str] | None = None) -> None:
    """console_scripts entry point: ``friction_feedforward --ros-args --params-file config/gimbal_friction.yaml``."""
    sys.exit(run_node('friction_feedforward', FrictionFeedforward, args, suite_node='friction_feedforward'))


if __name__ == '__main__':
    main()
