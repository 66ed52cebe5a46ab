"""The keeping of a learned correction in service: loaded, learned, saved in the background (no rclpy, no topics).

One job in one module: :class:`CorrectionKeeper`, what ``friction_feedforward`` (or a controller's own process)
needs around a :class:`~gimbal_friction.feedforward.correction.learner.Learner`: a file read at start (stale
temporaries of an interrupted save removed first; a refused file leaves the pure model and is never overwritten
while it exists), settings of the same layout changed while running, a model change that empties it, and saves
that never delay the caller (a snapshot written by a thread, atomically).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Mapping

from gimbal_friction.feedforward.correction.core import Correction
from gimbal_friction.feedforward.correction.file import exists, load_file, remove_stale_temporaries, save
from gimbal_friction.feedforward.correction.learner import Learner
from gimbal_friction.feedforward.correction.settings import (
    LAYOUT,
    CorrectionError,
    CorrectionSettings,
    LearningSettings,
    ModelIdentity,
)
from gimbal_friction.feedforward.correction.worker import BackgroundLearner
from gimbal_friction.physics.params import AxisParams

__all__ = ['CorrectionKeeper']


class CorrectionKeeper:
    """A learned correction loaded, learned and saved (see the module notes).

    ``identity`` is the model the correction belongs to, ``settings`` the correction's parameters (a file keeps its
    rows but takes the parameters' bound, prior, gate and guard; a file with another layout is refused).
    :attr:`load_error` holds the one-line reason a file was refused (the correction is then empty = the pure model,
    and that file is never overwritten while it exists); :attr:`load_note` what a reader should know of a file that
    was accepted (a deliberate hand edit, an older version converted).
    """

    def __init__(self, identity: ModelIdentity, settings: CorrectionSettings, learning: LearningSettings,
                 model: Mapping[str, AxisParams] | None = None, background: bool = False) -> None:
        self.identity, self.settings = identity, settings
        #: the model's parameters per joint (of ``identity``): a file read is checked against them (None: its identity)
        self.model = model
        #: with ``background``, refits, reports and saves run in the worker ``learning.fit_worker`` names
        #: (:class:`~gimbal_friction.feedforward.correction.worker.BackgroundLearner`; ``inline``: in the step)
        self.learner: Learner = (BackgroundLearner(Correction(settings, identity), learning, learning.fit_worker)
                                 if background and learning.fit_worker != 'inline' else
                                 Learner(Correction(settings, identity), learning))
        self.load_error: str | None = None
        self.load_note: str | None = None
        self.loaded_from: str | None = None
        self.removed_temporaries: list[str] = []   #: stale temporaries removed at start
        self._refused_path: str | None = None
        self.dirty = False                         #: changed since the last save
        self.saves = 0                             #: files written [-]
        self.last_save_time: float | None = None   #: wall-clock time of the last save [s since the epoch]
        self.last_save_path = ''
        self.last_save_error: str | None = None
        #: wall-clock time of the snapshot the last completed save holds: what a crash loses is what came after
        #: it (None: nothing saved yet) [s since the epoch]
        self.saved_state_time: float | None = None
        self.last_save_duration_s: float | None = None   #: snapshot to the file renamed in place, last save [s]
        self._started = time.time()
        self._writer: threading.Thread | None = None

    @property
    def correction(self) -> Correction:
        """The correction learned and applied."""
        return self.learner.correction

    def read(self, path: str) -> Correction:
        """The correction in ``path`` for this model and layout, with this keeper's settings (:attr:`load_note`
        set).

        Raises:
            CorrectionError: one line naming the file, the cause and the fix.
        """
        loaded = load_file(path, expected=self.identity, model=self.model)
        c = loaded.correction
        for name in LAYOUT:
            have, want = getattr(c.settings, name), getattr(self.settings, name)
            if have != want:
                raise CorrectionError(f'correction file {path}: {name} is {have!r}, the parameter correction_{name} '
                                      f'is {want!r}: set the parameter to match or delete the file')
        self.load_note = loaded.note
        return self.adopt(c)

    def adopt(self, c: Correction) -> Correction:
        """``c`` with this keeper's settings (its rows, scores and applied terms kept)."""
        return c if c.settings == self.settings else c.with_settings(self.settings)

    def start(self, path: str) -> None:
        """At start-up: remove the stale temporaries of an interrupted save of ``path``, then load it if it exists
        ('' or absent: an empty correction). A refused file leaves the correction empty with :attr:`load_error`
        set; nothing raises."""
        if not path:
            return
        self.removed_temporaries = [str(p) for p in remove_stale_temporaries(path)]
        try:
            if not exists(path):   # (a symbolic link loop is refused, not taken for no file yet)
                return
            self.replace(self.read(path))
            self.loaded_from = path
        except CorrectionError as err:
            self.load_error, self._refused_path = str(err), path

    def replace(self, c: Correction) -> None:
        """Learn on from ``c`` (learner state and counters kept)."""
        self.learner.replace(c)  # (a new correction, new buffers)
        self.load_error = self._refused_path = None

    def set_settings(self, settings: CorrectionSettings) -> None:
        """New bound, prior, gate or guard (same layout): the rows are kept, the targets follow."""
        self.settings = settings
        if isinstance(self.learner, BackgroundLearner):
            self.learner.set_settings(settings)
            return
        self.learner.flush()
        self.learner.correction = self.adopt(self.correction)

    def set_identity(self, identity: ModelIdentity, model: Mapping[str, AxisParams] | None = None) -> bool:
        """The model changed (``model``: its parameters per joint): a correction learned against the old one does not
        apply; start empty. True if it held something."""
        if identity == self.identity:
            return False
        self.model = model
        had = (bool(self.learner.correction_summary()['samples']) or self.learner.pending > 0
               or self.load_error is not None)
        self.identity = identity
        self.replace(Correction(self.settings, identity))
        self.loaded_from = self.load_note = None
        self.dirty = True
        return had

    def save(self, path: str, background: bool = False) -> bool:
        """Save atomically to ``path`` if something changed; True if a save was made (or, with ``background``,
        started: a snapshot is written by a thread, so the disk's fsync never delays the caller; a save still running
        is not started twice). A failure (or a file refused at load, never overwritten while it exists) is kept in
        :attr:`last_save_error`."""
        if not path or not (self.dirty or self.learner.pending):
            return False
        if self._refused_path is not None and os.path.realpath(path) == os.path.realpath(self._refused_path) \
                and os.path.lexists(path):
            self.last_save_error = (f'not saved: {path} was refused at load and is not overwritten; delete it or '
                                    'set another file')
            return False
        if isinstance(self.learner, BackgroundLearner):   # (the worker holds the rows: it writes the file)
            self.dirty = False
            self.learner.request_save(path)
            if not background:
                self.learner.drain()
            return self.collect() if not background else True
        if self._writer is not None and self._writer.is_alive():
            if background:
                return False
            self._writer.join()
        self.dirty = False
        taken = time.time()
        snapshot = self.learner.snapshot()
        if not background:
            return self._write(snapshot, path, taken)
        self._writer = threading.Thread(target=self._write, args=(snapshot, path, taken), name='correction_save',
                                        daemon=True)
        self._writer.start()
        return True

    def _write(self, c: Correction, path: str, taken: float) -> bool:
        try:
            save(c, path)
        except CorrectionError as err:
            self.last_save_error, self.dirty = str(err), True
            return False
        done = time.time()
        self.saves, self.last_save_error = self.saves + 1, None
        self.last_save_time, self.last_save_path = done, path
        self.saved_state_time, self.last_save_duration_s = taken, done - taken
        return True

    def unsaved_s(self, now: float | None = None) -> float:
        """What a crash at ``now`` (wall clock, default now) would lose [s]: the time since the snapshot the last
        completed save holds (since start when nothing was saved yet); 0 when nothing changed since it. A save
        still being written protects nothing until its file is renamed in place."""
        now = time.time() if now is None else now
        writing = self._writer is not None and self._writer.is_alive()
        if not (self.dirty or self.learner.pending or writing):
            return 0.0
        since = self.saved_state_time if self.saved_state_time is not None else self._started
        return max(0.0, now - since)

    def wait(self) -> None:
        """Wait for a background save to finish."""
        if self._writer is not None:
            self._writer.join()
        if isinstance(self.learner, BackgroundLearner):
            self.learner.drain()
            self.collect()

    def poll(self) -> bool:
        """Take a refit finished in the background in (never waits) and the outcome of its save; True if an
        applied term changed (then :attr:`dirty`)."""
        changed = self.learner.poll()
        if changed:
            self.dirty = True
        self.collect()
        return changed

    def collect(self) -> bool:
        """Record the saves a background worker made or failed (:attr:`saves`, :attr:`last_save_error`, ...); True
        if the last of them was written."""
        outcomes = getattr(self.learner, 'save_outcomes', None)
        ok = False
        while outcomes:
            path, error, when = outcomes.pop(0)
            if error is not None:
                self.last_save_error, self.dirty, ok = error, True, False
            else:
                self.saves, self.last_save_error, ok = self.saves + 1, None, True
                self.last_save_time, self.last_save_path = when, path
        return ok

    def close(self) -> None:
        """Stop a background worker (never waits)."""
        self.learner.close()
