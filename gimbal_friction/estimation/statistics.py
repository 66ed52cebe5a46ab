"""Running statistics per group, merged batch by batch: one implementation for a node (a few samples per call)
and for a whole bag (millions at once).

Each batch is reduced with numpy to per-group count, mean and sum of squared deviations, then merged into the
running values with the pairwise update of Chan, Golub & LeVeque (1979), "Updating formulae and a pairwise
algorithm for computing sample variances" (Stanford CS tech. report STAN-CS-79-773):
``n = n_a + n_b``, ``δ = x̄_b − x̄_a``, ``x̄ = x̄_a + δ n_b/n``, ``M2 = M2_a + M2_b + δ² n_a n_b / n``. Feeding the
same samples in any batching gives the same result to rounding. Besides mean and standard deviation, each group
keeps the position range and per-position-bin sums for the ripple (peak-to-peak of the position-binned means).

>>> s = GroupStatistics(bins=2, position_min=0.0, position_max=1.0)
>>> s.add([('a', 1), ('a', 1), ('a', 1)], np.array([1.0, 2.0, 4.0]), np.array([0.1, 0.2, 0.9]))
>>> s.add([('a', 1)], np.array([5.0]), np.array([0.8]))
>>> r = s.records()[0]
>>> r['count'], r['mean'], round(r['std'], 6), r['ripple']
(4, 3.0, 1.825742, 3.0)
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray


class _Group:
    __slots__ = ('bin_n', 'bin_sum', 'm2', 'max_pos', 'mean', 'min_pos', 'n')

    def __init__(self, bins: int) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0
        self.min_pos = math.inf
        self.max_pos = -math.inf
        self.bin_sum = np.zeros(bins)
        self.bin_n = np.zeros(bins, dtype=np.int64)


class GroupStatistics:
    """Count, mean, sample standard deviation, position range and ripple of values per group key.

    Parameters
    ----------
    bins : int
        Equal position bins across ``[position_min, position_max]`` for the ripple, [-].
    position_min, position_max : float
        Position window of the bins (positions outside go to the edge bins), [rad].
    """

    def __init__(self, bins: int, position_min: float, position_max: float) -> None:
        self.bins = int(bins)
        self.position_min = float(position_min)
        self.span = float(position_max) - float(position_min)
        self._groups: dict[Hashable, _Group] = {}

    def clear(self) -> None:
        self._groups.clear()

    def drop(self, predicate: Any) -> None:
        """Forget the groups whose key satisfies ``predicate(key)``."""
        for key in [k for k in self._groups if predicate(k)]:
            del self._groups[key]

    def add(self, keys: Sequence[Hashable], values: NDArray[np.float64], positions: NDArray[np.float64]) -> None:
        """Merge a batch: one key, value and position [rad] per sample (non-finite values are ignored)."""
        x = np.asarray(values, dtype=np.float64)
        if x.size == 0:
            return
        uniq: dict[Hashable, int] = {}
        gid = np.fromiter((uniq.setdefault(k, len(uniq)) for k in keys), dtype=np.int64, count=x.size)
        self.add_groups(list(uniq), gid, x, positions)

    def add_groups(self, keys: Sequence[Hashable], gid: NDArray[np.int64], values: NDArray[np.float64],
                   positions: NDArray[np.float64]) -> None:
        """:meth:`add` with the samples' keys given as ``keys[gid]`` (``keys`` distinct, in the order each first
        occurs in ``gid``): the same result, without a key object per sample."""
        x = np.asarray(values, dtype=np.float64)
        pos = np.asarray(positions, dtype=np.float64)
        if x.size == 0:
            return
        ok = np.isfinite(x) & np.isfinite(pos)
        if not ok.all():
            gid, x, pos = gid[ok], x[ok], pos[ok]
        if x.size == 0:
            return
        n_groups = len(keys)
        count = np.bincount(gid, minlength=n_groups)
        mean = np.bincount(gid, weights=x, minlength=n_groups) / np.maximum(count, 1)
        m2 = np.bincount(gid, weights=(x - mean[gid]) ** 2, minlength=n_groups)
        b = np.clip(((pos - self.position_min) / self.span * self.bins).astype(np.int64), 0, self.bins - 1)
        flat = gid * self.bins + b
        bin_n = np.bincount(flat, minlength=n_groups * self.bins).reshape(n_groups, self.bins)
        bin_sum = np.bincount(flat, weights=x, minlength=n_groups * self.bins).reshape(n_groups, self.bins)
        lo = np.full(n_groups, np.inf)
        hi = np.full(n_groups, -np.inf)
        np.minimum.at(lo, gid, pos)
        np.maximum.at(hi, gid, pos)
        for g, key in enumerate(keys):
            nb = int(count[g])
            if nb == 0:
                continue
            acc = self._groups.get(key)
            if acc is None:
                acc = self._groups[key] = _Group(self.bins)
            na = acc.n
            n = na + nb
            delta = float(mean[g]) - acc.mean
            acc.mean += delta * nb / n
            acc.m2 += float(m2[g]) + delta * delta * na * nb / n
            acc.n = n
            acc.min_pos = min(acc.min_pos, float(lo[g]))
            acc.max_pos = max(acc.max_pos, float(hi[g]))
            acc.bin_n += bin_n[g]
            acc.bin_sum += bin_sum[g]

    def records(self) -> list[dict[str, Any]]:
        """One record per group, in first-seen order: ``key``, ``count``, ``mean``, ``std`` (sample standard
        deviation, 0 below two samples), ``ripple`` (0 with fewer than two non-empty bins), ``min_position``,
        ``max_position``."""
        out = []
        for key, g in self._groups.items():
            filled = g.bin_n > 0
            means = g.bin_sum[filled] / g.bin_n[filled]
            out.append({'key': key, 'count': g.n, 'mean': g.mean,
                        'std': math.sqrt(g.m2 / (g.n - 1)) if g.n >= 2 else 0.0,
                        'ripple': float(means.max() - means.min()) if means.size >= 2 else 0.0,
                        'min_position': g.min_pos, 'max_position': g.max_pos})
        return out
