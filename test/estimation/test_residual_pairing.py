"""The residual pairing, one rule in one place (gimbal_friction.estimation.residuals, no rclpy): the live buffer
(:class:`ResidualPairing`, what residual_logger keeps) gives the rows :func:`pair_residuals` gives over the whole
input (what replay and the loop study call), whatever the order and batching of the messages."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np

from gimbal_friction.estimation.residuals import ResidualPairing, pair_residuals
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, MeasurementArrays, from_detail

ROOT = Path(__file__).resolve().parents[2]
S = 1_000_000_000


def measurements(joints: list[str], stamps_ns: list[int]) -> MeasurementArrays:
    rows = np.zeros((len(joints), len(MEASUREMENT_FIELDS)))
    rows[:, 0], rows[:, 1] = np.divmod(np.asarray(stamps_ns), S)
    rows[:, 3] = 0.03                                # velocity [rad/s]
    rows[:, 6] = -20.0                               # temperature [degC]
    rows[:, 8] = 0.004 + 1e-4 * np.arange(len(joints))   # friction [N*m]
    return from_detail(joints, rows)


def test_the_buffer_gives_the_rows_of_the_whole_input_whatever_the_arrival_order():
    joints = ['a', 'b'] * 10
    stamps = [S + (k // 2) * 1_000_000 for k in range(20)]
    m = measurements(joints, stamps)
    ff = [(j, t, 0.001 * k) for k, (j, t) in enumerate(zip(joints, stamps, strict=True)) if k % 7 != 3]
    whole = pair_residuals(m, [f[0] for f in ff], [f[1] for f in ff], [f[2] for f in ff])
    assert int(np.isnan(whole.predicted_nm).sum()) == 3   # the three feedforwards never sent
    pairing = ResidualPairing()
    rows = []
    for k in range(20):   # measurements first, each feedforward a little later, in reverse within each pair
        pairing.add_measurement(m.select(np.array([k])), now_s=float(k))
        if k % 2:
            for j in (k, k - 1):
                if j % 7 != 3:
                    pairing.add_feedforward(*ff[[f[:2] for f in ff].index((joints[j], stamps[j]))])
        rows.append(pairing.take(now_s=float(k), timeout_s=100.0))
    assert pairing.waiting == 3
    rows.append(pairing.take(now_s=20.0, timeout_s=100.0, final=True))
    assert pairing.waiting == 0
    got = type(whole).concatenate(rows)
    key = np.lexsort((got.joint, got.stamp_s))
    want = np.lexsort((whole.joint, whole.stamp_s))
    for name in whole._fields:
        a, b = np.asarray(getattr(got, name))[key], np.asarray(getattr(whole, name))[want]
        assert (a.tolist() == b.tolist()) if a.dtype.kind in 'US' else np.array_equal(a, b, equal_nan=True), name


def test_a_measurement_waits_for_its_feedforward_at_most_the_timeout():
    pairing = ResidualPairing()
    pairing.add_measurement(measurements(['a'], [5 * S]), now_s=10.0)
    assert len(pairing.take(now_s=10.4, timeout_s=0.5)) == 0 and pairing.waiting == 1
    (row,) = pairing.take(now_s=10.5, timeout_s=0.5).predicted_nm.tolist()   # waited long enough: no prediction
    assert math.isnan(row) and pairing.waiting == 0
    pairing.add_measurement(measurements(['a'], [6 * S]), now_s=11.0)
    pairing.add_feedforward('b', 6 * S, 0.5)    # another joint's: not its feedforward
    pairing.add_feedforward('a', 6 * S, 0.002)
    pairing.add_feedforward('a', 6 * S, 0.003)  # published twice: the last one
    assert pairing.take(now_s=11.0, timeout_s=0.5).predicted_nm.tolist() == [0.003]


def test_the_buffer_keeps_the_last_horizon_feedforwards():
    pairing = ResidualPairing(horizon=4)
    for k in range(6):
        pairing.add_feedforward('a', k * S, float(k))
    pairing.add_measurement(measurements(['a', 'a'], [1 * S, 5 * S]), now_s=0.0)
    got = pairing.take(now_s=0.0, timeout_s=1.0, final=True).predicted_nm.tolist()
    assert math.isnan(got[0]) and got[1] == 5.0


def test_match_predictions_is_called_in_one_place():
    """residual_logger, replay and the loop study pair through pair_residuals / ResidualPairing: the rule
    (match_predictions) is called nowhere else in the package."""
    callers = []
    for path in sorted((ROOT / 'gimbal_friction').rglob('*.py')):
        tree = ast.parse(path.read_text(encoding='utf-8'))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, 'id', getattr(node.func, 'attr', '')) \
                    == 'match_predictions':
                callers.append(path.relative_to(ROOT).as_posix())
    assert set(callers) == {'gimbal_friction/estimation/residuals.py'}, callers
