"""``/gimbal/friction/correction`` carries only finite numbers: the message builder of a cell's status
(:func:`gimbal_friction.nodes.feedforward.cell_values`), no node needed."""

from __future__ import annotations

import math

import pytest

from gimbal_friction.feedforward.correction import (
    Correction,
    CorrectionSettings,
    Learner,
    LearningSettings,
    model_identity,
)
from gimbal_friction.physics.params import AxisParams

pytest.importorskip('rclpy', reason='the message builder needs the ros-* wheels (requirements.txt)')
V = 2 * math.pi / 180   # 1/3 rpm [rad/s]


def _numbers_are_finite(text: str) -> bool:
    for word in text.split():
        try:
            x = float(word)
        except ValueError:
            continue
        if not math.isfinite(x):
            return False
    return True


def test_a_cell_nothing_has_scored_yet_publishes_no_nan():
    from gimbal_friction.nodes._common import status
    from gimbal_friction.nodes.feedforward import _CELL_KEYS, NOT_SCORED, cell_values
    learner = Learner(Correction(CorrectionSettings(prior_samples=1.0), model_identity({'elevation': AxisParams()})),
                      LearningSettings())
    for i in range(20):                          # one direction, one bin: learned, never scored out of sample
        assert learner.update('elevation', -40.0, V, 0.001 * i, 1e-3, 3e-3, now_s=0.01 * i) is None
    learner.flush()
    (rec,) = learner.cells('elevation')
    assert math.isnan(rec['rms_model_nm']) and math.isnan(rec['rms_with_nm'])   # the record: not scored yet
    rec['z'] = {**rec['z'], 'correction': math.nan}                              # any other figure alike
    msg = status('gimbal_friction/correction/elevation/cw/-40', b'\x00', rec['state'], 'elevation', cell_values(rec))
    values = {kv.key: kv.value for kv in msg.values}
    assert set(_CELL_KEYS) | {'std_error_nm', 'speed_profile_nm', 'terms', 'z_correction'} <= set(values)
    assert values['rms_model_nm'] == values['rms_with_nm'] == values['z_correction'] == NOT_SCORED == 'not scored'
    bad = {k: v for k, v in values.items() if not _numbers_are_finite(v)}
    assert not bad, bad
    assert float(values['samples']) == 20 and math.isfinite(float(values['mean_nm']))
