"""``loop-study --live --live-cases learning``: the real ``friction_feedforward`` learning in service, saved, restarted.

:func:`live_learning` runs inside :func:`gimbal_friction.runs.loop_live.live_study` (its supervisor, its probe node,
its ``gimbal_sim`` runs; the estimator in observer mode and the residual logger keep running throughout):

1. starts ``friction_feedforward`` with learning on: ``learning_enabled``, ``correction_file`` =
   ``correction.yaml`` in the live work folder (absent: learning starts from an empty correction), the correction's
   layout and the learner's rate of the study's case ``learned`` (:class:`~gimbal_friction.sim.study.LearnSetup`,
   a rate 33x the node default: service life squeezed into seconds), saved every :data:`SAVE_PERIOD_S` and
   published every :data:`PUBLISH_PERIOD_S`; then runs ``gimbal_sim`` (case ``learning``), recording
   ``/gimbal/friction/correction`` with a subscription of the probe node and reading the file with the library's
   reader (:func:`~gimbal_friction.feedforward.correction.load`, the model's identity checked) whenever
   it changes;
2. after the run, waits until the node has learned what it received (its ``/diagnostics`` learning status: no
   sample pending or in a fit, twice in a row with the same counts) and a periodic save holds it, then stops the
   node with SIGINT (exit code 0) and reads the file again;
3. restarts the node on the same file with ``learning_save_period_s`` = :data:`HOLD_SAVE_PERIOD_S` and compares its
   first correction message with the file: the same samples in every cell, the applied values equal to the file's
   or moved from them towards the learned ones (the learner steps on while it runs);
4. runs ``gimbal_sim`` again (case ``learning_resumed``, same seed) with the correction it resumed (learning on),
   waits as in 2 and stops the node: what it learned reached the file only through its save at shutdown.

Every wait is on a condition (the node's own counts), not on the machine's speed: the learner's worker runs at a
lower priority and may fall seconds behind on a loaded machine.

:func:`learning_report` turns what was seen into the ``learning`` object of the live section; its ``failure``
names the first thing that did not happen (the command then exits non-zero).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.config.node_settings import FEEDFORWARD_PREFIXED
from gimbal_friction.feedforward.correction import (
    DIRECTIONS,
    Correction,
    CorrectionError,
    ModelIdentity,
    model_identity,
)
from gimbal_friction.feedforward.correction import load as load_correction
from gimbal_friction.recording import topics

__all__ = ['CORRECTION_FILE', 'HOLD_SAVE_PERIOD_S', 'LEARNING_CASE', 'PUBLISH_PERIOD_S', 'RESUMED_CASE',
           'SAVE_PERIOD_S', 'CorrectionState', 'correction_state', 'learning_parameters', 'live_learning']

LEARNING_CASE = 'learning'
#: the live run after the restart (the correction resumed from the file, learning on)
RESUMED_CASE = 'learning_resumed'
#: name of the correction file in the live work folder
CORRECTION_FILE = 'correction.yaml'
#: ``learning_save_period_s`` of the live learning run until its first periodic save [s]
SAVE_PERIOD_S = 0.5
#: ``learning_save_period_s`` of the restarted node [s] (the parameter's maximum): what it learns reaches the file only
#: through its save at shutdown
HOLD_SAVE_PERIOD_S = 86400.0
#: ``correction_publish_period_s`` and ``diagnostics_period_s`` of the live learning runs [s]
PUBLISH_PERIOD_S = 0.25
#: the ``/diagnostics`` status of the feedforward's learning
LEARNING_STATUS = 'gimbal_friction/feedforward/learning'
_FIRST, _RESTART = 'friction_feedforward_learning', 'friction_feedforward_restart'


class CorrectionState(NamedTuple):
    """One ``/gimbal/friction/correction`` message, for one joint."""

    stamp_s: float          #: the message stamp (the node's clock) [s since the epoch]
    state: str              #: off, active, frozen, saturated
    samples: int            #: samples in the correction [-]
    cells_with_data: int    #: cells holding samples [-]
    max_abs_correction_nm: float   #: largest |applied correction| [N*m]
    cells: dict[tuple[str, str], tuple[int, float]]   #: (direction, centre '%g' degC) -> (samples, value_nm [N*m])

    def key(self) -> tuple[Any, ...]:
        """What makes two states the same (everything but the stamp and the state name)."""
        return self.samples, self.cells_with_data, self.max_abs_correction_nm, tuple(sorted(self.cells.items()))


def correction_state(msg: Any, joint: str) -> CorrectionState | None:
    """The state of ``joint`` in a correction message (diagnostic_msgs/DiagnosticArray, the statuses
    ``gimbal_friction/correction/<joint>`` and ``.../<joint>/<direction>/<centre>``); None without that joint."""
    prefix = f'gimbal_friction/correction/{joint}'
    head: dict[str, str] | None = None
    cells: dict[tuple[str, str], tuple[int, float]] = {}
    for st in msg.status:
        values = {kv.key: kv.value for kv in st.values}
        if st.name == prefix:
            head = values
        elif st.name.startswith(prefix + '/'):
            direction, centre = st.name[len(prefix) + 1:].split('/', 1)
            cells[direction, centre] = (int(values['samples']), float(values['value_nm']))
    if head is None:
        return None
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    return CorrectionState(float(stamp), head.get('state', ''), int(head['samples']), int(head['cells_with_data']),
                           float(head['max_abs_correction_nm']), cells)


def file_cells(c: Correction, joint: str) -> dict[tuple[str, str], tuple[int, float, float, float]]:
    """The cells of a correction named as in :attr:`CorrectionState.cells`: (samples, applied level [N*m], and the
    range [N*m] a learner resuming from it can have moved the level to: between the applied level, the learned one
    and the model's 0 (the guard may hold a cell back) of each cell)."""
    fit = c.copy().refit(joint)
    out = {}
    for rec in c.cells(joint):
        d = DIRECTIONS.index(rec['direction'])
        learned = float(fit.flat_nm[d, rec['bin']])
        value = float(rec['value_nm'])
        out[rec['direction'], f'{rec["centre_c"]:g}'] = (int(rec['samples']), value, min(value, learned, 0.0),
                                                         max(value, learned, 0.0))
    return out


def learning_parameters(learn: Any, correction_file: Path, save_period_s: float = SAVE_PERIOD_S) -> dict[str, Any]:
    """``friction_feedforward``'s parameters of the live learning run: learning on, ``correction_file``, the save
    period ``save_period_s`` [s], the short publish and diagnostics periods, and ``learn``'s
    (:class:`~gimbal_friction.sim.study.LearnSetup`) correction layout and learning rate under their parameter names
    (``correction_*``, ``learning_*``) and its loop judge's (``judge_*``; ``learning_judge`` off without one)."""
    out: dict[str, Any] = {'learning_enabled': True, 'correction_file': str(correction_file),
                           'learning_save_period_s': save_period_s, 'correction_publish_period_s': PUBLISH_PERIOD_S,
                           'diagnostics_period_s': PUBLISH_PERIOD_S}
    judge = getattr(learn, 'judge', None)
    for (prefix, cls), settings in zip(FEEDFORWARD_PREFIXED, (learn.correction, learn.learning, judge), strict=True):
        settings = settings if settings is not None else cls()
        out.update({prefix + name: getattr(settings, name) for name in settings.__dataclass_fields__})
    if judge is None:   # (the study's --learn-judge off: the residual guard alone)
        out['learning_judge'] = 'off'
    return out


class _FileWatch:
    """The correction file, read with the library's reader whenever it changes."""

    def __init__(self, path: Path, identity: ModelIdentity) -> None:
        self.path, self.identity = path, identity
        self.key: tuple[int, int, int] | None = None
        self.correction: Correction | None = None
        self.error: str | None = None

    def poll(self) -> bool:
        """Read the file if it changed; True if it did."""
        try:
            st = self.path.stat()
        except FileNotFoundError:
            changed, self.key, self.correction, self.error = self.key is not None, None, None, 'no file'
            return changed
        key = (st.st_ino, st.st_mtime_ns, st.st_size)
        if key == self.key:
            return False
        self.key = key
        try:
            self.correction, self.error = load_correction(self.path, expected=self.identity), None
        except CorrectionError as err:
            self.correction, self.error = None, str(err)
        return True

    def samples(self) -> int:
        """Samples in the file as last read (0: no readable file) [-]."""
        return int(self.correction.summary()['samples']) if self.correction is not None else 0


def live_learning(*, sup: Any, watcher: Any, node_args: list[str], work_dir: Path, inputs: Any, learn: Any,
                  run_sim: Callable[[str, Callable[[], None]], Any], wait_connected: Callable[[], None],
                  log: Callable[[str], None], timeout_s: float
                  ) -> tuple[dict[str, Any], dict[str, Any], Correction | None]:
    """Steps 1-4 of the module docstring; returns (the ``learning`` report, the ``gimbal_sim`` runs by case, the
    correction the file held when the node was restarted: None if unreadable).

    ``run_sim(case, tick)`` runs ``gimbal_sim`` with the feedforward (calling ``tick`` while it waits, about every
    0.1 s) and returns its loaded run; ``wait_connected`` waits for the graph. Node failures raise
    GimbalFrictionError; what the learning did or did not do is in the report.
    """
    from diagnostic_msgs.msg import DiagnosticArray

    joint = inputs.axis_name
    path = work_dir / CORRECTION_FILE
    if path.exists():
        msg = (f'{path} already exists: live learning starts from an empty correction (delete it or choose another '
               '--out)')
        raise GimbalFrictionError(msg)

    def node_args_with(name: str, save_period_s: float) -> list[str]:
        params = work_dir / name
        doc = {'friction_feedforward': {'ros__parameters': learning_parameters(learn, path, save_period_s)}}
        params.write_text(yaml.safe_dump(doc, sort_keys=False), encoding='utf-8')
        return [*node_args, '--params-file', str(params)]

    states: list[CorrectionState] = []
    learning: list[tuple[float, dict[str, str]]] = []

    def on_correction(msg: Any) -> None:
        s = correction_state(msg, joint)
        if s is not None:
            states.append(s)

    def on_diagnostics(msg: Any) -> None:
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        learning.extend((stamp, {kv.key: kv.value for kv in st.values}) for st in msg.status
                        if st.name == LEARNING_STATUS)

    node = watcher.node
    node.create_subscription(DiagnosticArray, topics.CORRECTION, on_correction, 100)
    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics, 100)
    files = _FileWatch(path, model_identity({joint: inputs.axis}))
    seen = {'periodic_samples': 0}

    def spin_until(cond: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not cond():
            sup.check_alive()
            if time.monotonic() > deadline:
                msg = f'live learning: {what} within {timeout_s:.0f} s; see {work_dir / "logs"}'
                raise GimbalFrictionError(msg)
            watcher.spin(0.1)

    def started(t0: float) -> None:
        wait_connected()
        spin_until(lambda: any(s.stamp_s >= t0 for s in states), 'no correction message from the new node')

    def settled(t_end: float) -> bool:
        """The node has learned what it received: its last two learning statuses (both after ``t_end``) with nothing
        pending or in a fit and the same counts, and a correction message with those samples."""
        last = [v for stamp, v in learning if stamp >= t_end][-2:]
        if len(last) < 2 or not states or states[-1].stamp_s < t_end:
            return False
        counts = [(v.get('samples_pending'), v.get('samples_in_fit'), v.get('samples_used'),
                   v.get('samples_in_correction')) for v in last]
        return (counts[0] == counts[1] and counts[0][:2] == ('0', '0')
                and str(states[-1].samples) == counts[0][3])

    def tick() -> None:
        watcher.spin(0.1)
        if files.poll() and not seen['periodic_samples'] and files.samples() > 0:
            seen['periodic_samples'] = files.samples()

    log(f'loop-study --live: friction_feedforward learning into {path}')
    t_first = time.time()
    sup.start_as(_FIRST, 'friction_feedforward', node_args_with('learning.yaml', SAVE_PERIOD_S))
    started(t_first)
    runs = {LEARNING_CASE: run_sim(LEARNING_CASE, tick)}
    t_end = time.time()
    spin_until(lambda: settled(t_end), 'the learning did not settle after the run')
    last = states[-1]
    # the periodic save catches up with what was learned (before the stop: the stop's own save proves nothing here)
    def saved_all() -> bool:
        tick()
        return files.samples() >= last.samples

    spin_until(saved_all, 'no periodic save of what was learned')
    code = sup.stop(_FIRST)
    files.poll()
    shutdown_samples, shutdown_error = files.samples(), files.error
    saved = files.correction
    log(f'loop-study --live: friction_feedforward stopped (code {code}); restarting it on {path}')
    t_restart = time.time()
    sup.start_as(_RESTART, 'friction_feedforward', node_args_with('learning_resumed.yaml', HOLD_SAVE_PERIOD_S))
    started(t_restart)
    resumed = next(s for s in states if s.stamp_s >= t_restart)
    runs[RESUMED_CASE] = run_sim(RESUMED_CASE, lambda: watcher.spin(0.1))
    t_end = time.time()
    spin_until(lambda: settled(t_end), 'the learning did not settle after the resumed run')
    files.poll()
    before_stop = (files.key, files.samples())
    last_resumed = states[-1]
    code_resumed = sup.stop(_RESTART)
    files.poll()
    first = [s for s in states if s.stamp_s < t_restart]
    second = [s for s in states if s.stamp_s >= t_restart]
    report = learning_report(
        first=first, second=second, resumed=resumed, saved=saved, joint=joint, path=path,
        periodic_samples=seen['periodic_samples'], stop_code=code, shutdown_samples=shutdown_samples,
        file_error=shutdown_error, resumed_stop_code=code_resumed,
        unsaved_at_stop=last_resumed.samples - before_stop[1], file_changed_at_stop=files.key != before_stop[0],
        resumed_shutdown_samples=files.samples(), resumed_file_error=files.error)
    return report, runs, saved


def learning_report(*, first: list[CorrectionState], second: list[CorrectionState], resumed: CorrectionState,
                    saved: Correction | None, joint: str, path: Path, periodic_samples: int, stop_code: int | None,
                    shutdown_samples: int, file_error: str | None, resumed_stop_code: int | None,
                    unsaved_at_stop: int, file_changed_at_stop: bool, resumed_shutdown_samples: int,
                    resumed_file_error: str | None) -> dict[str, Any]:
    """The ``learning`` object of the live section (see docs/closed-loop.md); ``failure`` is None or one line.

    ``stop_code``, ``shutdown_samples`` and ``file_error``: the first node's SIGINT and the file after it;
    ``resumed_*``, ``unsaved_at_stop`` (samples the restarted node learned, never saved periodically) and
    ``file_changed_at_stop``: the restarted node's SIGINT and the file after it.
    """
    samples_first = first[0].samples if first else 0
    samples_last = first[-1].samples if first else 0
    resumed_last = second[-1].samples if second else 0
    distinct = len({s.key() for s in first})
    changed = distinct >= 2 and samples_last > samples_first
    complete = file_error is None and shutdown_samples > 0 and shutdown_samples >= samples_last
    resumed_complete = (resumed_file_error is None and resumed_shutdown_samples >= resumed_last
                        and resumed_stop_code == 0)
    saved_at_shutdown = resumed_complete and unsaved_at_stop > 0 and file_changed_at_stop
    # the restart resumes: its first message holds the file's cells with their samples, and applied values equal to
    # the file's or moved from them towards the learned ones (the learner steps while it runs; 6 digits on the topic)
    want = file_cells(saved, joint) if saved is not None else {}
    diff = max((abs(resumed.cells[k][1] - v) for k, (_, v, _, _) in want.items() if k in resumed.cells),
               default=math.nan)
    same_cells = bool(want) and set(resumed.cells) == set(want) and all(
        resumed.cells[k][0] == n and lo - 5e-6 * abs(lo) - 1e-12 <= resumed.cells[k][1] <= hi + 5e-6 * abs(hi) + 1e-12
        for k, (n, _, lo, hi) in want.items())
    restart_resumed = same_cells and resumed.samples == shutdown_samples > 0
    failure = None
    if not first:
        failure = 'friction_feedforward published no correction message'
    elif not changed:
        failure = f'the correction did not change ({samples_first} -> {samples_last} samples, {distinct} states)'
    elif not periodic_samples:
        failure = f'no periodic save of the correction file {path} with samples during the run'
    elif stop_code != 0:
        failure = f'friction_feedforward exited with code {stop_code} at SIGINT'
    elif not complete:
        failure = (f'after the stop the correction file {path} does not hold what was learned '
                   f'({file_error or f"{shutdown_samples} samples, the last message had {samples_last}"})')
    elif not restart_resumed:
        failure = (f'the restart did not resume the file: first message {resumed.samples} samples in '
                   f'{resumed.cells_with_data} cells, the file {shutdown_samples} samples in {len(want)} cells '
                   f'(largest applied-value difference {diff:.3g} N*m)')
    elif resumed_last <= resumed.samples:
        failure = f'the restarted friction_feedforward learned nothing in its run ({resumed.samples} samples)'
    elif resumed_stop_code != 0:
        failure = f'the restarted friction_feedforward exited with code {resumed_stop_code} at SIGINT'
    elif not resumed_complete:
        held = resumed_file_error or f'{resumed_shutdown_samples} samples, its last message had {resumed_last}'
        failure = f"after the restarted node's stop the correction file {path} does not hold what it learned ({held})"
    elif not saved_at_shutdown:
        failure = f'{unsaved_at_stop} samples learned after the restart but no save at shutdown'
    return {
        'correction_file': str(path),
        'correction_messages': len(first), 'distinct_states': distinct, 'correction_changed': changed,
        'samples_first': samples_first, 'samples_last': samples_last,
        'cells_with_data_last': first[-1].cells_with_data if first else 0,
        'max_correction_nm': max((s.max_abs_correction_nm for s in first), default=0.0),
        'file_saved_periodic': periodic_samples > 0, 'periodic_save_samples': periodic_samples,
        'stop_exit_code': stop_code, 'shutdown_save_samples': shutdown_samples,
        'restart_resumed': restart_resumed, 'restart_samples': resumed.samples,
        'restart_cells_with_data': resumed.cells_with_data, 'restart_max_value_difference_nm': diff,
        'resumed_run_correction_messages': len(second),
        'resumed_run_samples_last': resumed_last,
        'resumed_stop_exit_code': resumed_stop_code, 'unsaved_samples_at_stop': unsaved_at_stop,
        'file_saved_at_shutdown': saved_at_shutdown, 'resumed_shutdown_save_samples': resumed_shutdown_samples,
        'ok': failure is None, 'failure': failure,
    }
