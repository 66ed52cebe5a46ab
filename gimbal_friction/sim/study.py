"""The closed-loop study (engine of ``gimbal-friction loop-study``): cases × temperature plateaus × profiles.

One job in one module: the study's run (its cases, the learning window and the scoring share one batch layout
and one report).

For every profile, all cases × temperatures integrate together in one vectorised batch
(:func:`~gimbal_friction.sim.engine.simulate`); every run sees the same sensor-noise stream (common random
numbers), so differences between cases are the cases'. Each temperature is a soaked plateau (bearing =
environment at t = 0 unless ``initial_bearing_offset_c`` says otherwise).

Case (d) ``refit`` closes the suite's own loop, estimate → log → refit → better feedforward, through the very
functions the nodes and ``gimbal-friction refit`` run:

1. the plain-feedforward runs of the service history at every plateau (another noise seed, :data:`LEARN_SEED`, and
   other motions than those scored, so the refit is scored out of sample), are turned into the estimator's input
   streams at the controller rate (:meth:`~gimbal_friction.sim.engine.EstimatorTrace.chamber_arrays`) and fed to
   :class:`~gimbal_friction.estimation.estimator.EstimatorLogic` (method ``observer`` by default: friction while the
   gimbal works, no constant-speed sweep needed; ``steady_state`` and ``both`` are offered);
2. each measurement is paired with the feedforward computed for its joint-state stamp
   (:func:`~gimbal_friction.estimation.residuals.pair_residuals`) into residual rows
   (:func:`~gimbal_friction.streams.residual_row.residual_rows`,
   :func:`~gimbal_friction.estimation.residuals.credible_rows`):
   what ``residual_logger`` logs;
3. the rows are accumulated into sufficient statistics and refitted exactly as ``gimbal-friction refit`` does
   (:func:`~gimbal_friction.refit.sufficient.accumulate_rows`, :func:`~gimbal_friction.refit.fit.refit_stats`,
   calibration offset ``auto``), by default for ``walther_a`` and the two direction-asymmetry anchors
   (:data:`DEFAULT_REFIT_FIT`, see :func:`refit_rows`);
4. case (d) runs the same feedforward with the refitted parameters.

Case ``learned`` learns in service, **one correction for every motion**: a *service history*
(:func:`~gimbal_friction.sim.profiles.history_profile`: the study's motions interleaved with motions it does not
score — slews, holding, tracking at other speeds, a wider slower scan, pointing under base motion) runs at every
plateau with the feedforward learning online, with the node's own settings (:data:`STUDY_CORRECTION`: the
defaults of ``friction_feedforward``; only the learning rate is raised, :data:`STUDY_LEARNING`, to compress a
service life into the history; :func:`study_settings` says so). One
:class:`~gimbal_friction.feedforward.correction.Learner` over all plateaus is fed the estimator's observer samples
every :data:`LEARN_CHUNK_S` of simulated time and steps at the node's ``step_period_s``; nothing of the simulator's
truth reaches it (ripple periods, speed shape and a torque independent of the direction are found in the data).
The correction is then frozen and scores every profile on seed 0, including ``weave``, which the history never
holds. The learning run is reported too (case ``learning``, with its worst 10 s window against the plain feedforward
of the same run).

Case ``chamber`` is what a user has before the gimbal enters service: the correction learned from the chamber test
of the same truth alone — the paper's protocol (each plateau soaked, constant-speed sweeps each way at the tracking
speed) simulated in closed loop without compensation, its streams replayed through the suite's own chamber path
(the ``chamber`` hook: the estimator's steady-state rules, the residual rows, the correction learned test-then-train
in time order with the same guard), scored like every case.

Case ``bound`` is the truth's own static map through the feedforward's delivery
(:func:`~gimbal_friction.sim.compensation.truth_bound`).

Records (one per case × temperature × profile) carry at least ``case``, ``temperature_c``, ``profile``,
``rate_error_rms_rad_s``, ``rate_error_peak_rad_s``, ``position_error_rms_rad``, ``position_error_peak_rad``,
``reversal_error_peak_rad``, ``current_margin`` (docs/cli.md ``loop-study``), plus ``duration_s``.
:func:`goal_checks` evaluates the study's goals on them (the feedforward against no compensation, the
constant and the ideal; at reversals; the learning goals of :data:`LEARNING_GOALS`); :func:`explain_misses` names
the truth term responsible for each missed learning goal.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError
from gimbal_friction.common.units import NS_PER_S, RAD_S_PER_RPM
from gimbal_friction.common.xp import ARRAY
from gimbal_friction.estimation.estimator import EstimatorLogic, EstimatorSettings
from gimbal_friction.estimation.residuals import credible_rows, pair_residuals
from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionSettings,
    Learner,
    LearningSettings,
    model_identity,
)
from gimbal_friction.feedforward.correction.judge import LoopJudge
from gimbal_friction.feedforward.correction.settings import JudgeSettings
from gimbal_friction.feedforward.presliding import PreslidingSettings, PreslidingTerm, ReversalRun
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings, check_velocity_source, velocity_used
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.fit import FIT_PARAMETERS, RefitResult, refit_stats
from gimbal_friction.refit.sufficient import SufficientStats, accumulate_rows
from gimbal_friction.sim.compensation import (
    CASE_CHAMBER,
    CASE_NONE,
    CASES,
    DEFAULT_CASES,
    EXTRA_CASES,
    JOINT,
    Compensator,
    ControllerInputs,
    constant_coulomb,
    dynamic_feedforward,
    model_friction,
    suite_feedforward,
    truth_bound,
)
from gimbal_friction.sim.config import PROFILES, SimConfig
from gimbal_friction.sim.engine import BatchResult, ClosedLoop, EstimatorTrace, Run, simulate
from gimbal_friction.sim.metrics import batch_metrics
from gimbal_friction.sim.profiles import Profile, history_profile, make_profile
from gimbal_friction.streams.arrays import ChamberArrays
from gimbal_friction.streams.measurement import METHOD_OBSERVER, METHOD_STEADY_STATE, MeasurementArrays
from gimbal_friction.streams.residual_row import ResidualRows

Array = NDArray[np.float64]

__all__ = [
    'CHAMBER_SEED',
    'DEFAULT_REFIT_FIT',
    'DEFAULT_TEMPERATURES',
    'ESTIMATOR_METHODS',
    'LEARNING_GOALS',
    'LEARN_SEED',
    'PRESLIDING_ESTIMATOR',
    'REPORT_ORDER',
    'SHORT_DURATIONS',
    'STUDY_CORRECTION',
    'STUDY_GOALS',
    'STUDY_JUDGE',
    'STUDY_LEARNING',
    'TRUTH_TERMS',
    'ChamberHook',
    'FeedforwardSetup',
    'LearnSetup',
    'RefitOutcome',
    'ReversalTrace',
    'StudyResult',
    'estimator_rows',
    'explain_misses',
    'goal_checks',
    'goal_legend',
    'judged_compensator',
    'presliding_runs',
    'refit_rows',
    'run_study',
    'study_settings',
    'term_off',
    'window_ratio',
]

#: Temperature plateaus of the study [°C] (the paper's chamber test).
DEFAULT_TEMPERATURES = (-40.0, -20.0, 0.0, 20.0, 40.0, 60.0)
#: Profile durations of the short (CI) study [s]: one reversal each after the 1 s transient.
SHORT_DURATIONS = {'tracking': 5.5, 'scan': 2.5, 'pointing': 2.5, 'weave': 5.5}
#: Parameters refitted for case (d) by default (see :func:`refit_rows`).
DEFAULT_REFIT_FIT = ('walther_a', 'direction_asymmetry_cold', 'direction_asymmetry_warm')
#: Estimator methods case (d) can collect its data with.
ESTIMATOR_METHODS = ('observer', 'steady_state', 'both')
#: Window of the reversal traces around the first reversal after the transient [s].
REVERSAL_TRACE_WINDOW_S = (-0.5, 1.0)
#: Noise seed of the learning runs (scoring runs: seed 0), so ``refit`` and ``learned`` are scored out of sample.
LEARN_SEED = 1
#: Noise seed of the chamber test (case ``chamber``).
CHAMBER_SEED = 2
#: The service history is passed this many times (``LearnSetup.duration_factor``; one pass is 64 s, 19 s short).
LEARN_FACTOR = 2.0
#: One pass of the service history in the short (CI) study is this fraction of the full one [-].
SHORT_HISTORY_SCALE = 0.3
#: The chamber test at each plateau: the tracking profile's constant-speed sweeps each way, this long [s] (short: 45 s,
#: the least at which a cell of a 200 Hz chamber bag has the guard's 3000 out-of-sample scores in each direction).
CHAMBER_S = 60.0
SHORT_CHAMBER_S = 45.0
#: The chamber test's estimator: the paper's steady-state rules where the speed holds, the observer where a
#: friction ripple moves it by more than the tolerance (an uncompensated loop in the cold).
CHAMBER_METHOD = 'both'
#: The chamber streams are replayed at this fraction of the controller rate (a chamber bag at 200 Hz) [-].
CHAMBER_EVERY_TICKS = 5
#: Window of the check "while learning never more than 5 % worse than the plain feedforward" [s].
LEARN_WINDOW_S = 10.0
#: The learning run feeds the estimator the messages of this much simulated time at once [s] (the node's callbacks).
LEARN_CHUNK_S = 0.1
#: Correction of cases ``learned`` and ``chamber``: the defaults of ``friction_feedforward``, nothing else.
STUDY_CORRECTION = CorrectionSettings()
#: Learning of case ``learned``: the node's defaults but the rate: the applied correction moves by at most 1e-2 N·m
#: per minute (the node's default is 3e-4: the study compresses a service life into a history of two minutes or less,
#: :func:`study_settings` states the factor).
STUDY_LEARNING = LearningSettings(max_rate_nm_per_min=1e-2)
#: The estimator's gates for the pre-sliding identification of case ``dynamic``: the node's observer with its gates
#: near zero speed opened (minimum speed, acceleration, its noise, a torque opposing the motion): the samples
#: through a reversal are exactly those the static path refuses.
PRESLIDING_ESTIMATOR: dict[str, Any] = {'observer_min_speed_rad_s': 1e-9, 'observer_max_accel_rad_s2': 1e6,
                                        'observer_max_accel_noise_rad_s2': 1e6, 'max_opposing_torque_nm': 100.0}
#: The loop's judge of case ``learned``: the node's defaults (``learning_judge`` on, the ``judge_*`` parameters).
STUDY_JUDGE = JudgeSettings()
#: Cases in report order (``learning``: the learning run of ``learned``, scored on its own seed and motions).
REPORT_ORDER = (*CASES[:4], 'learning', *CASES[4:], *EXTRA_CASES)
#: Gap between the stamps of successive runs in the estimator's streams [s] (a run's stamps never overlap another's).
RUN_GAP_S = 60.0

#: Refit of case (d): the residual rows and the configured params -> refitted params (or the whole RefitResult).
RefitHook = Callable[[ResidualRows, AxisParams], 'RefitResult | AxisParams']
#: Progress: (stage, fraction of the whole study done 0..1).
Progress = Callable[[str, float], None]
#: Case ``chamber``: the chamber test's streams (one per plateau, in time order), the configured params, the
#: estimator's settings and the correction's -> the correction learned from them and a record of what it read
#: (the suite's chamber path: :func:`gimbal_friction.chamber.learned.chamber_correction`).
ChamberHook = Callable[[Sequence[ChamberArrays], AxisParams, EstimatorSettings, CorrectionSettings],
                       tuple[Correction, dict[str, Any]]]


class FeedforwardSetup(NamedTuple):
    """How the suite's feedforward is configured (the ``friction_feedforward`` parameters the study uses)."""

    settings: FeedforwardSettings = FeedforwardSettings()
    velocity_source: str = 'measured'   #: the node's ``velocity_source`` (VELOCITY_SOURCES)

    def compensator(self, params: AxisParams, velocity_source: str | None = None, *,
                    correction: Correction | None = None) -> Compensator:
        """The feedforward of ``params`` (cases feedforward, refit, learned with ``correction``), on
        ``velocity_source`` (default the configured one)."""
        return suite_feedforward(params, self.settings, velocity_source=velocity_source or self.velocity_source,
                                 correction=correction)


class LearnSetup(NamedTuple):
    """How case ``learned`` learns (the correction's settings, the learner's, the length of the service history, the
    loop's judge: None for the residual guard alone)."""

    correction: CorrectionSettings = STUDY_CORRECTION
    learning: LearningSettings = STUDY_LEARNING
    duration_factor: float = LEARN_FACTOR   #: passes of the service history [-]
    judge: JudgeSettings | None = STUDY_JUDGE


def study_settings(learn: LearnSetup) -> dict[str, Any]:
    """What the study's learning runs with against the node's defaults: ``differs_from_node_default`` (setting →
    ``{'study': …, 'node': …}``, names as the node's parameters), ``time_compression`` (study rate / node rate [-]:
    an hour of service is learned in 1/that of an hour) and the service history's length."""
    diffs: dict[str, Any] = {}
    pairs: list[tuple[str, Any, Any]] = [('correction_', learn.correction, CorrectionSettings()),
                                         ('learning_', learn.learning, LearningSettings())]
    if learn.judge is None:
        diffs['learning_judge'] = {'study': 'off', 'node': 'auto'}
    else:
        pairs.append(('judge_', learn.judge, JudgeSettings()))
    for prefix, mine, node in pairs:
        for f in dataclasses.fields(mine):
            a, b = getattr(mine, f.name), getattr(node, f.name)
            if a != b:
                diffs[prefix + f.name] = {'study': a, 'node': b}
    return {'differs_from_node_default': diffs,
            'time_compression': learn.learning.max_rate_nm_per_min / LearningSettings().max_rate_nm_per_min,
            'history_passes': learn.duration_factor}


class ReversalTrace(NamedTuple):
    """Time series of one run around a reversal (for the figure), times relative to the reversal."""

    case: str
    temperature_c: float
    profile: str
    reversal_time_s: float       #: time of the reversal in the run [s]
    time_s: Array                #: time relative to the reversal [s]
    position_error_rad: Array    #: LOS position error [rad]
    rate_error_rad_s: Array      #: LOS rate error [rad/s]
    joint_velocity_rad_s: Array  #: true relative rate [rad/s]
    friction_nm: Array           #: truth friction torque [N·m]
    feedforward_nm: Array        #: compensation torque applied [N·m]


class RefitOutcome(NamedTuple):
    """What case (d) was built from: the estimator's measurements, the residual rows, the refit."""

    measurements: MeasurementArrays   #: accepted samples of the case-(c) runs
    rows: ResidualRows                #: residual rows (what residual_logger logs)
    counters: dict[str, Any]          #: estimator counters summed over the runs (accepted, rejected by reason)
    result: RefitResult | None        #: the refit (None: refused, or a hook that returned parameters only)
    params: AxisParams | None         #: parameters of case (d) (None: refused)
    error: str | None                 #: why the refit was refused


class StudyResult(NamedTuple):
    """Outcome of :func:`run_study`."""

    records: list[dict[str, Any]]          #: one per case × temperature × profile
    reversal_traces: list[ReversalTrace]   #: per case, coldest plateau, first reversal (tracking if run, else the
    #: first profile)
    refit: RefitOutcome | None             #: case (d)'s data and refit (None: not requested)
    notes: list[str]                       #: what happened that a reader should know (refit outcome, ...)
    wall_s: dict[str, float]               #: wall time per stage [s]
    config: SimConfig                      #: the configuration the study ran with (short durations applied)
    learned: dict[str, Correction] | None = None   #: ``history`` (case ``learned``) and ``chamber``: the corrections
    learners: dict[str, Learner] | None = None     #: ``history``: the learner of case ``learned`` (counters, state)
    chamber: dict[str, Any] | None = None          #: case ``chamber``: what its chamber path read
    presliding: PreslidingTerm | None = None       #: case ``dynamic``: the pre-sliding term learned
    judges: dict[str, LoopJudge] | None = None     #: ``history``: the loop's judge of case ``learned`` (frozen)

    @property
    def refit_params(self) -> AxisParams | None:
        """Parameters of case (d) (None: not run)."""
        return None if self.refit is None else self.refit.params


# ---------------------------------------------------------------------------------------------- the case-(d) chain
def _merge_counters(total: dict[str, Any], add: dict[str, Any]) -> None:
    for key in ('accepted', 'temperature_rejected'):
        bucket = total.setdefault(key, {})
        for k, v in add.get(key, {}).items():
            bucket[k] = bucket.get(k, 0) + v
    rejected = total.setdefault('rejected', {})
    for joint, reasons in add.get('rejected', {}).items():
        bucket = rejected.setdefault(joint, {})
        for k, v in reasons.items():
            bucket[k] = bucket.get(k, 0) + v


def estimator_rows(results: Sequence[tuple[BatchResult, Sequence[int]]], axis: AxisParams,
                   settings: EstimatorSettings, *, start_s: float = 1.0
                   ) -> tuple[MeasurementArrays, ResidualRows, dict[str, Any]]:
    """The estimator's measurements and the residual logger's rows for runs of simulated batches.

    Each run (``(batch, run indices)``) is fed, as the node would receive it at the controller rate, to its own
    :class:`~gimbal_friction.estimation.estimator.EstimatorLogic` (the run's stamps follow the previous run's after
    :data:`RUN_GAP_S`, from ``start_s`` [s]); each measurement is paired with the feedforward computed for its
    joint-state stamp and kept if credible, as ``residual_logger`` does.

    Returns:
        (measurements, residual rows, estimator counters summed over the runs)
    """
    parts_m: list[MeasurementArrays] = []
    parts_r: list[ResidualRows] = []
    counters: dict[str, Any] = {}
    start_ns = int(round(start_s * NS_PER_S))
    for batch, indices in results:
        gap_ns = int(round((float(batch.profile.time_s[-1]) + RUN_GAP_S) * NS_PER_S))
        for i in indices:
            trace = batch.estimator_trace(i, start_ns=start_ns)
            logic = EstimatorLogic({JOINT: axis}, settings)
            m = logic.feed(trace.chamber_arrays(JOINT), final=True)   # the run is the whole input
            _merge_counters(counters, logic.counters.as_dict())
            rows = pair_residuals(m, np.full(trace.stamp_ns.shape, JOINT), trace.stamp_ns,
                                  batch.traces.feedforward_computed_nm[:, i])
            keep = credible_rows(rows)
            parts_m.append(m.select(keep))
            parts_r.append(rows.select(keep))
            start_ns += gap_ns
    return MeasurementArrays.concatenate(parts_m), ResidualRows.concatenate(parts_r), counters


def refit_rows(rows: ResidualRows, axis: AxisParams, fit: Sequence[str] = DEFAULT_REFIT_FIT) -> RefitResult:
    """Refit ``axis`` to residual rows the way ``gimbal-friction refit`` does (sufficient statistics of the rows,
    :func:`~gimbal_friction.refit.fit.refit_stats`, calibration offset ``auto``).

    The default parameters (:data:`DEFAULT_REFIT_FIT`): ``walther_a``, the lubricant's viscosity level, which the
    cold plateaus determine (Palmgren's upper branch) and which the configured lubricant gets wrong; and
    ``direction_asymmetry_cold`` / ``_warm``, the temperature-dependent CW/CCW difference, which the observer sees
    in both directions at every plateau (the paper attributes it to grease distribution, not viscosity, so it is
    not folded into the viscosity). The refit also holds any parameter the data cannot determine at its
    configured value and says so.

    Raises:
        FitError: too few samples, or data that determine none of the parameters.
    """
    stats: dict[str, SufficientStats] = accumulate_rows(rows, {}, joints=[JOINT])
    if JOINT not in stats:
        return refit_stats(axis, SufficientStats.empty(), fit=fit)   # raises: too few samples
    return refit_stats(axis, stats[JOINT], fit=fit)


# ---------------------------------------------------------------------------------------------- the study
def _short_config(config: SimConfig) -> SimConfig:
    return config.replace(**{f'{p}_duration_s': s for p, s in SHORT_DURATIONS.items()})


def _records(result: BatchResult, duration_s: float) -> list[dict[str, Any]]:
    out = []
    for run, met in zip(result.runs, batch_metrics(result), strict=True):
        rec: dict[str, Any] = {'case': run.case, 'temperature_c': run.temperature_c, 'profile': result.profile.name}
        rec.update(met._asdict())
        rec['duration_s'] = duration_s
        out.append(rec)
    return out


def _reversal_traces(result: BatchResult, temperature_c: float) -> list[ReversalTrace]:
    prof, tr, cfg = result.profile, result.traces, result.config
    later = [t for t in prof.reversal_times_s if t >= cfg.settle_s]
    if not later:
        return []
    t_rev = float(later[0])
    sel = (prof.time_s >= t_rev + REVERSAL_TRACE_WINDOW_S[0]) & (prof.time_s <= t_rev + REVERSAL_TRACE_WINDOW_S[1])
    out = []
    for i, run in enumerate(result.runs):
        if run.temperature_c != temperature_c:
            continue
        out.append(ReversalTrace(
            run.case, run.temperature_c, prof.name, t_rev, prof.time_s[sel] - t_rev,
            tr.los_angle_rad[sel, i] - prof.target_angle_rad[sel],
            tr.los_rate_rad_s[sel, i] - prof.target_rate_rad_s[sel],
            tr.joint_velocity_true_rad_s[sel, i], tr.friction_nm[sel, i], tr.feedforward_nm[sel, i]))
    return out


def _check(temperatures: Sequence[float], profiles: Sequence[str], cases: Sequence[str],
           feedforward: FeedforwardSetup, estimator_method: str, refit_fit: Sequence[str],
           refit_profiles: Sequence[str] | None) -> list[float]:
    known = CASES + EXTRA_CASES
    for c in cases:
        if c not in known:
            raise ConfigError('cases', f'unknown case (choose from {", ".join(known)})', c)
    if not cases:
        raise ConfigError('cases', 'needs at least one case')
    for p in (*profiles, *(refit_profiles or ())):
        if p not in PROFILES:
            raise ConfigError('profiles', f'unknown profile (choose from {", ".join(PROFILES)})', p)
    if not profiles:
        raise ConfigError('profiles', 'needs at least one profile')
    temps = [float(t) for t in temperatures]
    if not temps:
        raise ConfigError('temperatures', 'needs at least one temperature')
    for t in temps:
        if not (math.isfinite(t) and -60.0 <= t <= 120.0):
            raise ConfigError('temperatures', 'must lie in [-60, 120] [degC]', t)
    check_velocity_source(feedforward.velocity_source)
    feedforward.settings.validate()
    if estimator_method not in ESTIMATOR_METHODS:
        raise ConfigError('estimator_method', f'must be one of {", ".join(ESTIMATOR_METHODS)}', estimator_method)
    for name in refit_fit:
        if name not in FIT_PARAMETERS:
            raise ConfigError('refit_fit', f'unknown parameter (choose from {", ".join(FIT_PARAMETERS)})', name)
    if not refit_fit:
        raise ConfigError('refit_fit', 'needs at least one parameter')
    return list(dict.fromkeys(temps))


def _learn_chunk(result: BatchResult, k0: int, k1: int, logics: dict[int, EstimatorLogic], learner: Learner,
                 model: Callable[[Any, Any], Array], start_ns: int) -> None:
    """Feed ticks [k0, k1) of the learning runs to their estimators and the accepted samples to the learner (the
    node's gates: accepted by the estimator, then the learner's)."""
    tr = result.traces
    stamps = start_ns + np.round(result.profile.time_s[k0:k1] * NS_PER_S).astype(np.int64)
    for i, logic in logics.items():
        trace = EstimatorTrace(result.runs[i], stamps, tr.joint_position_rad[k0:k1, i],
                               tr.joint_velocity_rad_s[k0:k1, i], tr.current_measured_a[k0:k1, i],
                               tr.temperature_c[k0:k1, i], result.temperature_sampled[k0:k1],
                               tr.gyro_rate_rad_s[k0:k1, i])
        m = logic.feed(trace.chamber_arrays(JOINT))
        if len(m):
            modelled = model(m.temperature_c, m.velocity_rad_s)
            learner.update_many(JOINT, m.temperature_c, m.velocity_rad_s, m.position_rad, m.friction_nm - modelled,
                                modelled, m.temperature_fresh)


def window_ratio(result: BatchResult, run: int, reference: int, window_s: float = LEARN_WINDOW_S,
                 step_s: float = 1.0) -> float:
    """Largest ratio of the LOS rate error RMS of run ``run`` over run ``reference`` in any window of ``window_s``
    [s] after the transient (``settle_s``), windows every ``step_s`` [s] (the whole run if shorter) [-]."""
    cfg, prof, tr = result.config, result.profile, result.traces
    keep = prof.time_s >= cfg.settle_s
    e = (tr.los_rate_rad_s[keep][:, [run, reference]] - prof.target_rate_rad_s[keep][:, None]) ** 2
    n = e.shape[0]
    w = min(n, max(1, int(round(window_s * cfg.rate_loop_hz))))
    step = max(1, int(round(step_s * cfg.rate_loop_hz)))
    c = np.concatenate([np.zeros((1, 2)), np.cumsum(e, axis=0)])
    starts = np.arange(0, n - w + 1, step)
    sums = c[starts + w] - c[starts]
    ratio = np.sqrt(sums[:, 0] / np.maximum(sums[:, 1], 1e-300))
    return float(ratio.max())


def presliding_runs(result: BatchResult, indices: Sequence[int], axis: AxisParams, ff: FeedforwardSetup,
                    correction: Correction | None, estimator: EstimatorSettings) -> list[ReversalRun]:
    """The data of the pre-sliding identification from runs ``indices`` of a simulated batch: per run, at every
    controller tick, the velocity the feedforward uses (its ``velocity_source``), the measured temperature, the
    feedforward's static level along the motion and its part independent of the direction (the model and
    ``correction``), and the friction sample the estimator took at the tick (its observer with
    :data:`PRESLIDING_ESTIMATOR`'s gates; NaN at ticks without one). Nothing of the truth: the streams the estimator
    and the feedforward receive."""
    settings = dataclasses.replace(estimator, method='observer', **PRESLIDING_ESTIMATOR)
    tr, prof, cfg = result.traces, result.profile, result.config
    model_ff = Feedforward({JOINT: axis}, ff.settings)
    tick_ns = cfg.controller_period_s * NS_PER_S
    out = []
    for i in indices:
        trace = result.estimator_trace(i, start_ns=0)
        logic = EstimatorLogic({JOINT: axis}, settings)
        m = logic.feed(trace.chamber_arrays(JOINT), final=True)
        n = prof.time_s.shape[0]
        friction = np.full(n, np.nan)
        k = np.round(m.stamp_ns / tick_ns).astype(np.int64)
        keep = (k >= 0) & (k < n)
        friction[k[keep]] = m.friction_nm[keep]
        source = 'reference' if ff.velocity_source == 'auto' else ff.velocity_source
        v = np.asarray(velocity_used(source, tr.joint_velocity_rad_s[:, i], tr.reference_velocity_rad_s[:, i], True,
                                     ARRAY), dtype=float)
        t = np.asarray(tr.temperature_c[:, i], dtype=float)
        have = np.isfinite(t)
        t_eval = np.where(have, t, ff.settings.fallback_temperature_c)
        model = np.asarray(model_ff.model_nm(JOINT, v, t_eval, ARRAY), dtype=float)
        if correction is not None:
            odd, even = correction.split_nm_array(JOINT, t_eval, v, tr.joint_position_rad[:, i], model)
        else:
            odd, even = np.zeros(n), np.zeros(n)
        out.append(ReversalRun(prof.time_s.copy(), v, np.where(have, t, np.nan), model + odd, even, friction))
    return out


def judged_compensator(plain: Compensator, corrected: Compensator, judge: LoopJudge) -> Compensator:
    """The feedforward the loop's judge chooses per run and tick: ``corrected`` (the learned correction) where
    :meth:`~gimbal_friction.feedforward.correction.judge.LoopJudge.use_candidate` says so for the run's cell (the
    latest temperature published [°C], the resolver's joint rate [rad/s]), ``plain`` (the model) elsewhere; both are
    evaluated every tick, so each keeps its temperature state. Delayed like ``corrected``."""
    def torque(inputs: ControllerInputs) -> Array:
        use = judge.use_candidate_array(JOINT, inputs.temperature_c, inputs.joint_velocity_rad_s, inputs.time_s)
        a = np.asarray(plain.torque(inputs), dtype=float)
        b = np.asarray(corrected.torque(inputs), dtype=float)
        return np.asarray(np.where(use, b, a), dtype=float)

    return Compensator(torque, corrected.delayed)


def _judge_chunk(result: BatchResult, k0: int, k1: int, runs: Sequence[int], judge: LoopJudge) -> None:
    """The loop error of ticks [k0, k1) of the learning runs to the judge: the LOS rate error the controller
    measures (gyro − the target's rate [rad/s]; no truth), with the temperature the sensor published [°C] and the
    resolver's joint rate [rad/s]."""
    tr, prof = result.traces, result.profile
    t = prof.time_s[k0:k1]
    for i in runs:
        judge.observe(JOINT, t, tr.temperature_c[k0:k1, i], tr.joint_velocity_rad_s[k0:k1, i],
                      tr.gyro_rate_rad_s[k0:k1, i] - prof.target_rate_rad_s[k0:k1])


def _learning_batch(cfg: SimConfig, axis: AxisParams, ff: FeedforwardSetup, prof: Profile, temps: Sequence[float],
                    learn: LearnSetup, estimator: EstimatorSettings, want_learned: bool,
                    report: Callable[[float], None]) -> tuple[BatchResult, Learner | None, LoopJudge | None]:
    """The service history at every plateau (seed :data:`LEARN_SEED`): the plain feedforward (the refit's data and
    the reference of the cost while learning) and, with ``want_learned``, the feedforward learning online (one
    :class:`~gimbal_friction.feedforward.correction.Learner` over the plateaus, from an empty correction, stepped at
    its ``step_period_s`` like the node's timer). With ``learn.judge``, the loop's judge
    (:class:`~gimbal_friction.feedforward.correction.judge.LoopJudge`) chooses per cell and block between the
    learned correction and the model, from the learning runs' loop error; it is frozen at the end."""
    runs = [Run('feedforward', t, LEARN_SEED) for t in temps]
    comps = {'feedforward': ff.compensator(axis)}
    learner: Learner | None = None
    judge: LoopJudge | None = None
    if want_learned:
        learner = Learner(Correction(learn.correction, model_identity({JOINT: axis})), learn.learning)
        runs += [Run('learned', t, LEARN_SEED) for t in temps]
        comps['learned'] = ff.compensator(axis, correction=learner.correction)
        if learn.judge is not None:
            judge = LoopJudge(learn.correction, (JOINT,), learn.judge)
            comps['learned'] = judged_compensator(ff.compensator(axis), comps['learned'], judge)
    loop = ClosedLoop(cfg, axis, prof, runs, comps)
    if learner is None:
        while not loop.done:
            loop.step()
            if loop.k % 1000 == 0:
                report(loop.k / loop.ticks)
        return loop.result(), None, None
    judged = [i for i, r in enumerate(runs) if r.case == 'learned']
    settings = dataclasses.replace(estimator, method='observer')
    logics = {i: EstimatorLogic({JOINT: axis}, settings) for i, r in enumerate(runs) if r.case == 'learned'}
    model = model_friction(axis)
    chunk = max(1, int(round(LEARN_CHUNK_S * cfg.rate_loop_hz)))
    period = learn.learning.step_period_s
    learner.step(0.0)
    next_step = period
    k0 = 0
    while not loop.done:
        for _ in range(min(chunk, loop.ticks - loop.k)):
            loop.step()
        res = loop.result()
        _learn_chunk(res, k0, loop.k, logics, learner, model, 0)
        if judge is not None:
            _judge_chunk(res, k0, loop.k, judged, judge)
        k0 = loop.k
        now = loop.k * cfg.controller_period_s
        if now >= next_step - 1e-9:     # the node's step timer
            learner.step(now)
            if judge is not None:
                judge.update_candidates(learner.correction)
            next_step += period
        report(loop.k / loop.ticks)
    learner.freeze()
    if judge is not None:
        judge.freeze()
    return loop.result(), learner, judge


def _chamber_batch(cfg: SimConfig, axis: AxisParams, temps: Sequence[float], short: bool,
                   report: Callable[[float], None]) -> list[ChamberArrays]:
    """The chamber test of the truth (seed :data:`CHAMBER_SEED`): at every soaked plateau, constant-speed sweeps each
    way over the tracking travel, no compensation; per plateau its streams as a chamber bag holds them (joint states
    and currents every :data:`CHAMBER_EVERY_TICKS` ticks, the temperature at its own rate), one plateau after the
    other in time."""
    duration = SHORT_CHAMBER_S if short else CHAMBER_S
    base = cfg.replace(base_motion_profiles=())
    prof = make_profile(base, 'tracking', duration)
    runs = [Run(CASE_NONE, t, CHAMBER_SEED) for t in temps]
    loop = ClosedLoop(base, axis, prof, runs, {})
    while not loop.done:
        loop.step()
        if loop.k % 1000 == 0:
            report(loop.k / loop.ticks)
    result = loop.result()
    gap_ns = int(round((duration + RUN_GAP_S) * NS_PER_S))
    return [result.estimator_trace(i, start_ns=NS_PER_S + i * gap_ns).chamber_arrays(JOINT, CHAMBER_EVERY_TICKS)
            for i in range(len(runs))]


def run_study(config: SimConfig, axis: AxisParams | None = None, *,
              temperatures: Sequence[float] = DEFAULT_TEMPERATURES, profiles: Sequence[str] = PROFILES,
              cases: Sequence[str] = DEFAULT_CASES, short: bool = False,
              feedforward: FeedforwardSetup | None = None, estimator: EstimatorSettings | None = None,
              estimator_method: str = 'observer', refit_fit: Sequence[str] = DEFAULT_REFIT_FIT,
              refit_profiles: Sequence[str] | None = None, refit: RefitHook | None = None,
              learn: LearnSetup | None = None, chamber: ChamberHook | None = None,
              progress: Progress | None = None) -> StudyResult:
    """Run the closed loop for every case × temperature × profile and measure the LOS errors.

    Cases ``refit`` and ``learned`` are scored out of sample: they learn from the service history
    (:func:`~gimbal_friction.sim.profiles.history_profile`, ``learn.duration_factor`` passes) on another noise seed
    (:data:`LEARN_SEED`), then every case is scored on seed 0 over [0, duration] of each profile. ``learned`` is one
    correction for every profile. The learning run is scored too (case ``learning``, with
    ``learning_worst_window_ratio``: its worst 10 s window against the plain feedforward on the same seed and
    motions). Case ``chamber`` learns from a simulated chamber test of the same truth (seed :data:`CHAMBER_SEED`)
    through ``chamber``.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration (``feedforward_latency_s`` is the transport latency of the node cases).
    axis : AxisParams, optional
        The configured model of the axis (default: the suite's defaults).
    temperatures : sequence of float
        Environment plateaus [°C].
    profiles : sequence of str
        Any of :data:`~gimbal_friction.sim.config.PROFILES`.
    cases : sequence of str
        Any of :data:`CASES` and the optional ``feedforward_measured`` / ``feedforward_reference`` /
        ``dynamic_unguarded`` (default :data:`~gimbal_friction.sim.compensation.DEFAULT_CASES`: all but ``dynamic``).
    short : bool
        Use the short durations of :data:`SHORT_DURATIONS` and a shorter history and chamber test (CI).
    feedforward : FeedforwardSetup, optional
        The feedforward's settings and velocity source (default: the node's defaults). Cases ``constant`` and
        ``bound`` use the same smooth sign and velocity.
    estimator : EstimatorSettings, optional
        The estimator's settings for cases ``refit``, ``learned`` and ``chamber`` (default: the node's);
        ``commanded_speed_rad_s`` is replaced by the tracking speed, ``method`` by ``estimator_method`` for the
        refit, by ``observer`` for the learning and by :data:`CHAMBER_METHOD` for the chamber test.
    estimator_method : str
        ``observer`` (default: friction while the gimbal works), ``steady_state`` or ``both``.
    refit_fit : sequence of str
        Parameters refitted for case ``refit`` (default :data:`DEFAULT_REFIT_FIT`).
    refit_profiles : sequence of str, optional
        Kept for callers of earlier versions: the refit learns from the service history whatever this says.
    refit : callable, optional
        Replaces :func:`refit_rows` (rows, configured params) -> RefitResult or AxisParams.
    learn : LearnSetup, optional
        Correction and learning settings of cases ``learned`` and ``chamber`` (default :class:`LearnSetup`: the
        node's defaults, the rate raised).
    chamber : callable, optional
        Case ``chamber``'s chamber path (:data:`ChamberHook`; without it the case is left out with a note).
    progress : callable, optional
        ``progress(stage, fraction)``, fraction of the whole study done.

    Raises:
        ConfigError: an unknown case, profile, method or parameter, no temperature, or a temperature outside
            [-60, 120] °C.
    """
    axis = axis if axis is not None else AxisParams()
    ff = feedforward if feedforward is not None else FeedforwardSetup()
    lrn = learn if learn is not None else LearnSetup()
    lrn.correction.validate()
    lrn.learning.validate()
    if not (math.isfinite(lrn.duration_factor) and 0.25 <= lrn.duration_factor <= 1000.0):
        raise ConfigError('learn_duration_factor', 'must lie in [0.25, 1000] [-]', lrn.duration_factor)
    profiles = list(dict.fromkeys(profiles))
    cases = list(dict.fromkeys(cases))
    temps = _check(temperatures, profiles, cases, ff, estimator_method, refit_fit, refit_profiles)
    cfg = _short_config(config) if short else config
    est = estimator if estimator is not None else EstimatorSettings()
    est = dataclasses.replace(est, commanded_speed_rad_s=cfg.tracking_speed_rpm * RAD_S_PER_RPM)
    notes: list[str] = []
    wall: dict[str, float] = {}
    want_dynamic = 'dynamic' in cases or 'dynamic_unguarded' in cases
    want_refit, want_learned = 'refit' in cases, 'learned' in cases or want_dynamic
    want_chamber = CASE_CHAMBER in cases
    if want_chamber and chamber is None:
        notes.append('case chamber left out: no chamber path was given (run it through gimbal-friction loop-study)')
        cases = [c for c in cases if c != CASE_CHAMBER]
        want_chamber = False
    figure_profile = 'tracking' if 'tracking' in profiles else profiles[0]
    scale = SHORT_HISTORY_SCALE if short else 1.0
    passes = max(1, int(math.floor(lrn.duration_factor)))
    frac = lrn.duration_factor - passes
    history = history_profile(cfg, scale, passes) if frac < 1e-9 else history_profile(
        cfg, scale * lrn.duration_factor, 1)
    hist_s = float(history.time_s[-1]) + cfg.controller_period_s
    chamber_s = SHORT_CHAMBER_S if short else CHAMBER_S
    work = []
    if want_refit or want_learned:
        work.append(('learning', len(temps) * hist_s * (1 + 2 * int(want_learned))))
    if want_chamber:
        work.append(('chamber', len(temps) * chamber_s))
    work += [(p, len(cases) * len(temps) * cfg.profile_duration_s(p)) for p in profiles]
    total, done = float(sum(w for _, w in work)) or 1.0, 0.0
    weights = dict(work)
    records: list[dict[str, Any]] = []
    reversal: list[ReversalTrace] = []
    learned: dict[str, Correction] = {}
    learners: dict[str, Learner] = {}
    judges: dict[str, LoopJudge] = {}
    chamber_info: dict[str, Any] | None = None
    presliding: PreslidingTerm | None = None

    def reporter(label: str, base: float, w: float) -> Callable[[float], None]:
        def report(f: float) -> None:
            if progress is not None:
                progress(label, (base + f * w) / total)
        return report

    # stage 1: the service history (another seed, other motions)
    outcome: RefitOutcome | None = None
    refit_params: AxisParams | None = None
    if want_refit or want_learned:
        t0 = time.perf_counter()
        label = 'service history (learning)'
        result, learner, judge = _learning_batch(cfg, axis, ff, history, temps, lrn, est, want_learned,
                                                 reporter(label, done, weights['learning']))
        done += weights['learning']
        ff_runs = [i for i, r in enumerate(result.runs) if r.case == 'feedforward']
        if learner is not None:
            learners['history'] = learner
            learned['history'] = learner.snapshot()
            for i, rec in enumerate(_records(result, hist_s)):
                if rec['case'] != 'learned':
                    continue
                ref = next(j for j in ff_runs if result.runs[j].temperature_c == rec['temperature_c'])
                rec['case'] = 'learning'
                rec['learning_worst_window_ratio'] = window_ratio(result, i, ref)
                records.append(rec)
            summ = learner.summary()
            periods = ', '.join(f'{q["period_deg"]:.3g} deg (z {q["z"]:.0f})' for q in
                                summ['joints'][JOINT]['periods']) or 'none'
            notes.append(f'learned (one correction, service history of {hist_s:.0f} s at every plateau): '
                         f'{summ["accepted"]} samples in {summ["cells_with_data"]} cells, {summ["cells_applied"]} '
                         f'applied, {summ["cells_held_back"]} held back by the guard (refused: '
                         f'{", ".join(f"{k} {v}" for k, v in sorted(summ["rejected"].items())) or "none"}); '
                         f'ripple periods found: {periods}; largest |correction| '
                         f'{summ["max_abs_correction_nm"] * 1e3:.3f} N*mm, largest direction-independent torque '
                         f'{summ["max_abs_unbalance_nm"] * 1e3:.3f} N*mm, {summ["saturated_cells"]} saturated cells')
            if judge is not None:
                judges['history'] = judge
                js = judge.summary()
                verdicts = '; '.join(f'{c["direction"]} {c["centre_c"]:+.1f} degC {c["state"]} (x{c["ratio"]:.3f}, '
                                     f'z {c["z"]:.1f}, {c["blocks_on"]}/{c["blocks_off"]} blocks on/off)'
                                     for c in js['joints'][JOINT])
                notes.append(f'learned: judged by the loop (blocks of {judge.settings.block_s:g} s, '
                             f'{js["on_share"]:.2f} of them on while testing): {js["cells_applied"]} cells applied, '
                             f'{js["cells_withdrawn"]} withdrawn, {js["cells_testing"]} still in test; '
                             f'{verdicts or "no cell tested"}')
            else:
                notes.append('learned: not judged by the loop (the residual guard alone)')
        wall[label] = time.perf_counter() - t0
        if want_dynamic and learner is not None:
            t1 = time.perf_counter()
            if progress is not None:
                progress('dynamic: pre-sliding identification', done / total)
            presliding = _learn_presliding(result, axis, ff, learned['history'], est, notes)
            wall['dynamic: pre-sliding identification'] = time.perf_counter() - t1
        if want_refit:
            t1 = time.perf_counter()
            if progress is not None:
                progress('refit: estimator -> residual rows -> refit', done / total)
            outcome = _refit([(result, ff_runs)], axis, cfg, est, estimator_method, refit_fit, refit, notes)
            refit_params = outcome.params
            wall['refit'] = time.perf_counter() - t1
        del result
    # stage 1b: the chamber test and its chamber path
    if want_chamber and chamber is not None:
        t0 = time.perf_counter()
        label = 'chamber test (learning)'
        arrays = _chamber_batch(cfg, axis, temps, short, reporter(label, done, weights['chamber']))
        done += weights['chamber']
        c_est = dataclasses.replace(est, method=CHAMBER_METHOD)
        corr, chamber_info = chamber(arrays, axis, c_est, lrn.correction)
        learned['chamber'] = corr
        summ = corr.summary()
        notes.append(f'chamber (the correction of a {chamber_s:.0f} s chamber test per plateau alone): '
                     f'{summ["samples"]} samples in {summ["cells_with_data"]} cells, {summ["cells_applied"]} applied, '
                     f'{summ["cells_held_back"]} held back by the guard; ripple periods found: '
                     f'{len(summ["joints"][JOINT]["periods"])}')
        wall[label] = time.perf_counter() - t0
    # stage 2: every case scored on seed 0 over [0, duration]
    for name in profiles:
        t0 = time.perf_counter()
        prof = make_profile(cfg, name)
        comps: dict[str, Compensator] = {}
        stage_cases = [c for c in cases if not (c == 'refit' and refit_params is None)]
        for c in stage_cases:
            if c == 'constant':
                comps[c] = constant_coulomb(axis, ff.settings, velocity_source=ff.velocity_source)
            elif c == 'feedforward':
                comps[c] = ff.compensator(axis)
            elif c == 'feedforward_measured':
                comps[c] = ff.compensator(axis, 'measured')
            elif c == 'feedforward_reference':
                comps[c] = ff.compensator(axis, 'reference')
            elif c == 'refit' and refit_params is not None:
                comps[c] = ff.compensator(refit_params)
            elif c == 'learned':
                comps[c] = ff.compensator(axis, correction=learned['history'])
                if 'history' in judges:    # the cells the loop applied only (frozen)
                    comps[c] = judged_compensator(ff.compensator(axis), comps[c], judges['history'])
            elif c in ('dynamic', 'dynamic_unguarded') and (c == 'dynamic' or presliding is not None):
                term = presliding if c == 'dynamic' or presliding is None else presliding.unguarded()
                comps[c] = dynamic_feedforward(axis, ff.settings, velocity_source=ff.velocity_source,
                                               correction=learned['history'], presliding=term)
                if 'history' in judges:    # the learned cells the loop applied only, as case learned
                    plain = dynamic_feedforward(axis, ff.settings, velocity_source=ff.velocity_source, presliding=term)
                    comps[c] = judged_compensator(plain, comps[c], judges['history'])
            elif c == CASE_CHAMBER:
                comps[c] = ff.compensator(axis, correction=learned['chamber'])
            elif c == 'bound':
                comps[c] = truth_bound(cfg, ff.settings, velocity_source=ff.velocity_source)
        runs = [Run(c, t) for c in stage_cases for t in temps]
        label = f'{name} ({", ".join(stage_cases)})'
        result = simulate(cfg, axis, prof, runs, comps, progress=reporter(label, done, weights[name]))
        done += weights[name]
        records.extend(_records(result, cfg.profile_duration_s(name)))
        if name == figure_profile:
            reversal.extend(_reversal_traces(result, min(temps)))
        wall[label] = time.perf_counter() - t0
    if progress is not None:
        progress('done', 1.0)
    order = {c: i for i, c in enumerate(REPORT_ORDER)}
    prof_order = {p: i for i, p in enumerate([*profiles, 'history'])}
    records.sort(key=lambda r: (prof_order.get(r['profile'], 99), order[r['case']], r['temperature_c']))
    reversal.sort(key=lambda t: order[t.case])
    return StudyResult(records, reversal, outcome, notes, wall, cfg, learned or None, learners or None, chamber_info,
                       presliding, judges or None)


def _learn_presliding(result: BatchResult, axis: AxisParams, ff: FeedforwardSetup, correction: Correction,
                      estimator: EstimatorSettings, notes: list[str]) -> PreslidingTerm:
    """Case ``dynamic``'s pre-sliding term, identified and guarded from the learning runs of case ``learned`` (the
    service history, seed :data:`LEARN_SEED`) with the learned correction's level (:func:`presliding_runs`)."""
    cfg = result.config
    settings = PreslidingSettings(velocity_threshold_rad_s=ff.settings.velocity_threshold_rad_s,
                                  delivery_delay_s=cfg.latency_ticks * cfg.controller_period_s)
    term = PreslidingTerm(settings, (JOINT,))
    runs = [i for i, r in enumerate(result.runs) if r.case == 'learned']
    counts = term.learn(JOINT, presliding_runs(result, runs, axis, ff, correction, estimator))
    verdicts = term.verdicts(JOINT)
    shown = '; '.join(f"{v['centre_c']:+g} degC {v['distance_rad'] * 1e6:.1f} urad "
                      f"({'applied' if v['applied'] else 'off: ' + v['held_back']}, z {v['z']:.1f}, "
                      f"{v['reversals_scored']} reversals)" for v in verdicts) or 'no data'
    notes.append(f"dynamic (pre-sliding term from the service history): {counts['samples']} samples near "
                 f"{counts['reversals']} reversals; {shown}")
    return term


def _refit(calibration: Sequence[tuple[BatchResult, Sequence[int]]], axis: AxisParams, cfg: SimConfig,
           estimator: EstimatorSettings | None, method: str, fit: Sequence[str], hook: RefitHook | None,
           notes: list[str]) -> RefitOutcome:
    base = estimator if estimator is not None else EstimatorSettings()
    settings = dataclasses.replace(base, method=method,
                                   commanded_speed_rad_s=cfg.tracking_speed_rpm * RAD_S_PER_RPM)
    measured, rows, counters = estimator_rows(calibration, axis, settings)
    n_obs = int(np.count_nonzero(measured.method == METHOD_OBSERVER))
    n_ss = int(np.count_nonzero(measured.method == METHOD_STEADY_STATE))
    runs = sum(len(i) for _, i in calibration)
    notes.append(f'refit data: estimator ({method}) on the feedforward runs of the learning windows '
                 f'(seed {LEARN_SEED}; {runs} runs of '
                 f'{", ".join(dict.fromkeys(b.profile.name for b, _ in calibration))}): {len(rows)} residual rows '
                 f'({n_obs} observer, {n_ss} steady-state)')
    result: RefitResult | None = None
    try:
        out = hook(rows, axis) if hook is not None else refit_rows(rows, axis, fit)
    except GimbalFrictionError as err:
        notes.append(f'case refit left out: the refit was refused ({err})')
        return RefitOutcome(measured, rows, counters, None, None, str(err))
    if isinstance(out, RefitResult):
        result, params = out, out.params
        held = [f'{k} ({v.reason})' for k, v in out.identifiability.items() if not v.identifiable]
        if held:
            notes.append('refit held at the configured value: ' + '; '.join(held))
        if out.offset.estimated:
            notes.append(f'refit calibration offset {out.offset.value_nm * 1e3:+.4f} N*mm (not in the feedforward)')
    else:
        params = out
    changed = {k: v for k, v in params.to_mapping().items() if axis.to_mapping()[k] != v}
    notes.append('refit: ' + (', '.join(f'{k} {getattr(axis, k):.6g} -> {v:.6g}' for k, v in changed.items())
                              or 'nothing changed'))
    return RefitOutcome(measured, rows, counters, result, params, None)


# ---------------------------------------------------------------------------------------------- goals
def _lookup(records: Sequence[dict[str, Any]]) -> dict[tuple[str, str, float], dict[str, Any]]:
    return {(r['profile'], r['case'], float(r['temperature_c'])): r for r in records}


#: Goals on the learned corrections (name, what): evaluated by :func:`goal_checks`.
LEARNING_GOALS = {
    'learned_vs_constant': 'learned <= 1.02 x constant (2 % noise)',
    'learned_vs_ff': 'learned <= 1.05 x the plain feedforward',
    'learned_vs_bound': 'learned <= 1.5 x bound',
    'learned_vs_none_cold': 'learned/none <= 0.4 at -40 and -20 degC where bound/none <= 0.25',
    'learning_cost': 'while learning never more than 5 % worse than the plain feedforward over any 10 s window',
    'chamber_vs_ff': 'chamber <= 1.05 x the plain feedforward',
    'chamber_vs_constant': 'chamber <= 1.02 x constant (2 % noise)',
    'ff_vs_constant': 'feedforward <= 1.05 x constant',
    'refit_vs_ff': 'refit (out of sample) <= feedforward',
    'dynamic_vs_learned': 'dynamic <= 1.05 x learned (never worse than what it extends)',
    'dynamic_vs_bound_cold': 'dynamic <= 0.7 x bound at -40 and -20 degC where ideal <= 0.5 x bound',
    'dynamic_reversal_cold': "dynamic reversal peak <= 0.7 x bound's at -40 and -20 degC where ideal <= 0.5 x bound",
}


#: The study's goals on the compensation cases (name, what): evaluated by :func:`goal_checks` (and
#: ``d_share_of_ideal_cold`` by :func:`gimbal_friction.runs.loop_study.study_document`). The letters are the cases:
#: (a) none, (b) constant, (c) feedforward, (d) refit, (e) ideal.
STUDY_GOALS = {
    'c_vs_a_cold': 'feedforward cuts the LOS rate error RMS of none by >= 60 % at -40 and -20 degC',
    'c_vs_a_all': 'feedforward cuts the LOS rate error RMS of none by >= 30 % at every plateau',
    'c_vs_b_cold': 'feedforward cuts the LOS rate error RMS of constant by >= 30 % at -40 degC',
    'd_near_e_cold': 'refit <= 1.2 x ideal at -40 degC',
    'c_reversal': 'feedforward peak error at reversals <= none',
    'd_share_of_ideal_cold': 'refit reaches >= 80 % of the improvement of ideal over none at -40 degC',
}


def goal_legend(names: Sequence[str]) -> list[str]:
    """One line per goal name in ``names`` (first appearance order) saying what it checks (:data:`STUDY_GOALS`,
    :data:`LEARNING_GOALS`).

    >>> goal_legend(['d_near_e_cold', 'd_near_e_cold'])
    ['  d_near_e_cold: refit <= 1.2 x ideal at -40 degC']
    """
    goals = STUDY_GOALS | LEARNING_GOALS
    return [f'  {n}: {goals.get(n, "(no description)")}' for n in dict.fromkeys(names)]


def goal_checks(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The study's goals evaluated on study records, per profile and plateau (those the records allow).

    - ``c_vs_a_cold``: (c) cuts the LOS rate error RMS by ≥ 60 % vs (a) at −40 and −20 °C;
    - ``c_vs_a_all``: by ≥ 30 % at every plateau;
    - ``c_vs_b_cold``: by ≥ 30 % vs (b) at −40 °C;
    - ``d_near_e_cold``: (d) within 20 % of (e) at −40 °C (RMS(d) ≤ 1.2 RMS(e));
    - ``c_reversal``: the peak error at reversals of (c) no worse than (a), at every plateau;
    - the learning goals (:data:`LEARNING_GOALS`, value = the ratio, target its limit): ``learned_vs_constant``
      (≤ 1), ``learned_vs_bound`` (learned/bound ≤ 1.5), ``learned_vs_none_cold`` (≤ 0.4 at −40 and −20 °C where
      bound/none ≤ 0.25), ``learning_cost`` (the learning run's worst 10 s window / the plain feedforward's ≤ 1.05),
      ``ff_vs_constant`` (≤ 1.05), ``refit_vs_ff`` (≤ 1);
    - the pre-sliding goals: ``dynamic_vs_learned`` (dynamic/learned ≤ 1.05), ``dynamic_vs_bound_cold`` (dynamic/bound
      ≤ 0.7 at −40 and −20 °C where ideal/bound ≤ 0.5) and ``dynamic_reversal_cold`` (the same cells, reversal peak
      over bound's ≤ 0.7).

    Each check: ``goal``, ``profile``, ``temperature_c``, ``value`` (the reduction [-] or the ratio), ``target``,
    ``met``.
    """
    look = _lookup(records)
    out: list[dict[str, Any]] = []

    def rms(p: str, c: str, t: float) -> float | None:
        r = look.get((p, c, t))
        return None if r is None else float(r['rate_error_rms_rad_s'])

    def ratio_goal(goal: str, p: str, t: float, num: float | None, den: float | None, target: float) -> None:
        if num is not None and den is not None and den > 0.0:
            out.append({'goal': goal, 'profile': p, 'temperature_c': t, 'value': num / den, 'target': target,
                        'met': num / den <= target})

    for p in dict.fromkeys(r['profile'] for r in records):
        temps = sorted({float(r['temperature_c']) for r in records if r['profile'] == p})
        for t in temps:
            a, b, c = rms(p, 'none', t), rms(p, 'constant', t), rms(p, 'feedforward', t)
            d, e = rms(p, 'refit', t), rms(p, 'ideal', t)
            if a is not None and c is not None:
                cut = 1.0 - c / a
                if t in (-40.0, -20.0):
                    out.append({'goal': 'c_vs_a_cold', 'profile': p, 'temperature_c': t, 'value': cut,
                                'target': 0.6, 'met': cut >= 0.6})
                out.append({'goal': 'c_vs_a_all', 'profile': p, 'temperature_c': t, 'value': cut, 'target': 0.3,
                            'met': cut >= 0.3})
                ra = look[(p, 'none', t)]['reversal_error_peak_rad']
                rc = look[(p, 'feedforward', t)]['reversal_error_peak_rad']
                if not (math.isnan(ra) or math.isnan(rc)):
                    out.append({'goal': 'c_reversal', 'profile': p, 'temperature_c': t, 'value': rc / ra,
                                'target': 1.0, 'met': rc <= ra})
            if t == -40.0 and b is not None and c is not None:
                cut = 1.0 - c / b
                out.append({'goal': 'c_vs_b_cold', 'profile': p, 'temperature_c': t, 'value': cut, 'target': 0.3,
                            'met': cut >= 0.3})
            if t == -40.0 and d is not None and e is not None:
                ratio = d / e
                out.append({'goal': 'd_near_e_cold', 'profile': p, 'temperature_c': t, 'value': ratio,
                            'target': 1.2, 'met': ratio <= 1.2})
            le, bd, ch = rms(p, 'learned', t), rms(p, 'bound', t), rms(p, 'chamber', t)
            ratio_goal('learned_vs_constant', p, t, le, b, 1.02)
            ratio_goal('learned_vs_ff', p, t, le, c, 1.05)
            ratio_goal('learned_vs_bound', p, t, le, bd, 1.5)
            if t in (-40.0, -20.0) and a is not None and bd is not None and bd / a <= 0.25:
                ratio_goal('learned_vs_none_cold', p, t, le, a, 0.4)
            lr = look.get((p, 'learning', t))
            if lr is not None and lr.get('learning_worst_window_ratio') is not None:
                ratio_goal('learning_cost', p, t, float(lr['learning_worst_window_ratio']), 1.0, 1.05)
            ratio_goal('chamber_vs_ff', p, t, ch, c, 1.05)
            ratio_goal('chamber_vs_constant', p, t, ch, b, 1.02)
            ratio_goal('ff_vs_constant', p, t, c, b, 1.05)
            ratio_goal('refit_vs_ff', p, t, d, c, 1.0)
            dy = rms(p, 'dynamic', t)
            ratio_goal('dynamic_vs_learned', p, t, dy, le, 1.05)
            if t in (-40.0, -20.0) and bd is not None and e is not None and e <= 0.5 * bd:
                ratio_goal('dynamic_vs_bound_cold', p, t, dy, bd, 0.7)
                if dy is not None:
                    ratio_goal('dynamic_reversal_cold', p, t, float(look[(p, 'dynamic', t)]['reversal_error_peak_rad']),
                               float(look[(p, 'bound', t)]['reversal_error_peak_rad']), 0.7)
    return out


#: Truth terms the study can switch off to name the one responsible for a missed goal: name -> changes of the
#: simulator's configuration (``lubricant``: the truth's lubricant set to the configured model's).
TRUTH_TERMS = ('asymmetry', 'ripple', 'lubricant', 'breakaway', 'sensor', 'disturbance')
#: Goals whose misses :func:`explain_misses` attributes, and the cases each needs.
_GOAL_CASES = {'learned_vs_constant': ('constant', 'learned'), 'learned_vs_bound': ('learned', 'bound'),
               'learned_vs_ff': ('feedforward', 'learned'), 'chamber_vs_ff': ('feedforward', 'chamber'),
               'chamber_vs_constant': ('constant', 'chamber'),
               'learned_vs_none_cold': ('none', 'learned', 'bound'), 'ff_vs_constant': ('constant', 'feedforward'),
               'refit_vs_ff': ('feedforward', 'refit'), 'learning_cost': ('feedforward', 'learned')}


def term_off(config: SimConfig, axis: AxisParams, term: str) -> SimConfig | None:
    """``config`` with truth term ``term`` (:data:`TRUTH_TERMS`) switched off, or None if it is already off."""
    if term == 'asymmetry':
        changes: dict[str, Any] = {'asymmetry_enabled': False}
    elif term == 'ripple':
        changes = {'ripple_amplitudes': tuple(0.0 for _ in config.ripple_amplitudes)}
    elif term == 'lubricant':
        changes = {'truth_walther_a': axis.walther_a, 'truth_walther_b': axis.walther_b,
                   'lubricant_walther_a_shift': 0.0, 'truth_palmgren_factor': axis.palmgren_factor}
    elif term == 'breakaway':
        changes = {'breakaway_ratio': 1.0}
    elif term == 'sensor':
        changes = {'temperature_bias_c': 0.0, 'temperature_sensor_time_constant_s': 0.0}
    elif term == 'disturbance':
        changes = {'disturbance_torque_nm': 0.0, 'unbalance_torque_nm': 0.0}
    else:
        raise ConfigError('term', f'unknown truth term (choose from {", ".join(TRUTH_TERMS)})', term)
    new = config.replace(**changes)
    return None if new == config else new


def explain_misses(config: SimConfig, axis: AxisParams, goals: Sequence[dict[str, Any]], **study: Any
                   ) -> list[dict[str, Any]]:
    """For every missed learning goal (:data:`LEARNING_GOALS`), the truth term responsible: the cell (profile,
    plateau) is run again (``short`` durations, only the cases the goal needs) with each active truth term of
    :data:`TRUTH_TERMS` switched off in turn (:func:`term_off`), and once with every term on (the reference at the
    same short durations: the full run's value is not comparable); the term whose removal brings the goal's value
    down most below that reference is named. ``study``: further arguments of :func:`run_study` (feedforward,
    estimator, learn).

    Returns one record per missed goal: ``goal``, ``profile``, ``temperature_c``, ``value`` (the full run's),
    ``value_short`` (every term on, short durations), ``responsible`` (the term, or None if no removal helps),
    ``value_without`` (term -> the goal's value with that term off, short durations).
    """
    missed = [g for g in goals if not g['met'] and g['goal'] in _GOAL_CASES]
    out = []
    cells: dict[str, set[float]] = {}
    needs: dict[str, set[str]] = {}
    for g in missed:
        cells.setdefault(g['profile'], set()).add(g['temperature_c'])
        needs.setdefault(g['profile'], set()).update(_GOAL_CASES[g['goal']])
    without: dict[tuple[str, str, float, str], float] = {}
    for p, temps in cells.items():
        cases = [c for c in REPORT_ORDER if c in needs[p]]
        for term in (None, *TRUTH_TERMS):   # None: every term on, the reference
            cfg = config if term is None else term_off(config, axis, term)
            if cfg is None:
                continue
            run_profiles = [p] if p in PROFILES else [PROFILES[0]]   # (the learning run: profile 'history')
            res = run_study(cfg, axis, temperatures=sorted(temps), profiles=run_profiles, cases=cases, short=True,
                            **study)
            for g in goal_checks(res.records):
                without[(g['goal'], p, g['temperature_c'], term or '')] = g['value']
    for g in missed:
        vals = {term: without[(g['goal'], g['profile'], g['temperature_c'], term)] for term in TRUTH_TERMS
                if (g['goal'], g['profile'], g['temperature_c'], term) in without}
        reference = without.get((g['goal'], g['profile'], g['temperature_c'], ''), g['value'])
        best = min(vals, key=lambda k: vals[k]) if vals else None
        responsible = best if best is not None and vals[best] < reference else None
        out.append({'goal': g['goal'], 'profile': g['profile'], 'temperature_c': g['temperature_c'],
                    'value': g['value'], 'value_short': reference, 'responsible': responsible,
                    'value_without': vals})
    return out
