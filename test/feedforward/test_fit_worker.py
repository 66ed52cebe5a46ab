"""Refits in a worker (BackgroundLearner): the same numbers as the inline step, taken in whole by poll, and a fit
that times out, dies or raises counted while the caller keeps the correction it had."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionKeeper,
    CorrectionSettings,
    Learner,
    LearningSettings,
    load,
    model_identity,
)
from gimbal_friction.feedforward.correction import worker as worker_module
from gimbal_friction.feedforward.correction.worker import BackgroundLearner
from gimbal_friction.physics.params import AxisParams

IDENT = model_identity({'elevation': AxisParams(), 'azimuth': AxisParams()})
OPEN = CorrectionSettings(guard_min_samples=0, guard_z=0.0)
FAST = LearningSettings(max_rate_nm_per_min=1.0, step_period_s=1.0)
WAIT_S = 120.0   # generous: the machine is shared (waits are on conditions, never asserted on)
PROBES = [(t, v, p) for t in (-35.0, 0.0, 15.0) for v in (0.1, -0.1, 0.4) for p in (-0.5, 0.0, 0.3)]


def until(cond, what: str) -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < WAIT_S, f'timed out waiting for {what}'
        time.sleep(0.005)


def ready(b: BackgroundLearner) -> BackgroundLearner:
    b.start()
    until(lambda: (b.poll(), b.worker_pid)[1] is not None, 'the worker to start')
    return b


def feed(learners, rng, n=700):
    """The same samples (both directions, a ripple of 2.2 deg over ±0.15 rad: periods are searched) to every
    learner."""
    for j in IDENT.joints:
        v = rng.choice([-1.0, 1.0], n) * rng.uniform(0.02, 0.5, n)
        p = rng.uniform(-0.15, 0.15, n)
        t = rng.uniform(-40.0, 0.0, n)
        m = np.full(n, 3e-3)
        r = np.sign(v) * (4e-4 + 3e-4 * np.sin(2 * np.pi * p / np.radians(2.2))) + rng.normal(0.0, 2e-5, n)
        for L in learners:
            L.update_many(j, t, v, p, r, m)


def settle(b: BackgroundLearner) -> bool:
    """Wait for the job in flight and take it in; whether an applied term changed."""
    changed = [False]

    def done() -> bool:
        changed[0] |= b.poll()
        return not b.busy
    until(done, 'the fit')
    return changed[0]


def torques(c: Correction) -> list[tuple[float, float]]:
    return [c.split_nm(j, t, v, p, 3e-3) for j in IDENT.joints for t, v, p in PROBES]


def assert_same(a: Correction, b: Correction) -> None:
    for j in IDENT.joints:
        pa, pb = a.applied(j), b.applied(j)
        for x, y in zip(pa, pb, strict=True):
            np.testing.assert_array_equal(x, y)
        assert a.periods[j] == b.periods[j]
    assert torques(a) == torques(b)


def run_both(mode: str, steps: int = 3):
    rng = np.random.default_rng(3)
    inline = Learner(Correction(OPEN, IDENT), FAST)
    bg = ready(BackgroundLearner(Correction(OPEN, IDENT), FAST, mode))
    inline.step(0.0)
    bg.step(0.0)
    settle(bg)                                     # (the first step gives the worker the correction alone)
    changed = []
    for k in range(1, steps + 1):
        feed([inline, bg], rng)
        a = inline.step(float(k))
        bg.step(float(k))
        changed.append((a, settle(bg)))
    return inline, bg, changed


@pytest.mark.slow
def test_a_refit_in_the_worker_process_gives_the_numbers_of_one_in_process(tmp_path):
    inline, bg, changed = run_both('process')
    try:
        assert bg.worker_pid != os.getpid() and bg.worker_rclpy_loaded is False   # a child without rclpy
        assert all(a == b for a, b in changed) and any(a for a, _ in changed)      # it learned something
        assert any(bg.correction.periods[j] for j in IDENT.joints)                 # periods were searched
        assert_same(inline.correction, bg.correction)
        s_in, s_bg = inline.correction_summary(), bg.correction_summary()
        assert s_in == s_bg
        np.testing.assert_equal([inline.cells(j) for j in IDENT.joints], [bg.cells(j) for j in IDENT.joints])
        # the worker saves what it holds: the file reads back as the inline correction
        path = tmp_path / 'c.yaml'
        assert bg.request_save(str(path))
        bg.drain()
        assert bg.save_outcomes[-1][:2] == (str(path), None)
        assert_same(inline.correction, load(path))
        assert load(path).summary()['samples'] == s_in['samples']
        assert (bg.fits, bg.fit_timeouts, bg.fit_failures, bg.samples_lost) == (len(changed) + 2, 0, 0, 0)
    finally:
        bg.close()


def test_a_thread_worker_gives_the_same_numbers_and_the_caller_swaps_only_when_it_polls():
    rng = np.random.default_rng(5)
    inline = Learner(Correction(OPEN, IDENT), FAST)
    bg = ready(BackgroundLearner(Correction(OPEN, IDENT), FAST, 'thread'))
    gate = threading.Event()
    real = worker_module.learn_step

    def held(*args):
        gate.wait(WAIT_S)
        return real(*args)
    try:
        inline.step(0.0)
        bg.step(0.0)
        settle(bg)
        feed([inline, bg], rng, n=400)
        inline.step(1.0)
        before = torques(bg.correction)
        worker_module.learn_step = held
        bg.step(1.0)
        assert bg.busy and bg.in_flight == 800 and bg.pending == 0
        assert not bg.poll() and torques(bg.correction) == before       # the fit runs: the old correction serves
        feed([inline, bg], rng, n=50)                                   # samples keep arriving meanwhile
        assert not bg.step(2.0) and bg.pending == 100                   # one fit in flight at most
        gate.set()
        assert settle(bg)
        assert torques(bg.correction) != before
        worker_module.learn_step = real
        inline.step(2.0)
        bg.step(2.0)
        settle(bg)
        assert_same(inline.correction, bg.correction)
    finally:
        worker_module.learn_step = real
        gate.set()
        bg.close()


@pytest.mark.slow
def test_a_fit_that_times_out_is_counted_the_old_correction_serves_and_a_new_worker_takes_over():
    inline, bg, _ = run_both('process', steps=2)
    try:
        bg.settings = LearningSettings(max_rate_nm_per_min=1.0, step_period_s=1.0, fit_timeout_s=0.2)
        before = torques(bg.correction)
        pid = bg.worker_pid
        assert pid is not None
        os.kill(pid, signal.SIGSTOP)                                   # a fit that never ends
        rng = np.random.default_rng(9)
        feed([bg], rng, n=100)
        bg.step(10.0)
        assert bg.busy
        until(lambda: (bg.poll(), bg.fit_timeouts)[1] == 1, 'the timeout')
        assert not bg.busy and bg.samples_lost == 200 and 'more than 0.2 s' in bg.last_fit_error
        assert torques(bg.correction) == before
        assert bg.fit_failures == 0 and bg.worker_restarts == 1
        # the next step starts a new worker from the caller's copy, and learns on
        bg.settings = FAST
        ready(bg)
        assert bg.worker_pid != pid
        feed([bg], rng, n=300)
        bg.step(11.0)
        fits = bg.fits
        settle(bg)
        assert bg.fits == fits + 1 and bg.fit_timeouts == 1
    finally:
        bg.close()


@pytest.mark.slow
def test_a_worker_that_dies_is_counted_and_the_old_correction_serves():
    inline, bg, _ = run_both('process', steps=2)
    try:
        before = torques(bg.correction)
        pid = bg.worker_pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        rng = np.random.default_rng(11)
        feed([bg], rng, n=100)
        until(lambda: (bg.step(12.0), bg.poll(), bg.fit_failures)[2] == 1, 'the crash to be seen')
        assert 'died' in bg.last_fit_error or 'gone' in bg.last_fit_error
        assert torques(bg.correction) == before and bg.fit_timeouts == 0
        ready(bg)
        assert bg.worker_pid != pid
        feed([bg], rng, n=300)
        bg.step(13.0)
        settle(bg)
        assert bg.fit_failures == 1 and not bg.busy
    finally:
        bg.close()


def test_a_fit_that_raises_is_counted_and_the_next_one_is_given_the_correction_again():
    rng = np.random.default_rng(13)
    bg = ready(BackgroundLearner(Correction(OPEN, IDENT), FAST, 'thread'))
    real = worker_module.learn_step

    def broken(*args):
        raise FloatingPointError('a fit that raises')
    try:
        bg.step(0.0)
        settle(bg)
        feed([bg], rng, n=300)
        worker_module.learn_step = broken
        bg.step(1.0)
        settle(bg)
        assert bg.fit_failures == 1 and 'FloatingPointError: a fit that raises' in bg.last_fit_error
        worker_module.learn_step = real
        feed([bg], rng, n=300)
        bg.step(2.0)
        settle(bg)                                  # (the worker dropped its correction: it is given it again)
        assert bg.fit_failures == 1 and bg.fits == 2
    finally:
        worker_module.learn_step = real
        bg.close()


def test_a_thread_fit_past_its_timeout_is_counted_once_and_taken_when_it_ends():
    rng = np.random.default_rng(17)
    bg = ready(BackgroundLearner(Correction(OPEN, IDENT),
                                 LearningSettings(max_rate_nm_per_min=1.0, fit_timeout_s=0.05), 'thread'))
    gate = threading.Event()
    real = worker_module.learn_step

    def held(*args):
        gate.wait(WAIT_S)
        return real(*args)
    try:
        bg.step(0.0)
        settle(bg)
        feed([bg], rng, n=300)
        worker_module.learn_step = held
        bg.step(1.0)
        until(lambda: (bg.poll(), bg.fit_timeouts)[1] == 1, 'the timeout')
        assert bg.busy and not bg.poll() and bg.fit_timeouts == 1
        gate.set()
        settle(bg)
        assert bg.fits == 2 and bg.fit_timeouts == 1 and bg.samples_lost == 0
    finally:
        worker_module.learn_step = real
        gate.set()
        bg.close()


def test_a_keeper_in_the_background_saves_through_its_worker_and_loads_a_reset_into_it(tmp_path):
    k = CorrectionKeeper(IDENT, OPEN, LearningSettings(max_rate_nm_per_min=1.0, fit_worker='thread'),
                         background=True)
    rng = np.random.default_rng(19)
    try:
        assert isinstance(k.learner, BackgroundLearner)
        ready(k.learner)
        k.learner.step(0.0)
        until(lambda: (k.poll(), k.learner.busy)[1] is False, 'the first job')
        feed([k.learner], rng, n=300)
        k.learner.step(1.0)
        until(lambda: (k.poll(), k.learner.busy)[1] is False, 'the fit')
        path = tmp_path / 'c.yaml'
        assert k.save(str(path)) and k.saves == 1 and k.last_save_error is None
        assert load(path).summary()['samples'] == 600
        # other settings of the same layout reach the worker's correction (and its file)
        k.set_settings(CorrectionSettings(guard_min_samples=0, guard_z=1.5))
        assert k.learner.correction.settings.guard_z == 1.5
        feed([k.learner], rng, n=50)
        k.learner.step(2.0)
        until(lambda: (k.poll(), k.learner.busy)[1] is False, 'the fit')
        k.dirty = True
        assert k.save(str(path)) and load(path).settings.guard_z == 1.5 and load(path).summary()['samples'] == 700
        k.learner.reset()
        k.dirty = True
        assert k.save(str(path)) and k.saves == 3
        assert load(path).summary()['samples'] == 0 and k.learner.correction_summary()['samples'] == 0
    finally:
        k.close()


def test_inline_keeps_the_plain_learner_and_fit_worker_is_checked():
    k = CorrectionKeeper(IDENT, OPEN, LearningSettings(fit_worker='inline'), background=True)
    assert type(k.learner) is Learner
    assert type(CorrectionKeeper(IDENT, OPEN, LearningSettings()).learner) is Learner   # (a library user's default)
    with pytest.raises(ConfigError, match='fit_worker'):
        LearningSettings(fit_worker='fork').validate()
    with pytest.raises(ConfigError, match='fit_timeout_s'):
        LearningSettings(fit_timeout_s=0.0).validate()
