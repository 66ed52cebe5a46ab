"""What a crash during a save loses (docs/robustness.md, issue 31 item 11): the samples learned after the snapshot the
last *completed* save holds. A save being written protects nothing until its file is renamed in place, so the loss
is the save period plus the duration of a save; the keeper says both (``last_save_duration_s``, ``unsaved_s``)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from gimbal_friction.feedforward.correction import (
    CorrectionKeeper,
    CorrectionSettings,
    LearningSettings,
    load,
    model_identity,
)
from gimbal_friction.feedforward.correction import keeper as keeper_module
from gimbal_friction.physics.params import AxisParams

V = 0.035   # [rad/s]


class Clock:
    """A wall clock the test moves by hand [s since the epoch]."""

    def __init__(self) -> None:
        self.now = 1_800_000_000.0

    def time(self) -> float:
        return self.now


def learn(k: CorrectionKeeper, n: int) -> None:
    for _ in range(n):
        assert k.learner.update('elevation', -40.0, V, 0.0, 1e-4, 3e-3, now_s=0.0) is None
        k.dirty = True


def test_a_crash_during_a_save_loses_what_came_after_the_last_completed_snapshot(tmp_path: Path,
                                                                                 monkeypatch: Any):
    clock = Clock()
    monkeypatch.setattr(keeper_module, 'time', clock)
    path = str(tmp_path / 'c.yaml')
    k = CorrectionKeeper(model_identity({'elevation': AxisParams()}), CorrectionSettings(), LearningSettings())
    assert k.unsaved_s() == 0.0 and k.saved_state_time is None and k.last_save_duration_s is None
    learn(k, 30)
    clock.now += 0.2
    assert k.unsaved_s() == pytest.approx(0.2)            # nothing saved yet: since start
    assert k.save(path)                                    # save 1: snapshot and file at t1
    t1 = clock.now
    assert k.saved_state_time == t1 and k.unsaved_s() == 0.0 and load(path).summary()['samples'] == 30

    # save 2 is slow: its snapshot is taken at t2, the file renamed in place only when the writer is let go
    release, writing = threading.Event(), threading.Event()
    real_save = keeper_module.save

    def slow_save(c: Any, p: str) -> None:
        writing.set()
        release.wait(timeout=60.0)
        real_save(c, p)
    monkeypatch.setattr(keeper_module, 'save', slow_save)
    learn(k, 20)
    clock.now += 0.2
    t2 = clock.now
    assert k.save(path, background=True)
    assert writing.wait(timeout=60.0)
    learn(k, 10)
    clock.now += 0.25                                      # killed now, during save 2:
    assert load(path).summary()['samples'] == 30           # the file holds save 1 (atomic: never half a file)
    assert k.unsaved_s() == pytest.approx(clock.now - t1)  # the loss counts from save 1's snapshot: 0.45 s, more
    assert k.unsaved_s() > 0.2                             # than one save period (0.2 s here)
    release.set()
    k.wait()
    # not killed: save 2 lands; it holds the state of its snapshot time t2, and took t2 -> now
    assert k.saved_state_time == t2 and k.last_save_duration_s == pytest.approx(0.25)
    assert load(path).summary()['samples'] == 50
    assert k.unsaved_s() == pytest.approx(clock.now - t2)  # the 10 samples after t2 are not saved yet
