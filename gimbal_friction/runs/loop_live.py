"""``gimbal-friction loop-study --live``: the real nodes in real time, on loopback, against the offline study.

:func:`live_study` starts ``friction_feedforward``, ``friction_estimator`` (method ``observer``) and
``residual_logger`` as processes with the study's parameter files, waits until they are connected, then runs
``gimbal_sim`` once per live case (``exit_when_done``, ``wait_for_subscribers``, ``record_path``): the wiring of
:mod:`gimbal_friction.runs.loop_wiring`, the same as ``closed_loop.launch.py``'s. They run on a free
ROS_DOMAIN_ID (:func:`~gimbal_friction.runs.supervisor.free_domain`: reserved, no other node on it) with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, under the supervisor of :mod:`gimbal_friction.runs.supervisor`
(stopped with SIGINT, then SIGTERM, then SIGKILL on success, failure and SIGINT / SIGTERM / SIGHUP at any moment,
start-up included). Each
``gimbal_sim`` run writes its traces and latencies (:func:`save_run`); :func:`load_run` turns them into the same
:class:`~gimbal_friction.sim.engine.BatchResult` the offline study measures, so both are measured by the same
:func:`~gimbal_friction.sim.metrics.batch_metrics`. The same case is then simulated offline with the
feedforward delayed by the age the live run applied it with (its median, in controller ticks), and the two LOS
rate error RMS are compared (agreement: within 10 %).

The transport latency is measured by ``gimbal_sim`` from the stamps: a feedforward message carries the stamp of the
joint state that produced it, so latency = arrival wall time − publish wall time of that joint state.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.common.files import write_bytes_atomic
from gimbal_friction.feedforward.correction import Correction
from gimbal_friction.runs.loop_wiring import LOOP_NODES, SimRun, loop_nodes, sim_node, write_parameter_files
from gimbal_friction.runs.supervisor import Supervisor, free_domain
from gimbal_friction.sim.compensation import Compensator, ControllerInputs
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.engine import BatchResult, Run, Traces, simulate
from gimbal_friction.sim.metrics import batch_metrics
from gimbal_friction.sim.profiles import make_profile
from gimbal_friction.sim.realtime import RealtimeRun
from gimbal_friction.sim.study import SHORT_DURATIONS, FeedforwardSetup

__all__ = ['AGREEMENT', 'live_study', 'load_run', 'save_run']

#: Live and offline agree when their LOS rate error RMS differ by at most this fraction [-].
AGREEMENT = 0.10
LIVE_NODES = LOOP_NODES


# ---------------------------------------------------------------------------------------------- run records
def save_run(path: str | os.PathLike[str], run: RealtimeRun) -> Path:
    """Write a run's traces, latencies and configuration to ``path`` (.npz; written whole or not at all)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    res = run.result()
    meta = {'config': run.config.to_mapping(), 'profile': run.profile.name, 'case': run.case,
            'temperature_c': run.settings.environment_temperature_c, 'seed': run.settings.run_seed,
            'duration_s': float(run.profile.time_s.shape[0] * run.config.controller_period_s),
            'ticks': int(res.traces.los_rate_rad_s.shape[0]), 'latency': run.latency_summary(),
            'stale': run.stale, 'foreign': run.foreign}
    arrays = {f'trace_{name}': np.asarray(getattr(res.traces, name))[:, 0] for name in Traces._fields}
    arrays.update(meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), sampled=res.temperature_sampled,
                  feedforward_age=run.feedforward_age, publish_wall_s=run.publish_wall_s,
                  transport_latency_s=np.asarray(run.transport_latency_s, dtype=float))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]  # numpy's savez stub types **kwds as one array type
    write_bytes_atomic(out, buffer.getvalue(), what='run')
    return out


def load_run(path: str | os.PathLike[str]) -> tuple[BatchResult, dict[str, Any], dict[str, np.ndarray]]:
    """A run written by :func:`save_run`: (the batch of one run, its metadata, the latency arrays).

    Raises:
        GimbalFrictionError: not a readable run record.
    """
    try:
        with np.load(Path(path)) as data:
            meta = json.loads(bytes(data['meta']).decode())
            traces = Traces(**{name: np.asarray(data[f'trace_{name}'])[:, None] for name in Traces._fields})
            sampled = np.asarray(data['sampled'])
            extra = {k: np.asarray(data[k]) for k in ('feedforward_age', 'publish_wall_s', 'transport_latency_s')}
    except (OSError, KeyError, ValueError) as err:
        msg = f'{path}: not a gimbal_sim run record ({err})'
        raise GimbalFrictionError(msg) from None
    config = SimConfig.from_mapping(meta['config'])
    profile = make_profile(config, meta['profile'], meta['duration_s'])
    n = int(meta['ticks'])
    if n < profile.time_s.shape[0]:   # an interrupted run: the ticks simulated
        from gimbal_friction.sim.profiles import Profile
        p = profile
        profile = Profile(p.name, p.time_s[:n], p.target_angle_rad[:n], p.target_rate_rad_s[:n],
                          p.base_angle_rad[:n], p.base_rate_rad_s[:n], p.reversal_times_s, p.base_motion)
    run = Run(meta['case'], float(meta['temperature_c']), int(meta['seed']))
    return BatchResult(config, profile, (run,), traces, sampled), meta, extra


# ---------------------------------------------------------------------------------------------- live study
class _GraphProbe:
    """A node in this process that only looks at the graph (no subscriptions: it costs no CPU per message)."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('loop_study_probe', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def _wait_connected(watcher: Any, sup: Supervisor, timeout_s: float) -> None:
    from gimbal_friction.recording import topics
    n = watcher.node
    deadline = time.monotonic() + timeout_s
    while True:
        ok = (n.count_subscribers(topics.JOINT_STATES) >= 3 and n.count_subscribers(topics.MOTOR_CURRENT) >= 2
              and n.count_subscribers(topics.TEMPERATURE) >= 3 and n.count_publishers(topics.FEEDFORWARD) >= 1
              and n.count_subscribers(topics.MEASURED_DETAIL) >= 1)
        if ok:
            return
        sup.check_alive()
        if time.monotonic() > deadline:
            msg = f'the nodes did not connect within {timeout_s:.0f} s'
            raise GimbalFrictionError(msg)
        watcher.spin(0.1)


def live_study(inputs: Any, *, temperature_c: float = -40.0, profile: str = 'tracking',
               cases: Sequence[str] = ('feedforward',), short: bool = False, duration_s: float | None = None,
               realtime_factor: float = 1.0, publish_every_ticks: int = 2, work_dir: Path | None = None,
               log: Callable[[str], None] = lambda text: None, connect_timeout_s: float = 60.0,
               learn: Any = None) -> dict[str, Any]:
    """Run the live closed loop for each of ``cases`` (``feedforward``, ``none``, ``learning``) and compare with
    offline.

    ``inputs`` is a :class:`gimbal_friction.runs.loop_study.StudyInputs`. Case ``learning`` runs after the others:
    the feedforward node learning in service, saved and restarted (:mod:`gimbal_friction.runs.live_learning`, with
    ``learn``, a :class:`~gimbal_friction.sim.study.LearnSetup`, default the study's). Returns the ``live`` section
    of the study document (with its ``records``: one per run, ``mode`` ``live``, with
    ``feedforward_latency_p50_s``; with case ``learning`` its ``learning`` report).

    Raises:
        GimbalFrictionError: a node that does not start or connect, or a run that does not finish.
    """
    import tempfile

    from gimbal_friction.runs.live_learning import LEARNING_CASE, RESUMED_CASE, live_learning
    from gimbal_friction.sim.study import LearnSetup

    cfg: SimConfig = inputs.sim
    if duration_s is None:
        duration_s = SHORT_DURATIONS[profile] if short else cfg.profile_duration_s(profile)
    plain = [c for c in cases if c != LEARNING_CASE]
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix='loop-live-')
        work_dir = Path(tmp.name)
    work_dir = Path(work_dir)
    (work_dir / 'logs').mkdir(parents=True, exist_ok=True)
    param_files = write_parameter_files(inputs, work_dir)
    records: list[dict[str, Any]] = []
    runs: dict[str, tuple[BatchResult, dict[str, Any], dict[str, np.ndarray]]] = {}
    learning: dict[str, Any] | None = None
    resumed_from: Correction | None = None
    try:
        with Supervisor({}, work_dir / 'logs', may_exit=lambda name: name.startswith('gimbal_sim')) as sup, \
                free_domain(log=lambda text: log(f'loop-study --live: {text}')) as did:
            sup.env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                           ROS_LOG_DIR=str(work_dir / 'logs' / 'ros'), PYTHONUNBUFFERED='1')
            watcher = None
            try:
                every = loop_nodes(param_files, work_dir / 'residuals')
                # the feedforward's arguments (the parameter files only): live_learning adds its own file to them
                args = every[0].ros_args()
                nodes = every if plain else every[1:]   # the learning case starts its own feedforward
                log(f'loop-study --live: starting {", ".join(n.name for n in nodes)} (domain {did}, loopback only)')
                for node in nodes:
                    sup.start_as(node.name, node.executable, node.ros_args())
                watcher = _GraphProbe(did)

                def run_sim(case: str, tick: Callable[[], None] | None = None
                            ) -> tuple[BatchResult, dict[str, Any], dict[str, np.ndarray]]:
                    run = SimRun(duration_s=float(duration_s), use_feedforward=case != 'none',
                                 temperature_c=temperature_c, profile=profile, realtime_factor=realtime_factor,
                                 publish_every_ticks=publish_every_ticks, record_path=str(work_dir / f'run_{case}.npz'))
                    return _run_sim(sup, param_files, work_dir, case, run, timeout_s=connect_timeout_s, log=log,
                                    tick=tick)

                if plain:
                    _wait_connected(watcher, sup, connect_timeout_s)
                for case in plain:
                    runs[case] = run_sim(case)
                if LEARNING_CASE in cases:
                    if plain:
                        code = sup.stop(LIVE_NODES[0])
                        if code != 0:
                            msg = f'friction_feedforward exited with code {code}; see {work_dir / "logs"}'
                            raise GimbalFrictionError(msg)
                    learning, more_runs, resumed_from = live_learning(
                        sup=sup, watcher=watcher, node_args=args, work_dir=work_dir, inputs=inputs,
                        learn=learn if learn is not None else LearnSetup(), run_sim=run_sim,
                        wait_connected=lambda: _wait_connected(watcher, sup, connect_timeout_s), log=log,
                        timeout_s=connect_timeout_s)
                    runs.update(more_runs)
                codes = sup.stop_all()
                bad = {k: v for k, v in codes.items() if v not in (0, None) and not k.startswith('gimbal_sim')}
                if bad:
                    msg = f'nodes exited with errors: {bad}; see {work_dir / "logs"}'
                    raise GimbalFrictionError(msg)
            finally:
                sup.stop_all()
                if watcher is not None:
                    watcher.close()
    finally:
        if tmp is not None:
            tmp.cleanup()
    out: dict[str, Any] = {'temperature_c': float(temperature_c), 'profile': profile, 'duration_s': duration_s,
                           'realtime_factor': realtime_factor, 'publish_every_ticks': publish_every_ticks,
                           'cases': list(cases)}
    for case, (batch, meta, _) in runs.items():
        (m,) = batch_metrics(batch)
        rec = {'case': case, 'temperature_c': float(temperature_c), 'profile': profile, **m._asdict(),
               'duration_s': duration_s, 'mode': 'live'}
        lat = meta['latency']
        rec['feedforward_latency_p50_s'] = lat['feedforward_latency_p50_s']
        records.append(rec)
        if case == 'feedforward' or (case == LEARNING_CASE and 'feedforward' not in runs):
            out.update(lat)
    if learning is not None:
        rms = {r['case']: r['rate_error_rms_rad_s'] for r in records}
        for c in (c for c in runs if c not in plain):
            learning[f'rate_error_rms_rad_s_{c}'] = rms[c]
            learning[f'feedforward_timed_out_ticks_{c}'] = runs[c][1]['latency'].get('feedforward_timed_out_ticks')
        if resumed_from is not None and RESUMED_CASE in runs:
            # what the resumed correction itself does, the live timing held equal: the run after the restart
            # replayed offline with the live per-tick feedforward age, with the correction (frozen) and without
            batch, _, extra = runs[RESUMED_CASE]
            learning['offline_resumed_rate_error_rms_rad_s_with_correction'] = _offline_twin(
                inputs, batch, 'feedforward', 0, extra['feedforward_age'], resumed_from)
            learning['offline_resumed_rate_error_rms_rad_s_without_correction'] = _offline_twin(
                inputs, batch, 'feedforward', 0, extra['feedforward_age'])
            # ... and with the nominal latency (the machine's load taken out)
            learning['offline_resumed_nominal_latency_rate_error_rms_rad_s_with_correction'] = _offline_twin(
                inputs, batch, 'feedforward', cfg.latency_ticks, correction=resumed_from)
            learning['offline_resumed_nominal_latency_rate_error_rms_rad_s_without_correction'] = _offline_twin(
                inputs, batch, 'feedforward', cfg.latency_ticks)
        out['learning'] = learning
    out['records'] = records
    out.setdefault('feedforward_latency_p50_s', math.nan)
    out.setdefault('feedforward_latency_p95_s', math.nan)
    out.setdefault('feedforward_age_p50_ticks', math.nan)
    if not plain:   # live vs offline: for the plain cases only (the learning runs change their feedforward)
        return out
    compare = 'feedforward' if 'feedforward' in runs else plain[0]
    batch, meta, extra = runs[compare]
    age = meta['latency'].get('feedforward_age_p50_ticks', math.nan)
    latency_ticks = int(round(age)) if math.isfinite(age) else 0
    nominal_ticks = cfg.latency_ticks
    replayed = _offline_twin(inputs, batch, compare, 0, extra['feedforward_age'])
    fixed = _offline_twin(inputs, batch, compare, latency_ticks)
    nominal = _offline_twin(inputs, batch, compare, nominal_ticks)
    live_rms = next(r['rate_error_rms_rad_s'] for r in records if r['case'] == compare)
    rel = live_rms / replayed - 1.0
    out.update({'case': compare, 'live_rate_error_rms_rad_s': live_rms,
                'offline_rate_error_rms_rad_s': replayed, 'relative_difference': rel,
                'agree': bool(abs(rel) <= AGREEMENT),
                'offline_fixed_latency_ticks': latency_ticks, 'offline_fixed_latency_rate_error_rms_rad_s': fixed,
                'offline_nominal_latency_ticks': nominal_ticks,
                'offline_nominal_latency_rate_error_rms_rad_s': nominal, 'records': records})
    return out


def _run_sim(sup: Supervisor, param_files: Sequence[Path], work_dir: Path, case: str, run: SimRun, *,
             timeout_s: float, log: Callable[[str], None], tick: Callable[[], None] | None = None
             ) -> tuple[BatchResult, dict[str, Any], dict[str, np.ndarray]]:
    """One ``gimbal_sim`` run of ``case`` (``run``: :mod:`gimbal_friction.runs.loop_wiring`), waited for (``tick``
    called while waiting, else 0.2 s waits); the loaded run (:func:`load_run`)."""
    record = Path(run.record_path)
    log(f'loop-study --live: gimbal_sim {case}, {run.profile} at {run.temperature_c:+g} degC for '
        f'{run.duration_s:g} s (real time x{run.realtime_factor:g})')
    node = sim_node(param_files, run)
    proc = sup.start_as(f'gimbal_sim_{case}', node.executable, node.ros_args())
    deadline = time.monotonic() + timeout_s + 3.0 * run.duration_s / run.realtime_factor + 30.0
    while proc.poll() is None:
        sup.check_alive()
        if time.monotonic() > deadline:
            msg = f'gimbal_sim ({case}) did not finish in time; see {work_dir / "logs"}'
            raise GimbalFrictionError(msg)
        if tick is not None:
            tick()
        else:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(0.2)
    if proc.returncode != 0 or not record.exists():
        tail = (work_dir / 'logs' / f'gimbal_sim_{case}.log').read_text(errors='replace')
        last = ' | '.join(tail.strip().splitlines()[-2:])
        msg = f'gimbal_sim ({case}) failed (code {proc.returncode}): {last}'
        raise GimbalFrictionError(msg)
    return load_run(record)


def _offline_twin(inputs: Any, live: BatchResult, case: str, latency_ticks: int,
                  ages: np.ndarray | None = None, correction: Correction | None = None) -> float:
    """LOS rate error RMS [rad/s] of the same run offline: the feedforward (with ``correction``, frozen, if given)
    ``latency_ticks`` old at every tick, or, with ``ages``, exactly as old as the live run had it at each tick (its
    timing replayed, the controller's ``feedforward_timeout_s`` included)."""
    cfg = live.config.replace(feedforward_latency_s=latency_ticks * live.config.controller_period_s)
    ff: FeedforwardSetup = inputs.feedforward
    comps: dict[str, Compensator] = {}
    if case == 'feedforward':
        comp = ff.compensator(inputs.axis, correction=correction)
        comps['feedforward'] = comp if ages is None else _replayed(comp, ages, cfg)
    res = simulate(cfg, inputs.axis, live.profile, [Run(case, live.runs[0].temperature_c, live.runs[0].seed)],
                   comps)
    return float(batch_metrics(res)[0].rate_error_rms_rad_s)


def _replayed(comp: Compensator, age: np.ndarray, config: SimConfig) -> Compensator:
    """``comp`` applied with the per-tick age of a live run: at tick k the torque computed at tick k − age[k]
    (0 N·m where the live run had received none yet or it was too old: :meth:`SimConfig.feedforward_fresh`)."""
    history: list[np.ndarray] = []

    def torque(inputs: ControllerInputs) -> np.ndarray:
        history.append(np.asarray(comp.torque(inputs), dtype=float))
        k = len(history) - 1
        a = int(age[k]) if k < age.shape[0] else -1
        return history[k - a] if a <= k and config.feedforward_fresh(a) else np.zeros_like(history[k])

    return Compensator(torque, delayed=False)
