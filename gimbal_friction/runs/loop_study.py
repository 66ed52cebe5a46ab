"""The closed-loop study as a user runs it (``gimbal-friction loop-study``): inputs from the parameter files, the
study (:func:`gimbal_friction.sim.study.run_study`), and its outputs — one JSON document, a table, figures and the
residual log case (d) was refitted from.

Inputs, layered like every tool (``--config`` files over the packaged defaults, key by key):

- the axis (``model.*`` / ``axis.<joint>.*``; J = ``inertia_kg_m2``), the feedforward's settings and
  ``velocity_source`` and the estimator's settings from the ``/**`` section (what the nodes read);
- the simulator from each file's ``gimbal_sim`` section (``config/gimbal_sim.yaml``; defaults in
  :class:`~gimbal_friction.sim.config.SimConfig`).

Outputs in ``--out DIR``:

- ``loop_study.json``: the document :func:`study_document` (also ``--format json`` on stdout): ``records`` (one
  per case × temperature × profile, docs/cli.md fields), ``goals`` (the study's goals), ``refit``, ``notes``,
  ``settings``, ``wall_s`` and, with ``--live``, ``live``;
- ``loop_study.txt``: the table of :func:`table_text`;
- ``figures/error_vs_temperature_<profile>.png`` (LOS rate and position error RMS per case vs temperature) and
  ``figures/reversal_trace.png`` (the coldest plateau around the first reversal);
- ``residuals/``: the residual log the estimator collected for case (d) (measured, measured_detail, residual and
  residual_detail, standard types, as residual_logger writes them): ``gimbal-friction refit OUT/residuals`` reads
  it and finds case (d)'s parameters again.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.settings import settings_from_parameters
from gimbal_friction.config.loader import axis_names, axis_params, load_parameters, read_yaml
from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.compensation import DEFAULT_CASES
from gimbal_friction.sim.config import SECTION, SimConfig, truth_differences, with_truth
from gimbal_friction.sim.study import (
    DEFAULT_REFIT_FIT,
    DEFAULT_TEMPERATURES,
    LEARNING_GOALS,
    REPORT_ORDER,
    FeedforwardSetup,
    LearnSetup,
    StudyResult,
    explain_misses,
    goal_checks,
    goal_legend,
    run_study,
    study_settings,
)
from gimbal_friction.streams.measurement import MeasurementArrays, detail_matrix
from gimbal_friction.streams.residual_row import ResidualRows

__all__ = ['RECORD_FIELDS', 'STUDY_FILE', 'TABLE_FILE', 'StudyInputs', 'figures', 'load_study_inputs', 'study',
           'study_document', 'table_text', 'write_outputs', 'write_residual_log']

STUDY_FILE = 'loop_study.json'
TABLE_FILE = 'loop_study.txt'
#: Fields of every record (docs/cli.md ``loop-study`` JSON plus the current margin and the mode).
RECORD_FIELDS = ('case', 'temperature_c', 'profile', 'rate_error_rms_rad_s', 'rate_error_peak_rad_s',
                 'position_error_rms_rad', 'position_error_peak_rad', 'reversal_error_peak_rad', 'current_margin',
                 'duration_s', 'mode', 'learning_worst_window_ratio')
#: Velocity sources the study accepts from the parameter files (``auto`` = reference when fresh, else measured; the
#: simulated reference is always fresh).


class StudyInputs(NamedTuple):
    """What the study runs with, from the parameter files."""

    sim: SimConfig
    axis_name: str
    axis: AxisParams
    feedforward: FeedforwardSetup
    estimator: EstimatorSettings


def _sim_config(paths: Sequence[str | Path]) -> SimConfig:
    cfg = SimConfig()
    for path in paths:
        data = read_yaml(path)
        if SECTION in data or '/' + SECTION in data:
            try:
                cfg = SimConfig.from_mapping(data, base=cfg)
            except ConfigError as err:
                raise ConfigError(f'{path}: {SECTION}.{err.parameter}', err.rule, err.value) from None
    return cfg


def load_study_inputs(config_paths: Sequence[str | Path] = (), axis: str | None = None, *,
                      latency_s: float | None = None, seed: int | None = None,
                      truth_path: str | Path | None = None) -> StudyInputs:
    """The study's inputs from the packaged defaults and ``config_paths`` (layered in order).

    ``latency_s`` [s] overrides ``feedforward_latency_s``, ``seed`` the simulator's noise seed; ``truth_path`` is a
    YAML file of truth parameters (:data:`~gimbal_friction.sim.config.TRUTH_PARAMETERS`, flat or in a
    ``gimbal_sim`` section) layered over the simulator's configuration. The truth never reads the configured model
    (``model.*``, ``axis.<joint>.*``): a wrong configuration costs, it does not move the truth.

    Raises:
        ConfigError: an unreadable file, an unknown axis, or a value that breaks a rule (named).
    """
    params = load_parameters(config_paths)
    name = axis if axis is not None else axis_names(params)[0]
    ax = axis_params(params, name)
    ff_settings = settings_from_parameters(FeedforwardSettings, params)
    source = ff_settings.velocity_source
    est = settings_from_parameters(EstimatorSettings, params)
    sim = _sim_config(config_paths)
    if truth_path is not None:
        data = read_yaml(truth_path)   # an unreadable file is named as a file
        try:
            sim = with_truth(sim, data)
        except ConfigError as err:
            raise ConfigError(f'{truth_path}: {err.parameter}', err.rule, err.value) from None
    if latency_s is not None:
        sim = sim.replace(feedforward_latency_s=latency_s)
    if seed is not None:
        sim = sim.replace(seed=seed)
    return StudyInputs(sim, name, ax, FeedforwardSetup(ff_settings, source),
                       est)


def study(inputs: StudyInputs, *, temperatures: Sequence[float] = DEFAULT_TEMPERATURES,
          profiles: Sequence[str] | None = None, cases: Sequence[str] = DEFAULT_CASES, short: bool = False,
          estimator_method: str = 'observer', refit_fit: Sequence[str] = DEFAULT_REFIT_FIT,
          learn: LearnSetup | None = None, progress: Callable[[str, float], None] | None = None) -> StudyResult:
    """:func:`~gimbal_friction.sim.study.run_study` with the inputs of the parameter files."""
    from gimbal_friction.chamber.learned import chamber_correction
    from gimbal_friction.sim.config import PROFILES
    return run_study(inputs.sim, inputs.axis, temperatures=temperatures,
                     profiles=PROFILES if profiles is None else profiles, cases=cases, short=short,
                     feedforward=inputs.feedforward, estimator=inputs.estimator, estimator_method=estimator_method,
                     refit_fit=refit_fit, learn=learn, chamber=_chamber_hook(inputs, chamber_correction),
                     progress=progress)


def _chamber_hook(inputs: StudyInputs, chamber_correction: Callable[..., Any]) -> Callable[..., Any]:
    """Case ``chamber``'s chamber path with the configured joint name and feedforward settings."""
    def hook(streams: Any, axis: AxisParams, estimator: EstimatorSettings, settings: Any) -> Any:
        return chamber_correction(streams, axis, estimator, settings, joint='elevation',
                                  feedforward=inputs.feedforward.settings)
    return hook


def explain(result: StudyResult, inputs: StudyInputs, goals: Sequence[dict[str, Any]], *,
            learn: LearnSetup | None = None) -> list[dict[str, Any]]:
    """The truth term responsible for each missed learning goal
    (:func:`~gimbal_friction.sim.study.explain_misses`, short durations)."""
    from gimbal_friction.chamber.learned import chamber_correction
    return explain_misses(result.config, inputs.axis, goals, feedforward=inputs.feedforward,
                          estimator=inputs.estimator, learn=learn, chamber=_chamber_hook(inputs, chamber_correction))


def _number(x: Any) -> Any:
    if isinstance(x, (np.floating, np.integer)):
        x = x.item()
    return x


def study_document(result: StudyResult, inputs: StudyInputs, *, live: dict[str, Any] | None = None,
                   explained: list[dict[str, Any]] | None = None, goals: list[dict[str, Any]] | None = None,
                   learn: LearnSetup | None = None) -> dict[str, Any]:
    """The JSON document of a study (non-finite numbers are written as null by the CLI).

    ``records``: one per case × temperature × profile with :data:`RECORD_FIELDS` (``mode`` ``offline``; with
    ``live`` also the live runs, ``mode`` ``live``, with ``feedforward_latency_p50_s``); ``goals``:
    :func:`~gimbal_friction.sim.study.goal_checks` plus, per profile at −40 °C, the share of the ideal improvement
    case (d) reaches; ``refit``: what case (d) was built from.
    """
    records = [{k: _number(r[k]) for k in RECORD_FIELDS if k in r} | {'mode': 'offline'} for r in result.records]
    live_records = [] if live is None else list(live.get('records', []))
    goals = list(goals) if goals is not None else goal_checks(result.records)
    look = {(r['profile'], r['case'], r['temperature_c']): r['rate_error_rms_rad_s'] for r in result.records}
    for p in dict.fromkeys(r['profile'] for r in result.records):
        a, d, e = (look.get((p, c, -40.0)) for c in ('none', 'refit', 'ideal'))
        if a is not None and d is not None and e is not None and a > e:
            share = (a - d) / (a - e)
            goals.append({'goal': 'd_share_of_ideal_cold', 'profile': p, 'temperature_c': -40.0, 'value': share,
                          'target': 0.8, 'met': share >= 0.8})
    refit: dict[str, Any] | None = None
    if result.refit is not None:
        r = result.refit
        refit = {'rows': len(r.rows), 'accepted_by_method': {
            'steady_state': int(np.count_nonzero(r.measurements.method == 0)),
            'observer': int(np.count_nonzero(r.measurements.method == 1))},
            'estimator_rejected': r.counters.get('rejected', {}), 'error': r.error}
        if r.result is not None:
            refit.update({'fitted': r.result.fitted, 'base': r.result.base,
                          'identifiable': {k: v.identifiable for k, v in r.result.identifiability.items()},
                          'standard_errors': r.result.standard_errors, 'rms_before_nm': r.result.rms_before_nm,
                          'rms_after_nm': r.result.rms_after_nm, 'offset_nm': r.result.offset.value_nm})
        elif r.params is not None:
            refit['params'] = {k: v for k, v in r.params.to_mapping().items()
                               if v != inputs.axis.to_mapping()[k]}
    doc: dict[str, Any] = {
        'records': records + live_records,
        'goals': goals,
        'refit': refit,
        'explained': explained,
        'learned': {p: c.summary() for p, c in (result.learned or {}).items()},
        'judge': {p: j.summary() for p, j in (result.judges or {}).items()},   # case learned: the loop's verdicts
        'chamber': result.chamber,
        'notes': list(result.notes),
        'settings': {'axis': inputs.axis_name, 'velocity_source': inputs.feedforward.velocity_source,
                     'velocity_threshold_rad_s': inputs.feedforward.settings.velocity_threshold_rad_s,
                     'feedforward_latency_s': result.config.feedforward_latency_s,
                     'controller_hz': result.config.rate_loop_hz, 'seed': result.config.seed,
                     'truth_differs_from_default': truth_differences(result.config),
                     **study_settings(learn if learn is not None else LearnSetup()),
                     'durations_s': {p: result.config.profile_duration_s(p) for p in
                                     dict.fromkeys(r['profile'] for r in result.records) if p != 'history'}},
        'wall_s': {k: round(v, 3) for k, v in result.wall_s.items()},
    }
    if live is not None:
        doc['live'] = {k: v for k, v in live.items() if k != 'records'}
    return doc


def _fmt(x: Any, scale: float, digits: int = 3) -> str:
    return '-' if x is None or (isinstance(x, float) and not math.isfinite(x)) else f'{x * scale:.{digits}f}'


#: Title of the learning run's table (:func:`table_text`): it is not a scored case.
LEARNING_RUN_TITLE = ('learning run (not a scored case: case learned while it learns, on the service history, another '
                      'seed and motions whose slews dominate its RMS; judged only by learning_cost): LOS rate error '
                      'RMS [mrad/s] (peak position error at reversals [mrad])')


def _case_table(records: list[dict[str, Any]], temps: list[float], order: dict[str, int]) -> str:
    """One row per case (report order), one column per temperature: RMS rate error (reversal peak)."""
    from gimbal_friction.common.text import format_table
    rows = []
    for c in sorted({r['case'] for r in records}, key=lambda c: order.get(c, 99)):
        by_t = {r['temperature_c']: r for r in records if r['case'] == c}
        cells = [f'{_fmt(by_t[t]["rate_error_rms_rad_s"], 1e3)} '
                 f'({_fmt(by_t[t]["reversal_error_peak_rad"], 1e3, 2)})' if t in by_t else '' for t in temps]
        rows.append([c, *cells])
    return format_table(rows, ['case'] + [f'{t:+g} degC' for t in temps])


def table_text(doc: dict[str, Any]) -> str:
    """The study as text: per profile, the LOS rate error RMS [mrad/s] with the reversal peak [mrad] per case and
    temperature; the goals not met; the refit; live vs offline; notes."""
    from gimbal_friction.common.text import format_table
    records = doc['records']
    out: list[str] = []
    offline = [r for r in records if r.get('mode', 'offline') == 'offline']
    temps = sorted({r['temperature_c'] for r in offline})
    order = {c: i for i, c in enumerate(REPORT_ORDER)}
    scored = [r for r in offline if r['case'] != 'learning']
    learning = [r for r in offline if r['case'] == 'learning']
    for p in dict.fromkeys(r['profile'] for r in scored):
        out.append(f'{p}: LOS rate error RMS [mrad/s] (peak position error at reversals [mrad])')
        out.append(_case_table([r for r in scored if r['profile'] == p], temps, order))
        out.append('')
    if learning:   # the learning run is not a scored case: its own table, said so
        out.append(LEARNING_RUN_TITLE)
        out.append(_case_table(learning, temps, order))
        out.append('')
    missed = [g for g in doc['goals'] if not g['met']]
    met = len(doc['goals']) - len(missed)
    out.append('study goals (feedforward vs none, vs constant, refit vs ideal, reversals; learning goals): '
               f'{met} of {len(doc["goals"])} met')
    for goal, what in LEARNING_GOALS.items():
        mine = [g for g in doc['goals'] if g['goal'] == goal]
        if mine:
            out.append(f'  {goal} ({what}): {sum(g["met"] for g in mine)} of {len(mine)} cells met, worst '
                       f'{max(g["value"] for g in mine):.3f}')
    why = {(e['goal'], e['profile'], e['temperature_c']): e for e in doc.get('explained') or []}
    for g in missed:
        e = why.get((g['goal'], g['profile'], g['temperature_c']))
        reason = ''
        if e is not None:
            short = e['value_short']
            reason = (f'; responsible: {e["responsible"]} ({short:.3f} -> '
                      f'{e["value_without"][e["responsible"]]:.3f} without it, short runs)' if e['responsible'] else
                      f'; no single truth term is responsible (short runs: {short:.3f}, no removal lowers it)')
        out.append(f'  missed {g["goal"]} ({g["profile"]}, {g["temperature_c"]:+g} degC): {g["value"]:.3f} '
                   f'(target {g["target"]:g}){reason}')
    named = [g['goal'] for g in missed if g['goal'] not in LEARNING_GOALS]   # (learning goals: described above)
    if named:
        out.append('goals missed above: what each checks')
        out.extend(goal_legend(named))
    refit = doc.get('refit')
    if refit:
        out.append(f'refit (case d): {refit["rows"]} residual rows ({refit["accepted_by_method"]["observer"]} '
                   f'observer, {refit["accepted_by_method"]["steady_state"]} steady-state)')
        for k, v in (refit.get('fitted') or {}).items():
            base = refit['base'][k]
            ok = refit['identifiable'][k]
            out.append(f'  {k}: {base:.6g} -> {v:.6g}' + ('' if ok else ' (not identifiable: held)'))
    live = doc.get('live')
    if live:
        rows = [[r['case'], _fmt(r['rate_error_rms_rad_s'], 1e3), _fmt(r['reversal_error_peak_rad'], 1e3, 2),
                 _fmt(r.get('feedforward_latency_p50_s'), 1e3, 2)] for r in records if r.get('mode') == 'live']
        out.append(f'live runs ({live["profile"]}, {live["temperature_c"]:+g} degC, {live["duration_s"]:g} s, real '
                   f'nodes on loopback):')
        out.append(format_table(rows, ['case', 'rate RMS [mrad/s]', 'reversal [mrad]', 'ff latency p50 [ms]']))
        if 'live_rate_error_rms_rad_s' in live:
            out.append(_live_vs_offline(live))
        out.append(f'feedforward transport latency p50 {_fmt(live["feedforward_latency_p50_s"], 1e3, 2)} ms, p95 '
                   f'{_fmt(live["feedforward_latency_p95_s"], 1e3, 2)} ms, max '
                   f'{_fmt(live.get("feedforward_latency_max_s"), 1e3, 2)} ms; age of the torque applied p50 '
                   f'{live["feedforward_age_p50_ticks"]:g}, p95 {live.get("feedforward_age_p95_ticks", math.nan):g} '
                   'ticks')
        if live.get('learning'):
            out.extend(_live_learning_lines(live['learning']))
    for n in doc.get('notes', []):
        out.append(f'note: {n}')
    return '\n'.join(out) + '\n'


def _live_vs_offline(live: dict[str, Any]) -> str:
    return (f'live vs offline ({live["case"]}): {_fmt(live["live_rate_error_rms_rad_s"], 1e3)} mrad/s live, '
            f'{_fmt(live["offline_rate_error_rms_rad_s"], 1e3)} offline with the live timing replayed: '
            f'{live["relative_difference"]:+.1%} ({"agree" if live["agree"] else "DISAGREE"} within 10 %); '
            f'offline with a fixed {live["offline_fixed_latency_ticks"]} ticks (the live median age): '
            f'{_fmt(live["offline_fixed_latency_rate_error_rms_rad_s"], 1e3)}, with the nominal '
            f'{live["offline_nominal_latency_ticks"]} ticks: '
            f'{_fmt(live["offline_nominal_latency_rate_error_rms_rad_s"], 1e3)}')


def _live_learning_lines(lr: dict[str, Any]) -> list[str]:
    """The live learning report (:func:`gimbal_friction.runs.live_learning.learning_report`) as text lines."""
    rms = {c: lr.get(f'rate_error_rms_rad_s_{c}') for c in ('learning', 'learning_resumed')}
    head = f'live learning (friction_feedforward learning in service into {lr["correction_file"]}): '
    topic = (f'  correction topic: {lr["correction_messages"]} messages, {lr["distinct_states"]} distinct states, '
             f'samples {lr["samples_first"]} -> {lr["samples_last"]} in {lr["cells_with_data_last"]} cells, largest '
             f'applied correction {_fmt(lr["max_correction_nm"], 1e3, 4)} N*mm')
    file = (f'  file: periodic save {"yes" if lr["file_saved_periodic"] else "NO"} ({lr["periodic_save_samples"]} '
            f'samples), {lr["shutdown_save_samples"]} samples after the SIGINT (exit code {lr["stop_exit_code"]}); '
            f'the restarted node (no periodic save) saved at its SIGINT '
            f'{"yes" if lr["file_saved_at_shutdown"] else "NO"} ({lr["unsaved_samples_at_stop"]} samples learned since '
            f'the restart, {lr["resumed_shutdown_save_samples"]} in the file; exit code '
            f'{lr["resumed_stop_exit_code"]})')
    restart = (f'  restart on the file: {"resumed" if lr["restart_resumed"] else "NOT resumed"} '
               f'({lr["restart_samples"]} samples in {lr["restart_cells_with_data"]} cells; largest applied-value '
               f'difference {_fmt(lr["restart_max_value_difference_nm"], 1e3, 6)} N*mm); LOS rate RMS '
               f'{_fmt(rms["learning"], 1e3)} mrad/s learning from empty, {_fmt(rms["learning_resumed"], 1e3)} '
               f'after the restart ({lr["resumed_run_samples_last"]} samples at its end)')
    timing = (f'  feedforward timed out on {_int(lr.get("feedforward_timed_out_ticks_learning"))} / '
              f'{_int(lr.get("feedforward_timed_out_ticks_learning_resumed"))} ticks of the two runs; the run after '
              'the restart replayed offline with its live timing: '
              f'{_fmt(lr.get("offline_resumed_rate_error_rms_rad_s_with_correction"), 1e3)} mrad/s with the resumed '
              f'correction (frozen), {_fmt(lr.get("offline_resumed_rate_error_rms_rad_s_without_correction"), 1e3)} '
              'without; with the nominal latency: '
              f'{_fmt(lr.get("offline_resumed_nominal_latency_rate_error_rms_rad_s_with_correction"), 1e3)} with, '
              f'{_fmt(lr.get("offline_resumed_nominal_latency_rate_error_rms_rad_s_without_correction"), 1e3)} '
              'without')
    return [head + ('ok' if lr['ok'] else f'FAILED: {lr["failure"]}'), topic, file, restart, timing]


def _int(x: Any) -> str:
    return '-' if x is None or (isinstance(x, float) and not math.isfinite(x)) else f'{x:.0f}'



# ---------------------------------------------------------------------------------------------- figures
_CASE_STYLE = {'none': ('k', 'o'), 'constant': ('tab:orange', 's'), 'feedforward': ('tab:blue', '^'),
               'refit': ('tab:green', 'v'), 'ideal': ('0.6', 'x'), 'learned': ('tab:red', 'D'),
               'learning': ('salmon', 'd'), 'dynamic': ('tab:olive', 'h'), 'bound': ('tab:brown', '*'),
               'feedforward_measured': ('tab:purple', 'd'),
               'feedforward_reference': ('tab:cyan', 'P')}


def figures(result: StudyResult, out_dir: Path) -> list[Path]:
    """Error vs temperature per case (one figure per profile) and the reversal trace, PNGs in ``out_dir``."""
    from gimbal_friction.plots.figures import pyplot, save_figure
    plt = pyplot()
    paths = []
    recs = result.records
    for p in dict.fromkeys(r['profile'] for r in recs):
        fig, axes = plt.subplots(1, 2, figsize=(11.0, 4.4))
        for c in dict.fromkeys(r['case'] for r in recs if r['profile'] == p):
            rows = sorted((r for r in recs if r['profile'] == p and r['case'] == c), key=lambda r: r['temperature_c'])
            color, marker = _CASE_STYLE.get(c, ('tab:gray', '.'))
            t = [r['temperature_c'] for r in rows]
            axes[0].plot(t, [r['rate_error_rms_rad_s'] * 1e3 for r in rows], marker=marker, color=color, label=c)
            axes[1].plot(t, [r['position_error_rms_rad'] * 1e6 for r in rows], marker=marker, color=color, label=c)
        axes[0].set_ylabel('LOS rate error RMS [mrad/s]')
        axes[1].set_ylabel('LOS position error RMS [µrad]')
        for ax in axes:
            ax.set_xlabel('temperature [°C]')
            ax.set_yscale('log')
            ax.grid(True, which='both', alpha=0.35)
        axes[0].legend(fontsize=8)
        fig.suptitle(f'Closed loop, {p} profile: LOS error vs temperature per compensation case')
        fig.tight_layout()
        paths.append(save_figure(fig, out_dir / f'error_vs_temperature_{p}.png'))
    if result.reversal_traces:
        tr0 = result.reversal_traces[0]
        fig, axes = plt.subplots(3, 1, figsize=(9.0, 8.0), sharex=True)
        for tr in result.reversal_traces:
            color, _ = _CASE_STYLE.get(tr.case, ('tab:gray', '.'))
            axes[0].plot(tr.time_s, tr.position_error_rad * 1e6, color=color, label=tr.case)
            axes[1].plot(tr.time_s, tr.rate_error_rad_s * 1e3, color=color, label=tr.case)
            if tr.case not in ('none', 'ideal'):
                axes[2].plot(tr.time_s, tr.feedforward_nm * 1e3, color=color, label=f'{tr.case}: compensation')
        none = next((tr for tr in result.reversal_traces if tr.case == 'none'), tr0)
        axes[2].plot(none.time_s, none.friction_nm * 1e3, 'k--', lw=1, label='truth friction (none)')
        axes[0].set_ylabel('LOS position error [µrad]')
        axes[1].set_ylabel('LOS rate error [mrad/s]')
        axes[2].set_ylabel('torque [N·mm]')
        axes[2].set_xlabel(f'time from the reversal at {tr0.reversal_time_s:.2f} s [s]')
        for ax in axes:
            ax.grid(True, alpha=0.35)
        axes[0].legend(fontsize=8, ncol=3)
        axes[2].legend(fontsize=7, ncol=2)
        fig.suptitle(f'Around a reversal, {tr0.profile} profile at {tr0.temperature_c:+g} °C')
        fig.tight_layout()
        paths.append(save_figure(fig, out_dir / 'reversal_trace.png'))
    return paths


# ---------------------------------------------------------------------------------------------- residual log
def write_residual_log(measurements: MeasurementArrays, rows: ResidualRows, folder: Path) -> int:
    """Write the estimator's measurements and the residual rows as ``residual_logger`` logs them (measured,
    measured_detail, residual, residual_detail; log time = the sample's stamp) into a new residual-log folder.
    Returns the number of messages written.

    Raises:
        RecordingError: the folder already holds a log or cannot be written.
    """
    from gimbal_friction.recording import topics
    from gimbal_friction.recording.cdr import float64_multi_array_cdr_rows, joint_state_cdr_rows, split_rows
    from gimbal_friction.recording.residual_log import ResidualLogWriter

    log_topics = [(topics.MEASURED, topics.JOINT_STATE_TYPE), (topics.MEASURED_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE),
                  (topics.RESIDUAL, topics.JOINT_STATE_TYPE), (topics.RESIDUAL_DETAIL, topics.FLOAT64_MULTI_ARRAY_TYPE)]
    n = len(rows)
    with ResidualLogWriter(folder, flush_interval_s=None, chunk_size=1 << 20) as w:
        if n == 0:
            return 0
        m_detail, r_detail = detail_matrix(measurements), rows.matrix()
        datas: list[bytes] = [b''] * (4 * n)
        for joint in sorted(set(rows.joint.tolist())):
            sel = np.flatnonzero(rows.joint == joint)
            stamps = np.asarray(measurements.stamp_ns, dtype=np.int64)[sel]
            pos, vel = measurements.position_rad[sel], measurements.velocity_rad_s[sel]
            parts = [split_rows(joint_state_cdr_rows(stamps, [joint], pos, vel, measurements.friction_nm[sel])),
                     split_rows(float64_multi_array_cdr_rows(m_detail[sel], joint)),
                     split_rows(joint_state_cdr_rows(stamps, [joint], pos, vel, rows.residual_nm[sel])),
                     split_rows(float64_multi_array_cdr_rows(r_detail[sel], joint))]
            for q, k in enumerate(sel.tolist()):
                for j in range(4):
                    datas[4 * k + j] = parts[j][q]
        ids = np.tile(np.arange(4, dtype=np.int64), n)
        logs = np.repeat(np.asarray(measurements.stamp_ns, dtype=np.int64), 4)
        order = np.argsort(logs, kind='stable')
        w.write_raw_many(log_topics, ids[order], logs[order], [datas[i] for i in order.tolist()])
    return 4 * n


def write_outputs(out_dir: Path, doc: dict[str, Any], result: StudyResult, *, residual_log: bool = True
                  ) -> list[Path]:
    """Write the JSON document, the table, the figures and (``residual_log``) case (d)'s residual log into
    ``out_dir``. Returns the paths written.

    Raises:
        GimbalFrictionError: a file or folder that cannot be written, or a residual log already there.
    """
    from gimbal_friction.common.files import write_text_atomic
    from gimbal_friction.common.text import json_finite
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / STUDY_FILE, out_dir / TABLE_FILE]
    write_text_atomic(paths[0], json.dumps(json_finite(doc), indent=1) + '\n')
    write_text_atomic(paths[1], table_text(doc))
    paths += figures(result, out_dir / 'figures')
    if residual_log and result.refit is not None and len(result.refit.rows):
        folder = out_dir / 'residuals'
        write_residual_log(result.refit.measurements, result.refit.rows, folder)
        paths.append(folder)
    return paths
