"""The loop's judge of the learned correction (feedforward/correction/judge.py): a synthetic loop whose error depends
on whether the candidate is on, plus noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity
from gimbal_friction.feedforward.correction.judge import RESIZE_WEIGHT, LoopJudge, correction_signature
from gimbal_friction.feedforward.correction.settings import JudgeSettings

LAYOUT = CorrectionSettings()
NT = LAYOUT.n_temperature
J = 'elevation'
COLD = -40.0


def _signature(level_nm: float = 1e-4, t_c: float = COLD) -> np.ndarray:
    sig = np.zeros((2, NT, 3))
    b = int((t_c - LAYOUT.temperature_min_c) // LAYOUT.temperature_bin_c)
    sig[:, b] = level_nm
    return sig


def _run(judge: LoopJudge, seconds: float, factor_on: float, *, start_s: float = 0.0, seed: int = 1,
         dt: float = 0.002, sigma: float = 1e-3) -> list[bool]:
    """A loop moving at ±0.1 rad/s (reversing every 0.75 s, a speed change every 2.1 s) whose rate error has RMS
    ``sigma`` × (``factor_on`` while the judge has the candidate on); observed every 0.05 s. Returns whether the
    candidate was on at each observed chunk, for the cw direction's cell."""
    rng = np.random.default_rng(seed)
    on_log = []
    t0 = start_s
    while t0 < start_s + seconds - 1e-9:
        t = t0 + np.arange(0.0, 0.05, dt)
        v = 0.1 * np.sign(np.sin(2.0 * math.pi * t / 1.5) + 1e-9) * (1.0 + 2.0 * (np.floor(t / 2.1) % 2))
        on = np.array([judge.use_candidate(J, COLD, float(vv), float(tt)) for tt, vv in zip(t, v, strict=True)])
        scale = sigma * (1.0 + 0.5 * (np.abs(v) > 0.15))       # the error depends on the speed too
        e = rng.normal(0.0, 1.0, t.size) * scale * np.where(on, factor_on, 1.0)
        judge.observe(J, t, np.full(t.size, COLD), v, e)
        on_log.append(bool(judge.use_candidate(J, COLD, 0.1, float(t[0]))))
        t0 += 0.05
    return on_log


def test_a_candidate_that_hurts_the_loop_is_withdrawn_early() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings())
    judge.offer(J, _signature())
    assert judge.state_of(J, COLD, 0.1) == 'testing'
    _run(judge, 40.0, 1.5)
    assert judge.state_of(J, COLD, 0.1) == 'withdrawn'
    assert judge.state_of(J, COLD, -0.1) == 'withdrawn'
    cell = next(c for c in judge.cells(J) if c['direction'] == 'cw')
    assert cell['z'] > JudgeSettings().stop_z and cell['ratio'] > 1.5
    assert 'higher' in cell['reason']
    # withdrawn: back to the model, never on again
    assert not any(_run(judge, 10.0, 1.5, start_s=40.0))


def test_a_candidate_that_helps_the_loop_is_applied() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings())
    judge.offer(J, _signature())
    _run(judge, 60.0, 0.8)
    assert judge.state_of(J, COLD, 0.1) == 'applied'
    assert judge.state_of(J, COLD, -0.1) == 'applied'
    cell = next(c for c in judge.cells(J) if c['direction'] == 'cw')
    assert cell['z'] < -JudgeSettings().z and cell['ratio'] < 0.8
    assert cell['blocks_on'] >= JudgeSettings().min_blocks and cell['blocks_off'] >= JudgeSettings().min_blocks


def test_a_candidate_that_does_nothing_is_not_applied() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings(max_blocks=20))
    judge.offer(J, _signature())
    _run(judge, 60.0, 1.0)
    assert judge.state_of(J, COLD, 0.1) in ('testing', 'withdrawn')
    assert judge.state_of(J, COLD, 0.1) != 'applied'


def test_the_share_of_blocks_on_is_bounded_while_testing() -> None:
    for share in (0.5, 0.25):
        judge = LoopJudge(LAYOUT, (J,), JudgeSettings(on_share=share, block_s=1.0))
        judge.offer(J, _signature())
        on = [judge.use_candidate(J, COLD, 0.1, k + 0.5) for k in range(40)]
        g = round(1.0 / share)
        assert [sum(on[i:i + g]) for i in range(0, 40, g)] == [1] * (40 // g)   # exactly one block on per group
        assert judge.state_of(J, COLD, 0.1) == 'testing'


def test_an_applied_cell_keeps_blocks_off_and_is_withdrawn_when_later_data_falsify_it() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings(memory_groups=10))
    judge.offer(J, _signature())
    _run(judge, 60.0, 0.7)
    assert judge.state_of(J, COLD, 0.1) == 'applied'
    first = int(math.floor(60.0)) + 1
    on = [judge.use_candidate(J, COLD, 0.1, float(first + k) + 0.5) for k in range(20)]
    assert 1 <= 20 - sum(on) <= 3          # about a tenth of the blocks off
    judge.reset()
    judge.offer(J, _signature())
    _run(judge, 60.0, 0.7)
    assert judge.state_of(J, COLD, 0.1) == 'applied'
    _run(judge, 400.0, 2.0, start_s=60.0)   # the gimbal changed: the candidate now hurts
    assert judge.state_of(J, COLD, 0.1) == 'withdrawn'
    assert judge.state_of(J, COLD, -0.1) == 'withdrawn'
    reasons = [c['reason'] for c in judge.cells(J)]
    assert any('falsified' in r for r in reasons), reasons
    assert not any(_run(judge, 5.0, 2.0, start_s=460.0))     # back to the model


def test_both_directions_of_a_bin_are_switched_together() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings())
    judge.offer(J, _signature())
    for k in range(40):
        t = 0.2 * k + 0.1
        assert judge.use_candidate(J, COLD, 0.1, t) == judge.use_candidate(J, COLD, -0.1, t)
    sig = _signature()
    b = int((COLD - LAYOUT.temperature_min_c) // LAYOUT.temperature_bin_c)
    judge.state[0, 1, b] = 3                     # the ccw direction withdrawn: the whole bin is the model
    judge.offer(J, sig)
    assert not any(judge.use_candidate(J, COLD, v, 10.0 + 0.2 * k) for k in range(20) for v in (0.1, -0.1))


def test_a_new_candidate_restarts_the_test_and_a_small_change_does_not() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings())
    judge.offer(J, _signature(1e-4))
    _run(judge, 40.0, 1.5)
    assert judge.state_of(J, COLD, 0.1) == 'withdrawn'
    judge.offer(J, _signature(1.1e-4))            # a refit that moved it by 10 %: the verdict stands
    assert judge.state_of(J, COLD, 0.1) == 'withdrawn'
    before = judge.groups.copy()
    judge.offer(J, _signature(2e-4))              # the same shape, twice the size: tested again, evidence weighed less
    assert judge.state_of(J, COLD, 0.1) == 'testing'
    assert before.sum() > 0 and np.array_equal(judge.groups, np.floor(before * RESIZE_WEIGHT))
    other = _signature(1e-4)
    other[:, other[0, :, 0] > 0, 2] = -1e-4       # a new shape: the test starts from nothing
    judge.offer(J, other)
    assert judge.state_of(J, COLD, 0.1) == 'testing'
    assert judge.groups.sum() == 0 and judge.cells(J) == []   # nothing counted of the new test yet
    _run(judge, 60.0, 0.8, start_s=40.0)
    assert judge.state_of(J, COLD, 0.1) == 'applied'
    judge.offer(J, np.zeros((2, NT, 3)))          # back to the model: untested, off
    assert judge.state_of(J, COLD, 0.1) == 'untested'
    assert not judge.use_candidate(J, COLD, 0.1, 200.5)
    assert judge.restarts == 6                    # two directions, three times


def test_frozen_uses_the_applied_cells_only_and_ignores_samples() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings())
    sig = _signature()
    sig[:, 20] = 1e-4                             # a second bin, never visited
    judge.offer(J, sig)
    _run(judge, 60.0, 0.8)
    judge.freeze()
    assert all(judge.use_candidate(J, COLD, 0.1, 100.0 + k) for k in range(15))
    assert not judge.use_candidate(J, LAYOUT.centre_c(20), 0.1, 120.0)
    assert judge.observe(J, [121.5], [COLD], [0.1], [1.0]) == 0
    assert np.array_equal(judge.use_candidate_array(J, [COLD, COLD, math.nan], [0.1, -0.1, 0.1], 130.0),
                          [True, True, False])
    summary = judge.summary()
    assert summary['cells_applied'] == 2 and summary['frozen'] and summary['judged_by_loop']


def test_late_samples_are_counted_not_judged() -> None:
    judge = LoopJudge(LAYOUT, (J,), JudgeSettings())
    judge.offer(J, _signature())
    judge.use_candidate(J, COLD, 0.1, 10.5)
    assert judge.observe(J, [5.7, 10.6], [COLD, COLD], [0.1, 0.1], [1e-3, 1e-3]) == 1
    assert judge.late_samples == 1


def test_the_signature_of_a_correction() -> None:
    c = Correction(CorrectionSettings(guard_min_samples=0, guard_z=0.0), model_identity({J: {}}))
    assert not np.any(correction_signature(c, J))
    n = 400
    for v in (0.03, -0.03):
        c.learn_residuals(J, [COLD] * n, [v] * n, [0.0] * n, [2e-4 * np.sign(v)] * n, [3.1e-3] * n)
    c.settle()
    sig = correction_signature(c, J)
    b = int((COLD - LAYOUT.temperature_min_c) // LAYOUT.temperature_bin_c)
    assert sig.shape[:2] == (2, NT) and sig[0, b].max() > 1e-4 and sig[1, b].max() > 1e-4
    judge = LoopJudge(c.settings, (J,))
    judge.update_candidates(c)
    assert judge.state_of(J, COLD, 0.03) == 'testing'


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match='on_share'):
        LoopJudge(LAYOUT, (J,), JudgeSettings(on_share=0.6))
    with pytest.raises(ConfigError, match='settle_s'):
        LoopJudge(LAYOUT, (J,), JudgeSettings(block_s=0.5, settle_s=0.5))
