"""The estimator's array shortcuts give exactly what the per-sample code gave: the statistics' groups of a batch
found with numpy (no key tuple per sample)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gimbal_friction.estimation import estimator as est
from gimbal_friction.estimation.statistics import GroupStatistics

JOINTS = ['elevation', 'azimuth', 'roll']


def _batch(seed: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples in runs of one joint, direction and plateau (as a chamber test gives them), with interleaved
    joints, unknown plateaus (NaN), plateaus that come back later, zero velocities and non-finite values."""
    rng = np.random.default_rng(seed)
    runs = int(rng.integers(1, 40))
    lengths = rng.integers(1, max(2, 2 * n // runs), size=runs)
    rank = np.repeat(rng.integers(0, len(JOINTS), size=runs), lengths)
    velocity = np.repeat(rng.choice([-0.03, 0.0, 0.03], size=runs), lengths) * rng.uniform(0.5, 1.5, rank.size)
    plateau = np.repeat(rng.choice([-40.0, -20.0, 0.0, 20.0, np.nan], size=runs), lengths)
    shuffle = rng.random(rank.size) < 0.05            # single samples off their run
    rank[shuffle] = rng.integers(0, len(JOINTS), size=int(shuffle.sum()))
    plateau[rng.random(rank.size) < 0.02] = np.nan
    value = rng.normal(1e-3, 2e-4, rank.size)
    value[rng.random(rank.size) < 0.01] = np.nan
    position = rng.uniform(-0.2, 0.3, rank.size)
    joint = np.asarray(JOINTS)[rank]
    return joint, rank, velocity, plateau, value, position


def _per_sample_keys(joint: np.ndarray, velocity: np.ndarray, plateau: np.ndarray) -> list[tuple]:
    """The keys the estimator built for each sample before (joint, direction, plateau or None)."""
    direction = np.where(velocity > 0.0, 1, -1)
    return [(j, d, None if math.isnan(p) else p)
            for j, d, p in zip(joint.tolist(), direction.tolist(), plateau.tolist(), strict=True)]


@pytest.mark.parametrize('seed', range(12))
def test_statistics_groups_equal_the_per_sample_keys(seed):
    """Two batches into running statistics: the groups and every value (bit for bit) and the order of the
    records are those of one key tuple per sample."""
    by_key = GroupStatistics(4, -0.1, 0.2)
    by_group = GroupStatistics(4, -0.1, 0.2)
    for part in range(2):
        joint, rank, velocity, plateau, value, position = _batch(100 * seed + part, 3000)
        keys, gid = est._statistics_groups(joint, rank, velocity, plateau)
        assert len(set(keys)) == len(keys)
        assert [keys[g] for g in gid.tolist()] == _per_sample_keys(joint, velocity, plateau)
        first = [int(np.flatnonzero(gid == g)[0]) for g in range(len(keys))]
        assert first == sorted(first)                   # numbered in the order they first occur
        by_key.add(_per_sample_keys(joint, velocity, plateau), value, position)
        by_group.add_groups(keys, gid, value, position)
    assert repr(by_group.records()) == repr(by_key.records())


def test_statistics_groups_of_one_sample_and_of_one_run():
    keys, gid = est._statistics_groups(np.asarray(['elevation']), np.asarray([0]), np.asarray([-0.03]),
                                       np.asarray([np.nan]))
    assert keys == [('elevation', -1, None)] and gid.tolist() == [0]
    keys, gid = est._statistics_groups(np.asarray(['azimuth'] * 5), np.full(5, 1), np.full(5, 0.03),
                                       np.full(5, 20.0))
    assert keys == [('azimuth', 1, 20.0)] and gid.tolist() == [0] * 5


def test_sorted_and_identity_helpers():
    a = np.asarray([3, 1, 2])
    assert est._sorted(a).tolist() == [1, 2, 3]
    b = np.asarray([1, 1, 2, 5])
    assert est._sorted(b) is b
    assert est._is_identity(np.arange(4)) and est._is_identity(np.arange(0))
    assert not est._is_identity(np.asarray([0, 2, 1])) and not est._is_identity(np.asarray([1, 2]))
