"""Refits of in-service learning off the caller's thread: a worker that owns the learning state (pure numpy; the
child process imports no rclpy).

One job in one module: :class:`BackgroundLearner`, a :class:`~gimbal_friction.feedforward.correction.learner.Learner`
whose step is split. The caller's thread (a node's only executor thread) keeps the cheap part: the gate, the pending
samples and the step's rate limit. The expensive part (scoring and keeping the samples, the refit, the search for
ripple periods, the summary and the cells a status reports, the save of the file) runs in a worker, one job at a time:

- ``process`` (the default): a child process started with the ``spawn`` context, at a lower priority
  (:func:`~gimbal_friction.feedforward.low_priority.lower_priority`, before its imports); it holds the whole
  correction (its rows) and the caller only a copy of what the feedforward reads (the applied terms and their
  lookups);
- ``thread``: the same worker loop in a thread of the caller's process (shares the caller's interpreter lock);
- ``inline``: no worker (the plain :class:`Learner`).

:meth:`BackgroundLearner.step` sends a job (never waits: with a job in flight the samples wait for the next step);
:meth:`BackgroundLearner.poll`, called from a short timer, takes a finished one in whole: for every joint the applied
terms, the candidate, the target, the ripple periods and the lookups at once, so the feedforward never reads a fit
half taken in. A job not answered within ``fit_timeout_s`` is counted as timed out (a process is stopped and
restarted; a thread cannot be stopped: its result is taken when it comes); a worker that dies or a fit that raises is
counted as failed. Either way the feedforward keeps the applied correction it had; a restarted worker starts from
the caller's copy, so the rows learned since it was last given one (at start, after a reset or a file loaded) are
lost and counted in :attr:`BackgroundLearner.samples_lost`.

The worker runs the very functions the inline step runs
(:func:`~gimbal_friction.feedforward.correction.learner.learn_step`), on the same samples in the same order: the same
numbers.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
import types
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.feedforward.correction.core import Correction
from gimbal_friction.feedforward.correction.file import save
from gimbal_friction.feedforward.correction.learner import Learner, learn_rows, learn_step
from gimbal_friction.feedforward.correction.settings import CorrectionError, CorrectionSettings, LearningSettings
from gimbal_friction.feedforward.low_priority import run_fit_worker

__all__ = ['NICE', 'BackgroundLearner', 'Job', 'Result', 'run_job', 'serve']

Array = NDArray[np.float64]
#: how much lower the child process's priority is than the caller's (``os.nice``) [-]
NICE = 10
#: a worker that does not say it is ready within this long after its start is counted as failed [s]
START_TIMEOUT_S = 60.0


@dataclass
class Job:
    """What the worker is asked to do: learn ``rows`` (per joint, :meth:`Learner.take_pending`), then refit and move
    the applied terms by at most ``limit_nm`` [N·m] (None: learn only, no refit); first, take ``sync`` as the whole
    correction and ``settings`` as its settings, if given; last, save to ``save_path`` if given."""

    generation: int
    rows: dict[str, Array]
    limit_nm: float | None
    sync: Correction | None = None
    settings: CorrectionSettings | None = None
    save_path: str | None = None


@dataclass
class Result:
    """What the worker answers: per joint what the feedforward reads, and the reports of the correction after the job
    (its summary and cells), the save's outcome and the fit's duration [s]; ``error`` if the job raised."""

    generation: int
    changed: bool = False
    joints: dict[str, dict[str, Any]] = field(default_factory=dict)
    summary: dict[str, Any] | None = None
    cells: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    save_path: str | None = None
    save_error: str | None = None
    save_time: float | None = None
    seconds: float = 0.0
    error: str | None = None


def run_job(master: Correction | None, job: Job) -> tuple[Correction, Result]:
    """Do ``job`` on ``master`` (in place; ``job.sync`` replaces it): the correction after it and the answer."""
    t0 = time.perf_counter()
    if job.sync is not None:
        master = job.sync
    if master is None:
        raise CorrectionError('fit worker: a job without a correction to learn into')
    if job.limit_nm is None:
        learn_rows(master, job.rows)
        changed = False
    else:
        changed = learn_step(master, job.rows, job.limit_nm)
    if job.settings is not None and job.settings != master.settings:
        master = master.with_settings(job.settings)
        changed = True
    res = Result(job.generation, changed)
    for j in master.identity.joints:
        st = master.joint(j)
        res.joints[j] = {'applied': st.applied, 'candidate': st.candidate, 'target': st.target,
                         'searched_at': st.searched_at, 'angle_range': st.angle_range, 'bin_ranges': st.bin_ranges,
                         'periods': master.periods[j], 'lookup': master.lookups[j]}
        res.cells[j] = master.cells(j)
    res.summary = master.summary()
    if job.save_path:
        res.save_path = job.save_path
        try:
            save(master, job.save_path)
            res.save_time = time.time()
        except CorrectionError as err:
            res.save_error = str(err)
    res.seconds = time.perf_counter() - t0
    return master, res


def serve(conn: Any) -> None:
    """The worker's loop: says it is ready (with its pid and whether rclpy is loaded), then answers jobs until
    ``None`` or the other end closes. A job that raises is answered with the error (the worker then needs a
    ``sync``)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)   # (the node's Ctrl-C is the node's to handle)
    conn.send(('ready', os.getpid(), 'rclpy' in sys.modules))
    master: Correction | None = None
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        try:
            master, res = run_job(master, job)
        except Exception:
            master, res = None, Result(job.generation, error=traceback.format_exc(limit=-3).strip())
        try:
            conn.send(res)
        except (EOFError, OSError):
            return


@contextlib.contextmanager
def _bare_main() -> Iterator[None]:
    """``spawn`` runs the parent's main script again in the child (a node's imports rclpy): the child needs only this
    module, so it is shown a bare ``__main__`` while it starts."""
    main = sys.modules['__main__']
    sys.modules['__main__'] = types.ModuleType('__main__')
    try:
        yield
    finally:
        sys.modules['__main__'] = main


class _Worker:
    """One worker (a child process or a thread) and the caller's end of its pipe."""

    def __init__(self, mode: str) -> None:
        self.mode = mode
        self.ready = False
        self.pid: int | None = None
        self.rclpy_loaded = False
        self.started_at = time.monotonic()
        if mode == 'process':
            ctx = multiprocessing.get_context('spawn')
            self.conn, child = ctx.Pipe()
            self.proc: Any = ctx.Process(target=run_fit_worker, args=(child, NICE), name='correction_fit',
                                         daemon=True)
            with _bare_main():
                self.proc.start()
            child.close()
        else:
            self.conn, child = multiprocessing.Pipe()
            self.proc = threading.Thread(target=serve, args=(child,), name='correction_fit', daemon=True)
            self.proc.start()

    def alive(self) -> bool:
        return bool(self.proc.is_alive())

    def check_ready(self) -> bool:
        """Read the worker's hello if it came (never waits)."""
        if not self.ready and self.conn.poll():
            _, self.pid, self.rclpy_loaded = self.conn.recv()
            self.ready = True
        return self.ready

    def stop(self, kill: bool = False) -> None:
        """Ask the worker to end (``kill``: a process is killed at once); never waits for it."""
        if kill and self.mode == 'process':
            with contextlib.suppress(OSError, ValueError):
                self.proc.kill()
        else:
            with contextlib.suppress(OSError, ValueError):
                self.conn.send(None)
        with contextlib.suppress(OSError):
            self.conn.close()


class BackgroundLearner(Learner):
    """A :class:`Learner` whose refits run in a worker (see the module notes); ``worker`` is ``process`` or
    ``thread``.

    Counters (for a status): :attr:`fits` answered, :attr:`fit_timeouts`, :attr:`fit_failures` (the worker died or the
    fit raised; the last reason in :attr:`last_fit_error`), :attr:`samples_lost` (see the module notes),
    :attr:`last_fit_s` (the last fit's duration in the worker [s]), :attr:`worker_restarts`.
    """

    def __init__(self, correction: Correction, settings: LearningSettings, worker: str = 'process') -> None:
        super().__init__(correction, settings)
        if worker not in ('process', 'thread'):
            raise CorrectionError(f'fit worker {worker!r}: must be process or thread')
        self.worker_mode = worker
        self.fits = self.fit_timeouts = self.fit_failures = self.samples_lost = self.worker_restarts = 0
        self.last_fit_s = math.nan
        self.last_fit_error: str | None = None
        #: saves the worker made or failed: (path, error or None, wall-clock time [s since the epoch] or None)
        self.save_outcomes: list[tuple[str, str | None, float | None]] = []
        self._worker: _Worker | None = None
        self._generation = 0
        self._sync = True           # the worker must be given this side's correction (it is the whole truth)
        self._settings_change: CorrectionSettings | None = None
        self._save_path: str | None = None
        self._job: Job | None = None
        self._sent_at = 0.0
        self._timed_out = False
        self._report: tuple[dict[str, Any], dict[str, list[dict[str, Any]]]] | None = None
        #: this side's reports until the worker's come (made once per generation: ~0.1 s for a large correction)
        self._own: tuple[int, dict[str, Any], dict[str, list[dict[str, Any]]]] | None = None

    # ------------------------------------------------------------------ state
    @property
    def busy(self) -> bool:
        """A job is in flight."""
        return self._job is not None

    @property
    def in_flight(self) -> int:
        """Samples sent with the job in flight [-]."""
        return sum(len(a) for a in self._job.rows.values()) if self._job is not None else 0

    @property
    def worker_pid(self) -> int | None:
        """The worker's process id once it said it is ready (a thread: the caller's)."""
        return self._worker.pid if self._worker is not None and self._worker.ready else None

    @property
    def worker_rclpy_loaded(self) -> bool | None:
        """Whether rclpy was loaded in the worker when it said it was ready (None: not yet)."""
        return self._worker.rclpy_loaded if self._worker is not None and self._worker.ready else None

    # ------------------------------------------------------------------ the cheap part, on the caller's thread
    def start(self) -> None:
        """Start the worker if none runs (it says when it is ready; :meth:`poll` reads it)."""
        if self._worker is None:
            self._worker = _Worker(self.worker_mode)

    def _ready(self) -> bool:
        self.start()
        return self._worker is not None and self._worker.check_ready()

    def step(self, now_s: float) -> bool:
        """Send the step's job to the worker (the samples stay pending while a job is in flight or the worker
        starts); never waits, so never True: :meth:`poll` takes the result in."""
        if self.busy or not self._ready():
            return False
        job = self.take_step(now_s)
        if job is not None:
            self._send(*job)
        elif self._sync or self._save_path or (self.frozen and self.pending):
            # (at the first step, the correction alone: its reports come back at once, not after a long refit)
            self._send(self.take_pending(), None)
        return False

    def flush(self) -> None:
        """Nothing here: the pending samples go to the worker with the next job (:meth:`drain` waits for them)."""

    def _send(self, rows: dict[str, Array], limit_nm: float | None) -> None:
        if self._worker is None:
            return
        job = Job(self._generation, rows, limit_nm, self.correction if self._sync else None, self._settings_change,
                  self._save_path)
        try:
            self._worker.conn.send(job)
        except (OSError, ValueError) as err:
            self._job = job
            self._lost(f'fit worker died ({err})', timeout=False)
            return
        self._sync, self._settings_change, self._save_path = False, None, None
        self._job, self._sent_at, self._timed_out = job, time.monotonic(), False

    def poll(self) -> bool:
        """Take a finished job in whole, count a timed-out or failed one; never waits. True if an applied term
        changed."""
        w = self._worker
        if w is None:
            return False
        if not w.ready:
            if not w.check_ready() and (not w.alive() or time.monotonic() - w.started_at > START_TIMEOUT_S):
                self._lost('fit worker did not start', timeout=False)
            return False
        if self._job is None:
            if self._save_path:
                self._send(self.take_pending(), None)
            return False
        try:
            done = w.conn.poll()
            res = w.conn.recv() if done else None
        except (EOFError, OSError):
            self._lost('fit worker died', timeout=False)
            return False
        if res is None:
            if not w.alive():
                self._lost('fit worker died', timeout=False)
            elif not self._timed_out and time.monotonic() - self._sent_at > self.settings.fit_timeout_s:
                if self.worker_mode == 'process':
                    self._lost(f'fit took more than {self.settings.fit_timeout_s:g} s: worker restarted', timeout=True)
                else:   # (a thread cannot be stopped: counted, its result taken when it comes)
                    self.fit_timeouts += 1
                    self.last_fit_error = f'fit took more than {self.settings.fit_timeout_s:g} s'
                    self._timed_out = True
            return False
        return self._take(res)

    def _take(self, res: Result) -> bool:
        self._job = None
        if res.save_path is not None:
            self.save_outcomes.append((res.save_path, res.save_error, res.save_time))
        if res.error is not None:
            self.fit_failures += 1
            self.last_fit_error = res.error.splitlines()[-1]
            self._sync = True      # (the worker dropped its correction)
            return False
        self.fits += 1
        self.last_fit_s = res.seconds
        if res.generation != self._generation:
            return False           # (this side changed the correction meanwhile: the worker is given it next)
        c = self.correction
        for j, jf in res.joints.items():
            st = c.joint(j)
            st.applied, st.candidate, st.target = jf['applied'], jf['candidate'], jf['target']
            st.searched_at, st.angle_range, st.bin_ranges = jf['searched_at'], jf['angle_range'], jf['bin_ranges']
            c.periods[j] = jf['periods']
            old, new = c.lookups[j], jf['lookup']
            if old is not None:
                c._saturations_before += old.saturations
            if new is not None:
                new.saturations = 0
            c.lookups[j] = new
        if res.summary is not None:
            self._report = (res.summary, res.cells)
        return res.changed

    def _lost(self, reason: str, timeout: bool) -> None:
        """The worker is gone or stopped: counted; a new one starts at the next step from this side's copy."""
        if timeout:
            self.fit_timeouts += 1
        else:
            self.fit_failures += 1
        self.last_fit_error = reason
        if self._job is not None:
            self.samples_lost += self.in_flight
            if self._job.save_path:
                self.save_outcomes.append((self._job.save_path, f'not saved: {reason}', None))
            if self._job.settings is not None and self._settings_change is None:
                self._settings_change = self._job.settings
        self._job = None
        if self._worker is not None:
            self._worker.stop(kill=True)
            self._worker = None
            self.worker_restarts += 1
        self._sync = True

    # ------------------------------------------------------------------ changes made on this side
    def replace(self, correction: Correction) -> None:
        super().replace(correction)
        self._changed_here()

    def reset(self) -> None:
        super().reset()
        self._changed_here()

    def set_settings(self, settings: CorrectionSettings) -> None:
        """Other settings of the same layout: this side's copy now, the worker's with the next job."""
        self.correction = self.correction.with_settings(settings)
        self._settings_change = None if self._sync else settings
        self._report = self._own = None

    def _changed_here(self) -> None:
        """This side's correction is the whole truth again (a file loaded, a reset): the worker is given it with
        the next job, a job in flight is not taken in."""
        self._generation += 1
        self._sync, self._settings_change, self._report = True, None, None

    def request_save(self, path: str) -> bool:
        """Have the worker save the correction (every sample learned) to ``path`` with the next job (at once when
        none is in flight); the outcome arrives in :attr:`save_outcomes`."""
        self._save_path = path
        if not self.busy and self._ready():
            self._send(self.take_pending(), None)
        return True

    def drain(self, timeout_s: float | None = None) -> None:
        """Wait (at most ``timeout_s`` [s], default ``fit_timeout_s``, per job) for the job in flight, then send the
        pending samples (and a save asked for) and wait for them too. For shutdown: this blocks."""
        limit = self.settings.fit_timeout_s if timeout_s is None else timeout_s
        for _ in range(2):
            t0 = time.monotonic()
            if not self._job and not (self.pending or self._save_path):
                return
            while self._worker is not None and not self._worker.ready and time.monotonic() - t0 < limit:
                self._worker.conn.poll(0.05)
                self.poll()
            if not self.busy and (self.pending or self._save_path):
                if self._worker is None or not self._ready():
                    return
                self._send(self.take_pending(), None)
            while self.busy and time.monotonic() - t0 < limit:
                w = self._worker
                if w is None:
                    break
                with contextlib.suppress(OSError, EOFError):
                    w.conn.poll(0.05)
                self.poll()
            if self.busy:
                self._lost(f'fit took more than {limit:g} s at shutdown', timeout=True)
                return

    def close(self) -> None:
        """Stop the worker (never waits)."""
        if self._worker is not None:
            self._worker.stop()
            self._worker = None

    # ------------------------------------------------------------------ reports
    def correction_summary(self) -> dict[str, Any]:
        """The summary the worker made with the last fit (this side's until one came), with this side's count of
        clipped lookups."""
        summary = self._report[0] if self._report is not None else self._own_report()[1]
        return {**summary, 'lookup_saturations': self.correction.lookup_saturations}

    def correction_cells(self, joint: str) -> list[dict[str, Any]]:
        if self._report is not None:
            return self._report[1][joint]
        cells = self._own_report()[2]
        if joint not in cells:
            cells[joint] = super().correction_cells(joint)
        return cells[joint]

    def _own_report(self) -> tuple[int, dict[str, Any], dict[str, list[dict[str, Any]]]]:
        if self._own is None or self._own[0] != self._generation:
            self._own = (self._generation, super().correction_summary(), {})
        return self._own
