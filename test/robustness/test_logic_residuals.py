"""Residual rows (pure) under hostile measurements and predictions: what the residual logger builds, refuses and
sums. Never an exception, an OverflowError (the old logger died squaring an effort of 1e154) or a NaN RMS; a
refused row is counted by the caller (credible_rows gives the mask); a NaN prediction (no feedforward) keeps the
row, its residual out of the RMS.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gimbal_friction.estimation.residuals import (
    MAX_CREDIBLE_TORQUE_NM,
    ResidualStats,
    credible_rows,
    credible_torque,
    match_predictions,
)
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS, from_detail
from gimbal_friction.streams.residual_row import residual_rows

ODD = [math.nan, math.inf, -math.inf, 1e154, -1e154, 1e308, 5e-324, 0.0, 100.0, 100.0000001]
VALUE = st.one_of(st.floats(-0.01, 0.01), st.sampled_from(ODD), st.floats(allow_nan=True, allow_infinity=True))
TEMP = st.one_of(st.floats(-60.0, 120.0), st.sampled_from([math.nan, math.inf, -1e300, 1e300, -273.15, -274.0]))


def detail_row(stamp_s: int, temperature: float, friction: float, position: float = 0.01,
               velocity: float = 0.0349) -> list[float]:
    row = [0.0] * len(MEASUREMENT_FIELDS)
    values = {'stamp_sec': float(stamp_s), 'stamp_nanosec': 0.0, 'position_rad': position,
              'velocity_rad_s': velocity, 'current_a': 0.06, 'temperature_c': temperature, 'temperature_fresh': 1.0,
              'friction_nm': friction, 'torque_constant_nm_per_a': 0.05, 'method': 0.0}
    for k, v in values.items():
        row[MEASUREMENT_FIELDS.index(k)] = v
    return row


@settings(max_examples=150, deadline=None)
@given(rows=st.lists(st.tuples(VALUE, VALUE, TEMP, st.sampled_from([0.01, math.nan, 1e308])), min_size=1,
                     max_size=30),
       bin_c=st.sampled_from([0.001, 5.0, 1000.0]))
def test_rows_refuse_the_incredible_and_statistics_stay_finite(rows, bin_c):
    data = np.array([detail_row(k + 1, t, meas, position=pos) for k, (meas, _, t, pos) in enumerate(rows)])
    m = from_detail(['elevation'] * len(rows), data)
    predicted = np.array([p for _, p, _, _ in rows])
    r = residual_rows(m, predicted)
    ok = credible_rows(r)
    for k, (meas, pred, t, pos) in enumerate(rows):
        expected = (math.isfinite(meas) and abs(meas) <= MAX_CREDIBLE_TORQUE_NM
                    and (math.isnan(pred) or (math.isfinite(pred) and abs(pred) <= MAX_CREDIBLE_TORQUE_NM))
                    and (math.isnan(t) or -273.15 <= t <= 1000.0) and math.isfinite(pos))
        assert bool(ok[k]) == expected, (meas, pred, t, pos)
    kept = r.select(ok)
    stats = ResidualStats(bin_c)
    stats.add(kept)
    stats.add(kept)   # twice: the running sums
    for (joint, b), (n, rms) in stats.rms().items():
        assert joint == 'elevation' and n >= 1
        assert math.isfinite(rms) and 0.0 <= rms <= 2 * MAX_CREDIBLE_TORQUE_NM
        assert b is None or math.isfinite(b)
    paired = np.isfinite(kept.residual_nm)
    assert sum(n for n, _ in stats.rms().values()) == 2 * int(np.count_nonzero(paired))


def test_the_effort_that_killed_the_logger():
    """An effort of 1e154 squared overflowed a Python float; now the row is refused and the RMS untouched."""
    m = from_detail(['elevation', 'elevation'], np.array([detail_row(1, 20.0, 0.002), detail_row(2, 20.0, 1e154)]))
    r = residual_rows(m, np.array([0.001, 0.001]))
    assert credible_rows(r).tolist() == [True, False]
    stats = ResidualStats()
    stats.add(r.select(credible_rows(r)))
    ((_, (n, rms)),) = stats.rms().items()
    assert n == 1 and rms == pytest.approx(0.001)
    assert credible_torque([1e154, math.nan, -math.inf, 0.002]).tolist() == [False, False, False, True]


@pytest.mark.parametrize('bad', [
    {'stamp_sec': math.nan}, {'stamp_sec': 1e300}, {'stamp_sec': -1e300}, {'stamp_sec': 2.0**31},
    {'stamp_sec': 1.5}, {'stamp_nanosec': 1e9}, {'stamp_nanosec': -1.0}, {'stamp_nanosec': math.inf},
    {'method': 7.0}, {'method': math.nan},
])
def test_measured_detail_with_an_impossible_stamp_or_method_is_refused(bad):
    row = detail_row(5, 20.0, 0.002)
    for k, v in bad.items():
        row[MEASUREMENT_FIELDS.index(k)] = v
    with pytest.raises(ValueError, match=r'stamp|method'):
        from_detail(['elevation'], np.array([row]))


@settings(max_examples=60, deadline=None)
@given(ff=st.lists(st.tuples(st.sampled_from(['elevation', 'azimuth', '']), st.integers(-3, 3), VALUE),
                   max_size=20),
       meas=st.lists(st.tuples(st.sampled_from(['elevation', 'azimuth']), st.integers(-3, 3)), max_size=10))
def test_pairing_is_total(ff, meas):
    """match_predictions never raises and returns for each sample the feedforward of its joint and stamp (the
    last one published for it) or NaN."""
    fj = np.array([j for j, _, _ in ff], dtype=str)
    fs = np.array([s for _, s, _ in ff], dtype=np.int64)
    ft = np.array([t for _, _, t in ff], dtype=np.float64)
    mj = np.array([j for j, _ in meas], dtype=str)
    ms = np.array([s for _, s in meas], dtype=np.int64)
    got = match_predictions(mj, ms, fj, fs, ft)
    for k, (j, s) in enumerate(meas):
        hits = [t for jj, ss, t in ff if jj == j and ss == s]
        if not hits:
            assert math.isnan(got[k])
        else:
            assert got[k] == hits[-1] or (math.isnan(got[k]) and math.isnan(hits[-1]))
