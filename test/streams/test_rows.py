"""The residual row and the measurement layout: defined once, every form derived, the legacy layout still read."""

from __future__ import annotations

import numpy as np
import pytest

from gimbal_friction.recording import topics
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, MeasurementArrays, detail_matrix, from_detail
from gimbal_friction.streams.residual_row import (
    RESIDUAL_FIELDS,
    RESIDUAL_FIELDS_V1,
    ResidualRows,
    residual_rows,
    rows_from_detail,
)


def _measurements(n: int = 5) -> MeasurementArrays:
    rng = np.random.default_rng(0)
    return MeasurementArrays(
        np.array(['elevation', 'azimuth'] * n)[:n], 1_700_000_000_123_456_789 + np.arange(n) * 10**7,
        rng.normal(size=n), rng.normal(size=n), rng.normal(size=n), rng.normal(size=n), rng.normal(size=n),
        rng.random(n) > 0.5, rng.normal(size=n), np.full(n, 0.05), np.full(n, 0.01), np.full(n, 1e-4),
        np.arange(n, dtype=np.int8) % 2)


def test_measurement_detail_round_trips_exactly_including_the_stamp():
    m = _measurements()
    back = from_detail(m.joint, detail_matrix(m))
    for name, a, b in zip(MeasurementArrays._fields, m, back):
        assert np.array_equal(a, b), name
    assert detail_matrix(m).shape == (5, len(MEASUREMENT_FIELDS))
    with pytest.raises(ValueError):
        from_detail(['elevation'], detail_matrix(m))


def test_residual_rows_and_their_detail_layout():
    m = _measurements()
    pred = np.array([0.1, np.nan, 0.3, 0.4, 0.5])
    rows = residual_rows(m, pred)
    assert np.array_equal(rows.residual_nm, m.friction_nm - pred, equal_nan=True)
    assert np.array_equal(rows.current_a, m.current_a) and np.array_equal(rows.method, m.method)
    back = rows_from_detail(rows.joint, rows.matrix())
    for name, a, b in zip(ResidualRows._fields, rows, back):
        assert np.array_equal(a, b, equal_nan=np.asarray(a).dtype.kind == 'f'), name
    assert topics.RESIDUAL_FIELDS is RESIDUAL_FIELDS and topics.MEASUREMENT_FIELDS is MEASUREMENT_FIELDS
    assert list(rows.matrix()[0]) == [getattr(rows, f)[0] for f in RESIDUAL_FIELDS]
    with pytest.raises(ValueError):
        residual_rows(m, pred[:2])


def test_layout_1_logs_are_still_read():
    v1 = np.arange(3 * len(RESIDUAL_FIELDS_V1), dtype=float).reshape(3, -1)
    rows = rows_from_detail(['elevation'] * 3, v1)
    col = {f: i for i, f in enumerate(RESIDUAL_FIELDS_V1)}
    assert np.array_equal(rows.measured_nm, v1[:, col['measured_nm']])
    assert np.array_equal(rows.residual_nm, v1[:, col['residual_nm']])
    assert np.all(np.isnan(rows.torque_constant_nm_per_a)) and np.all(rows.method == 0)
    with pytest.raises(ValueError, match='values'):
        rows_from_detail(['elevation'], np.zeros((1, 5)))
