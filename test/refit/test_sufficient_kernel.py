"""The accumulation kernel of the sufficient statistics (refit.sufficient) against a plain reference: the same cells
and, per cell, the same count, sums, mean and centred sum of squares (1e-12 relative), whichever path the kernel
takes (dense cell code, sorted codes for wide key ranges, rows of keys beyond 2^62 cells) and however the samples
are cut into accumulation steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.refit import sufficient
from gimbal_friction.refit.sufficient import SPEED_RATIO, TEMPERATURE_RESOLUTION_C, SufficientStats


def reference(t, n, y, d, clock, width):
    """Cells the slow, obvious way: one dict entry per key, sums over the samples of each key in sample order."""
    cells: dict[tuple[int, int, int, int], list[int]] = {}
    for k in range(t.size):
        b = math.floor(clock[k] / width) if math.isfinite(clock[k] / width) else -1
        key = (b, math.floor(t[k] / TEMPERATURE_RESOLUTION_C), 1 if d[k] > 0 else -1,
               math.floor(math.log(abs(n[k])) / math.log(SPEED_RATIO)))
        cells.setdefault(key, []).append(k)
    out = []
    for key in sorted(cells):   # (batch, t, direction, speed): the order of SufficientStats
        idx = np.array(cells[key])
        ys = y[idx]
        mean = math.fsum(ys) / idx.size
        out.append((*key, idx.size, math.fsum(t[idx]), math.fsum(np.abs(n[idx])), mean,
                    math.fsum((ys - mean) ** 2)))
    cols = list(zip(*out, strict=True))
    return {name: np.array(col) for name, col in zip(('batch', 't_index', 'direction', 's_index', 'samples',
                                                      'sum_t', 'sum_n', 'mean_y', 'm2_y'), cols, strict=True)}


def random_samples(rng, size, time_span_s):
    t = rng.choice([-40.0, 0.0, 60.0], size) + rng.normal(0.0, 0.3, size)
    n = np.exp(rng.normal(-1.0, 0.5, size)) * rng.choice([1.0, -1.0], size)   # sign of a speed is ignored
    y = 1e-3 + rng.normal(0.0, 3e-4, size)
    d = rng.choice([1.0, -1.0], size)
    clock = np.sort(rng.uniform(0.0, time_span_s, size))
    return t, n, y, d, clock


def assert_same(stats, ref):
    for name in ('batch', 't_index', 'direction', 's_index'):
        np.testing.assert_array_equal(getattr(stats, name), ref[name], err_msg=name)
    np.testing.assert_array_equal(stats.samples, ref['samples'])
    for name in ('sum_t', 'sum_n', 'mean_y', 'm2_y'):
        np.testing.assert_allclose(getattr(stats, name), ref[name], rtol=1e-12, atol=0.0, err_msg=name)


@pytest.mark.parametrize(('chunk', 'time_span_s'), [
    (1 << 16, 30.0),      # one step, dense cell code
    (97, 30.0),           # many steps: cells cut between steps are merged (Chan)
    (1 << 16, 1e7),       # wide batch range: sorted codes
    (500, 1e7),
    (1 << 16, 1e18),      # beyond 2^62 cells: rows of keys
])
def test_cells_equal_the_reference(monkeypatch, chunk, time_span_s):
    monkeypatch.setattr(sufficient, 'CHUNK', chunk)
    rng = np.random.default_rng(chunk + int(math.log10(time_span_s)))
    t, n, y, d, clock = random_samples(rng, 3000, time_span_s)
    clock[[5, 17]] = [math.nan, math.inf]   # an unusable stamp goes to batch -1
    clock = np.sort(clock)
    stats = SufficientStats.from_arrays(t, n, y, d, time=clock)
    assert stats.n_samples == t.size
    assert_same(stats, reference(t, n, y, d, clock, sufficient.BATCH_S))


def test_cells_without_stamps_use_the_sample_order(monkeypatch):
    monkeypatch.setattr(sufficient, 'CHUNK', 250)
    rng = np.random.default_rng(3)
    t, n, y, d, _ = random_samples(rng, 4001, 1.0)
    stats = SufficientStats.from_arrays(t, n, y, d)
    width = max(1, t.size // sufficient.ORDINAL_BATCHES)
    assert_same(stats, reference(t, n, y, d, np.arange(t.size, dtype=float), width))


def test_the_kernel_does_not_change_its_inputs():
    rng = np.random.default_rng(4)
    arrays = random_samples(rng, 2000, 50.0)
    copies = [a.copy() for a in arrays]
    SufficientStats.from_arrays(*arrays[:4], time=arrays[4])
    for a, b in zip(arrays, copies, strict=True):
        np.testing.assert_array_equal(a, b)
