"""Many units' chamber tests at once: per-unit refits on Dask, the population, and the units outside it.

One job in one module: the fleet run (finding the units, the per-unit work on Dask and the population summary).

A production line tests every seeker; each unit leaves a residual log (``residual_logger`` / ``replay`` output) or
a chamber-test bag. :func:`run_fleet` finds the units (:func:`discover_units`), runs :func:`process_unit` for each
on a Dask cluster (an embedded :class:`distributed.LocalCluster` by default, or an existing scheduler), and
:func:`population` summarises the refitted parameters robustly (median and MAD) and flags the units outside it.

Per unit (on a worker): the log is streamed chunk by chunk into per-bin sufficient statistics
(:mod:`gimbal_friction.refit.sufficient`; memory bounded by the chunk, about 30 MB, whatever the log's length) and
refitted (:func:`gimbal_friction.refit.fit.refit_stats`); a bag is read in windows of
:data:`BAG_WINDOW_MESSAGES` messages (:meth:`~gimbal_friction.recording.bag.ChamberBag.iter_arrays`) fed one
after another to the estimator's logic, as the live node gets its callback batches, and each window's accepted
samples are added to the statistics: memory is bounded by the window (about 1 kB per message while decoded and
estimated), whatever the bag's length (a 2-hour 1 kHz test holds 22 M messages). Measured on a 2.6 M-message bag:
peak RSS 175 MB in windows, 1.8 GB in one piece. Only the small result travels back to the client.

Population. For each refitted parameter of an axis: the median over the units that determined it, and the
spread ``σ_rob = 1.4826 · MAD`` (the standard deviation of a normal population, robust to the outliers it must
find). A unit is outside when ``|x − median| > z_max · max(σ_rob, se_median)`` (``z_max`` = 3.5, Iglewicz &
Hoaglin's modified z-score; ``se_median`` the median of the units' own standard errors, so that a population of
identical units does not flag noise). The reason names the parameter, its value against the median, by how many
spreads, and what it usually means (viscosity: grease batch; contact friction: preload, i.e. gasket or a stiff
bearing; ...).
"""

from __future__ import annotations

import math
import resource
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from gimbal_friction.common.errors import FitError, GimbalFrictionError
from gimbal_friction.physics.model import friction_torque, viscosity_cst
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.residual_read import ReadReport
from gimbal_friction.recording.topics import RESIDUAL_DETAIL, TEMPERATURE
from gimbal_friction.refit.fit import DEFAULT_FIT, RefitResult, refit_stats
from gimbal_friction.refit.records import offset_values, refit_section_text
from gimbal_friction.refit.sufficient import SufficientStats, accumulate_rows
from gimbal_friction.streams.residual_row import residual_rows

#: Messages of a chamber bag decoded at once on a worker (about 1 kB each while processed) [-].
BAG_WINDOW_MESSAGES = 100_000
#: Default parameters of a fleet refit: refit's (the lubricant, with the calibration offset beside it). The contact
#: friction (preload) is ``--fit walther_a,sliding_friction_coefficient --offset off``: beside the offset the sliding
#: coefficient is not determined by a test like the shipped sample (it runs to its bound).
DEFAULT_FLEET_FIT = DEFAULT_FIT
#: Modified z-score beyond which a unit is outside the population [-].
Z_MAX = 3.5
#: MAD -> standard deviation of a normal population [-].
MAD_TO_SIGMA = 1.4826
#: Temperatures at which the refitted friction of every unit is reported [°C].
REPORT_TEMPERATURES_C = (-40.0, 20.0, 60.0)

#: What a parameter outside the population usually means.
MEANING = {
    'walther_a': 'lubricant viscosity (a different grease batch, contamination or fill)',
    'walther_b': 'viscosity-temperature slope (a different grease)',
    'viscosity_offset_cst': 'viscosity offset (a different grease)',
    'palmgren_factor': 'viscous drag floor (grease quantity or type)',
    'sliding_friction_coefficient': 'contact friction (preload: an over-tight gasket or a stiff bearing)',
    'scale_positive': 'positive-direction friction (cabling, unbalance)',
    'scale_negative': 'negative-direction friction (cabling, unbalance)',
    'direction_asymmetry_cold': 'cold direction asymmetry (grease distribution)',
    'direction_asymmetry_warm': 'warm direction asymmetry (grease distribution)',
    'torque_offset_nmm': 'constant torque offset (motor calibration: I_0)',
    'viscosity_m40_cst': 'viscosity at -40 degC (a different grease batch)',
}


class UnitSpec(NamedTuple):
    """One unit's test: a residual log or a chamber bag."""

    name: str
    path: str
    kind: str   #: 'log' or 'bag'


class FitSettings(NamedTuple):
    """How every unit is refitted (shipped to the workers; plain data)."""

    axes: dict[str, AxisParams]         #: configured axes and their base parameters
    config_paths: tuple[str, ...]       #: parameter files (the replay of bags reads them on the worker)
    fit: tuple[str, ...] = DEFAULT_FLEET_FIT
    offset: str = 'auto'
    bin_width_c: float = 5.0
    loss: str = 'linear'
    calibration_se_nm: float | None = None
    direction: str = 'both'
    #: folder for each unit's ``<unit>.refit.yaml`` and learned ``<unit>.correction.yaml`` (None: not written)
    correction_dir: str | None = None


# ------------------------------------------------------------------------------------------------------------
# finding the units


def _bag_topics(path: Path) -> set[str] | None:
    """Topics listed in a rosbag2 ``metadata.yaml`` (None: unreadable)."""
    try:
        doc = yaml.safe_load((path / 'metadata.yaml').read_text(encoding='utf-8'))
        info = doc['rosbag2_bagfile_information']
        return {str(t['topic_metadata']['name']) for t in info.get('topics_with_message_count', [])}
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None


def _mcap_topics(path: Path) -> set[str] | None:
    """Channels in an MCAP file's summary (None: no summary, e.g. a torn file)."""
    from mcap.reader import make_reader

    try:
        with path.open('rb') as f:
            summary = make_reader(f).get_summary()
    except Exception:
        return None
    if summary is None:
        return None
    return {c.topic for c in summary.channels.values()}


def classify(path: Path) -> UnitSpec | None:
    """The unit at ``path`` (a residual log, a replay/logger output folder with ``residuals/``, or a chamber
    bag), or None when ``path`` is neither (e.g. a folder of units)."""
    if path.is_file():
        if path.suffix != '.mcap':
            return None
        topics = _mcap_topics(path)
        kind = 'bag' if topics is not None and TEMPERATURE in topics and RESIDUAL_DETAIL not in topics else 'log'
        return UnitSpec(path.stem, str(path), kind)
    if not path.is_dir():
        return None
    if (path / 'residuals').is_dir():
        return UnitSpec(path.name, str(path / 'residuals'), 'log')
    if (path / 'metadata.yaml').is_file():
        topics = _bag_topics(path) or set()
        if RESIDUAL_DETAIL in topics or TEMPERATURE not in topics:
            return UnitSpec(path.name, str(path), 'log')
        return UnitSpec(path.name, str(path), 'bag')
    if any(p.suffix == '.mcap' for p in path.iterdir() if p.is_file()):
        return UnitSpec(path.name, str(path), 'log')
    return None


def discover_units(paths: Sequence[Path]) -> list[UnitSpec]:
    """The units of ``paths``: each path is a unit, or a folder whose entries are units (one level).

    Raises:
        GimbalFrictionError: a path that does not exist, or no unit at all.
    """
    units: list[UnitSpec] = []
    for path in paths:
        if not path.exists():
            msg = f'{path}: no such file or directory'
            raise GimbalFrictionError(msg)
        unit = classify(path)
        if unit is not None:
            units.append(unit)
            continue
        found = [u for u in (classify(p) for p in sorted(path.iterdir())) if u is not None] if path.is_dir() else []
        if not found:
            msg = f'{path}: neither a residual log, a chamber bag, nor a folder of them'
            raise GimbalFrictionError(msg)
        units.extend(found)
    seen: dict[str, int] = {}
    out = []
    for u in units:  # unique names
        k = seen.get(u.name, 0)
        seen[u.name] = k + 1
        out.append(u if k == 0 else u._replace(name=f'{u.name}#{k + 1}'))
    return out


# ------------------------------------------------------------------------------------------------------------
# one unit (runs on a worker)


def unit_stats_from_log(path: str, direction: str, report: ReadReport | None = None) -> dict[str, SufficientStats]:
    """Per-joint statistics of a residual log, streamed (the one place a fleet worker reads a log); ``report``
    (filled) says what the read skipped."""
    from gimbal_friction.refit.logs import read_stats

    return {joint: data.stats for joint, data in read_stats([Path(path)], direction=direction, report=report,
                                                            label='fleet: reading').items()}


def unit_stats_from_bag(path: str, config_paths: Sequence[str], direction: str,
                        window_messages: int = BAG_WINDOW_MESSAGES) -> dict[str, SufficientStats]:
    """Per-joint statistics of a chamber bag: the estimator's accepted samples (the offline replay's logic, fed
    window by window of ``window_messages`` messages, so memory stays bounded); the one place a fleet worker
    reads a bag."""
    from gimbal_friction.chamber.replay import node_settings
    from gimbal_friction.estimation.estimator import EstimatorLogic
    from gimbal_friction.recording.bag import open_chamber_bag

    axes, _, est_settings = node_settings([Path(p) for p in config_paths])
    logic = EstimatorLogic(axes, est_settings)
    stats: dict[str, SufficientStats] = {}
    for window in open_chamber_bag(path, axes=list(axes)).iter_arrays(window_messages):  # none of them: refused
        measured = logic.feed(window)   # the refit's samples of these rows, as from a residual log
        accumulate_rows(residual_rows(measured, np.full(len(measured), np.nan)), stats, direction=direction)
    measured = logic.flush()            # the bag has ended: the samples waiting for a later temperature
    accumulate_rows(residual_rows(measured, np.full(len(measured), np.nan)), stats, direction=direction)
    return stats


def _axis_record(result: RefitResult, base: AxisParams) -> dict[str, Any]:
    from gimbal_friction.refit.records import fleet_record

    p = result.params
    temps = np.asarray(REPORT_TEMPERATURES_C)
    torque = friction_torque(p, temps, base.speed_rpm).m_total_nmm
    return fleet_record(result, float(viscosity_cst(p, -40.0)),
                        {f'{t:g}': float(m) for t, m in zip(temps.tolist(), torque.tolist(), strict=True)})


def process_unit(unit: UnitSpec, settings: FitSettings) -> dict[str, Any]:
    """Read one unit (streaming) and refit every configured axis it holds; a JSON-ready record.

    Never raises for the unit's own problems: an unreadable test or a refused fit is the record's ``error``.
    """
    t0 = time.perf_counter()
    rec: dict[str, Any] = {'unit': unit.name, 'path': unit.path, 'kind': unit.kind, 'axes': {}, 'error': None}
    try:
        if unit.kind == 'bag':
            stats = unit_stats_from_bag(unit.path, settings.config_paths, settings.direction)
        else:
            report = ReadReport()
            try:
                stats = unit_stats_from_log(unit.path, settings.direction, report)
            finally:
                rec['read'] = report.as_dict()
        rec['read_s'] = time.perf_counter() - t0
        axes = [a for a in settings.axes if a in stats]
        if not axes:
            damage = f'; read: {rec["read"]["summary"]}' if rec.get('read', {}).get('skipped') else ''
            msg = (f'no samples of a configured axis (joints present: {", ".join(sorted(stats)) or "none"}; '
                   f'configured: {", ".join(settings.axes)}{damage})')
            raise FitError(msg)
        rec['rows'] = {a: stats[a].tally.rows for a in axes}
        rec['skipped_rows'] = {a: {'nonfinite': stats[a].tally.skipped_nonfinite,
                                   'standstill': stats[a].tally.skipped_standstill} for a in axes}
        rec['cells'] = {a: len(stats[a]) for a in axes}
        refitted: dict[str, dict[str, float]] = {}
        offsets: dict[str, tuple[float, float, bool]] = {}
        for axis in axes:
            base = settings.axes[axis]
            try:
                result = refit_stats(base, stats[axis], fit=settings.fit, offset=settings.offset,
                                     bin_width_c=settings.bin_width_c, loss=settings.loss,
                                     calibration_se_nm=settings.calibration_se_nm)
            except FitError as err:
                rec['axes'][axis] = {'error': str(err)}
                continue
            rec['axes'][axis] = _axis_record(result, base)
            refitted[axis] = result.refitted
            offsets[axis] = offset_values(result)
        if settings.correction_dir is not None:
            rec['correction'] = unit_correction(unit, settings, refitted, offsets)
    except GimbalFrictionError as err:
        rec['error'] = str(err)
    except Exception as err:  # one unit's failure must not stop the fleet: it is its record
        rec['error'] = f'{type(err).__name__}: {err}'
    rec['seconds'] = time.perf_counter() - t0
    rec['max_rss_mb'] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return rec


def correction_paths(folder: str | Path, unit: str) -> tuple[Path, Path]:
    """Where ``fleet --correction-out`` writes a unit's refitted parameters and its learned correction."""
    return Path(folder) / f'{unit}.refit.yaml', Path(folder) / f'{unit}.correction.yaml'


def unit_correction(unit: UnitSpec, settings: FitSettings, refitted: dict[str, dict[str, float]],
                    offsets: Mapping[str, tuple[float, float, bool]] | None = None) -> dict[str, Any]:
    """Write the unit's refitted parameters (``<unit>.refit.yaml``, layerable as ``refit --out``, with the fitted
    calibration offsets as refit writes them: :func:`~gimbal_friction.refit.records.refit_section_text`) and the
    correction learned from its residual log against that model (``<unit>.correction.yaml``, a second streamed
    pass); the record of both (``error`` instead for a bag unit: replay it first)."""
    from gimbal_friction.chamber.learned import correction_record, learn_correction
    from gimbal_friction.common.files import write_text_atomic
    from gimbal_friction.config.loader import render_parameter_file
    from gimbal_friction.feedforward.correction import save as save_correction

    if unit.kind != 'log' or settings.correction_dir is None:
        return {'error': 'a chamber bag: replay it (gimbal-friction replay) and pass its residual log to learn a '
                         'correction'}
    params_path, path = correction_paths(settings.correction_dir, unit.name)
    header = (f'gimbal-friction fleet: unit {unit.name} ({unit.path}): refitted parameters (layer over '
              + ' + '.join(['packaged defaults', *settings.config_paths]) + f'); learned correction: {path.name}')
    write_text_atomic(params_path, render_parameter_file(axes_overrides=refitted, header=header)
                      + refit_section_text(offsets or {}))
    learned = learn_correction([Path(unit.path)], [*map(Path, settings.config_paths), params_path],
                               label='fleet: correction')
    save_correction(learned.correction, path)
    return {'params': str(params_path), **correction_record(learned, path)}


# ------------------------------------------------------------------------------------------------------------
# the population


def _values(records: Sequence[Mapping[str, Any]], axis: str) -> dict[str, list[tuple[str, float, float]]]:
    """Per parameter: (unit, value, standard error) of the units that determined it."""
    out: dict[str, list[tuple[str, float, float]]] = {}
    for rec in records:
        a = rec['axes'].get(axis)
        if not a or 'error' in a:
            continue
        for name, value in a['fitted'].items():
            if a['identifiable'].get(name):
                out.setdefault(name, []).append((rec['unit'], float(value), float(a['standard_errors'][name])))
        if a['offset']['estimated']:
            out.setdefault('torque_offset_nmm', []).append((rec['unit'], float(a['offset']['value_nmm']),
                                                            float(a['offset']['se_nmm'])))
        out.setdefault('viscosity_m40_cst', []).append((rec['unit'], float(a['viscosity_m40_cst']), math.nan))
    return out


def population(records: Sequence[Mapping[str, Any]], z_max: float = Z_MAX) -> dict[str, Any]:
    """Median, robust spread and outliers of the refitted parameters, per axis.

    Returns ``{'axes': {axis: {parameter: {median, mad, spread, se_median, n, low, high}}}, 'outliers': [...]}``;
    an outlier is ``{unit, axis, parameter, value, median, z, reason}``.
    """
    axes = sorted({a for rec in records for a in rec['axes']})
    stats: dict[str, dict[str, Any]] = {}
    outliers: list[dict[str, Any]] = []
    for axis in axes:
        stats[axis] = {}
        for name, rows in _values(records, axis).items():
            x = np.array([v for _, v, _ in rows])
            ses = np.array([s for _, _, s in rows])
            med = float(np.median(x))
            mad = float(np.median(np.abs(x - med)))
            spread = MAD_TO_SIGMA * mad
            se_med = float(np.nanmedian(ses)) if np.any(np.isfinite(ses)) else 0.0
            scale = max(spread, se_med, 1e-12 * max(abs(med), 1.0))
            stats[axis][name] = {'median': med, 'mad': mad, 'spread': spread, 'se_median': se_med, 'n': len(rows),
                                 'low': med - z_max * scale, 'high': med + z_max * scale}
            if len(rows) < 3:
                continue
            for unit, value, _ in rows:
                z = (value - med) / scale
                if abs(z) > z_max:
                    where = 'above' if z > 0 else 'below'
                    outliers.append({
                        'unit': unit, 'axis': axis, 'parameter': name, 'value': value, 'median': med, 'z': z,
                        'reason': (f'{name} = {value:.6g} is {abs(z):.1f} spreads {where} the median {med:.6g} '
                                   f'(spread {scale:.3g}): {MEANING.get(name, name)}')})
    outliers.sort(key=lambda o: (o['unit'], -abs(o['z'])))
    return {'axes': stats, 'outliers': outliers, 'z_max': z_max}


# ------------------------------------------------------------------------------------------------------------
# running on Dask


class FleetRun(NamedTuple):
    """What :func:`run_fleet` computed."""

    records: list[dict[str, Any]]
    population: dict[str, Any]
    scheduler: str
    workers: int
    seconds: float          #: wall time, cluster start included [s]
    startup_s: float = 0.0  #: of which starting (or connecting to) the cluster [s]


#: how to install what ``fleet`` runs on (one line, in the refusal when it is missing)
DASK_INSTALL = "pip install 'dask[distributed]' (or gimbal_friction[fleet]; pinned versions: requirements.txt)"


def require_dask() -> None:
    """Refuse, in one line, to run without Dask's ``distributed`` (an optional dependency of ``fleet`` only).

    Raises:
        GimbalFrictionError: ``dask`` or ``distributed`` cannot be imported, with the command that installs them.
    """
    import importlib

    for module in ('dask', 'distributed'):
        try:
            importlib.import_module(module)
        except ImportError as err:
            msg = f'fleet runs on Dask and {err.name or module!r} is not installed: {DASK_INSTALL}'
            raise GimbalFrictionError(msg) from None


def run_fleet(units: Sequence[UnitSpec], settings: FitSettings, *, scheduler: str | None = None,
              workers: int | None = None, processes: bool = True, memory_limit: str = 'auto',
              on_done: Callable[[int, int, dict[str, Any]], None] | None = None) -> FleetRun:
    """Refit every unit on Dask and summarise the population.

    Parameters
    ----------
    units : sequence of UnitSpec
        The units (:func:`discover_units`).
    settings : FitSettings
        How to refit.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); default an embedded ``LocalCluster``.
    workers : int, optional
        Workers of the local cluster (default: the CPU count, at most the number of units).
    processes : bool
        Local workers as processes (default) or threads.
    memory_limit : str
        Memory limit per local worker (Dask syntax, e.g. ``'2GiB'``; ``'auto'``: the machine's memory shared).
    on_done : callable, optional
        Called as ``on_done(done, total, record)`` when a unit finishes (progress).

    Raises
    ------
    GimbalFrictionError
        The scheduler cannot be reached or the cluster cannot start.
    """
    import logging

    require_dask()
    from distributed import Client, LocalCluster, as_completed

    t0 = time.perf_counter()
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout='20s')
        else:
            import os

            n = workers or min(len(units), os.cpu_count() or 1)
            cluster = LocalCluster(n_workers=max(1, n), threads_per_worker=1, processes=processes,
                                   dashboard_address=None, memory_limit=memory_limit,
                                   silence_logs=logging.ERROR)
            client = Client(cluster)
    except (OSError, TimeoutError) as err:
        where = scheduler or 'a local cluster'
        msg = f'cannot start or reach Dask ({where}): {err}'
        raise GimbalFrictionError(msg) from None
    t_ready = time.perf_counter()
    records: list[dict[str, Any]] = []
    try:
        address = str(client.scheduler.address) if client.scheduler is not None else str(scheduler)
        n_workers = len(client.scheduler_info().get('workers', {}))
        futures = [client.submit(process_unit, u, settings, key=f'fleet-unit-{i}-{u.name}', pure=False)
                   for i, u in enumerate(units)]
        for done, fut in enumerate(as_completed(futures), start=1):
            rec = fut.result()
            records.append(rec)
            if on_done is not None:
                on_done(done, len(units), rec)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    order = {u.name: i for i, u in enumerate(units)}
    records.sort(key=lambda r: order[r['unit']])
    return FleetRun(records, population(records), address if scheduler else 'local', n_workers,
                    time.perf_counter() - t0, t_ready - t0)


def progress_line(done: int, total: int, rec: Mapping[str, Any], stream: Any = None) -> None:
    """One line per finished unit on stderr."""
    out = stream if stream is not None else sys.stderr
    failed = {axis: a['error'] for axis, a in (rec.get('axes') or {}).items() if 'error' in a}
    if rec.get('error'):
        status = f'error: {rec["error"]}'
    elif failed and len(failed) == len(rec['axes']):   # every axis refused: the unit failed, not 'ok'
        status = 'error: ' + '; '.join(f'{axis}: {why}' for axis, why in failed.items())
    else:
        status = 'ok' + ''.join(f'; {axis} failed: {why}' for axis, why in failed.items())
    read = rec.get('read') or {}
    if read.get('skipped'):  # every command that skips data says how much
        status += f'; {read["summary"]}'
    out.write(f'fleet: {done}/{total} {rec["unit"]} ({rec.get("seconds", math.nan):.1f} s) {status}\n')
    out.flush()


# ------------------------------------------------------------------------------------------------------------
# figure


def plot_fleet(run: FleetRun, path: Path) -> Path:
    """One panel per (axis, parameter): every unit's value with its 95 % interval, the median, the band of the
    population (± z_max spreads) and the outliers in red; PNG via matplotlib Agg."""
    from gimbal_friction.plots.figures import pyplot, save_figure

    plt = pyplot()

    panels = [(axis, name) for axis, params in run.population['axes'].items() for name in params]
    if not panels:
        msg = 'no unit was refitted: nothing to plot'
        raise GimbalFrictionError(msg)
    flagged = {(o['unit'], o['axis'], o['parameter']) for o in run.population['outliers']}
    units = [r['unit'] for r in run.records]
    cols = min(3, len(panels))
    rows = math.ceil(len(panels) / cols)
    fig, axs = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.6 * rows), squeeze=False)
    for ax, (axis, name) in zip(axs.ravel(), panels, strict=False):
        st = run.population['axes'][axis][name]
        for i, rec in enumerate(run.records):
            a = rec['axes'].get(axis)
            if not a or 'error' in a:
                continue
            if name == 'torque_offset_nmm':
                if not a['offset']['estimated']:
                    continue
                value = a['offset']['value_nmm']
                lo, hi = a['offset']['ci95_nmm']
            elif name == 'viscosity_m40_cst':
                value, lo, hi = a['viscosity_m40_cst'], math.nan, math.nan
            else:
                if not a['identifiable'].get(name):
                    continue
                value, (lo, hi) = a['fitted'][name], a['ci95'][name]
            bad = (rec['unit'], axis, name) in flagged
            color = 'C3' if bad else 'C0'
            err = None if not (math.isfinite(lo) and math.isfinite(hi)) else [[value - lo], [hi - value]]
            ax.errorbar([i], [value], yerr=err, fmt='o', color=color, capsize=2, ms=4)
            if bad:
                ax.annotate(rec['unit'], (i, value), fontsize=7, color='C3', xytext=(3, 3),
                            textcoords='offset points')
        ax.axhline(st['median'], color='k', lw=1.0, label='median')
        ax.axhspan(st['low'], st['high'], color='0.85', zorder=0, label=f'+/- {run.population["z_max"]:g} spreads')
        ax.set_title(f'{axis}: {name}', fontsize=9)
        ax.set_xticks(range(len(units)))
        ax.set_xticklabels(units, rotation=90, fontsize=6)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axs.ravel()[len(panels):]:
        ax.set_visible(False)
    fig.suptitle(f'fleet: {len(run.records)} units, {len(run.population["outliers"])} outlier flag(s)', fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)
