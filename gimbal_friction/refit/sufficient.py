r"""Per-bin sufficient statistics of measured friction: what the refit needs, at a size independent of the samples.

A refit compares group means of the measured friction ``y = |τ|`` along the motion [N·m] with the model. The
model is smooth in temperature and speed, so a group of samples can be replaced by *cells* of nearly equal
temperature and speed without changing the fit: a cell holds

- its key: fine temperature bin ``floor(t / temperature_resolution_c)`` (0.1 °C), direction ±1, fine speed bin
  ``floor(ln n / ln speed_ratio)`` (ratio 1.25^0.1 ≈ 1.022) and time batch ``floor(time / batch_width)``
  (1 s of stamps);
- its statistics: count ``c``, ``Σ t`` [°C], ``Σ n`` [rpm], the mean ``ȳ`` [N·m] and the centred sum of squares
  ``M2 = Σ (y − ȳ)²`` [N²·m²] (merged with Chan's formula, so variances do not suffer from cancellation).

The model is evaluated at each *point* (the cells of one fine temperature/speed bin and direction, merged over
time batches) at its mean temperature and speed. Within 0.1 °C the model changes by at most about 1 % (the viscous
torque at −40 °C, d ln M_L/dT ≈ 0.11 /K), and its curvature over the bin (what evaluating at the mean neglects)
is of the order of 10⁻⁵ relative. The fine bins are aligned with the refit's groups (5 °C bins centred on
multiples of 5, speed groups of ratio 1.25): every group edge is a fine-bin edge for any group width that is a
multiple of 0.1 °C, so a group is an exact union of points.

The time batches carry what the correlated-noise weighting needs: the refit's standard error of a group mean is
the larger of the i.i.d. value and a batch-means value over 10 consecutive stretches of the group's samples; the
stretches are built from the group's cells in time order (cell granularity: 1 s), where the per-sample refit
split the samples themselves. With one sample per cell (``exact=True``) both are the same computation.

Everything is associative: statistics of chunks of a log, of several logs or of several units merge with
:meth:`SufficientStats.merge` in any grouping, with the same result to rounding. A 2-hour, 1 kHz chamber test
(7·10⁶ samples per axis) gives about 10⁴–10⁵ cells.

>>> rng = np.random.default_rng(0)
>>> t = np.repeat([-40.0, 20.0], 5000) + rng.normal(0.0, 0.05, 10000)
>>> y = np.where(t < 0.0, 3e-3, 1e-3) + rng.normal(0.0, 1e-4, 10000)
>>> d = np.tile([1.0, -1.0], 5000)
>>> s = SufficientStats.from_arrays(t, np.full(10000, 1 / 3), y, d, time=np.arange(10000) / 1000.0)  # 1 kHz
>>> s.n_samples, len(s) < 200
(10000, True)
>>> halves = SufficientStats.from_arrays(t[:4000], np.full(4000, 1 / 3), y[:4000], d[:4000], time=np.arange(4000.0),
...                                      batch_width=5.0)
>>> rest = SufficientStats.from_arrays(t[4000:], np.full(6000, 1 / 3), y[4000:], d[4000:],
...                                    time=np.arange(4000.0, 10000.0), batch_width=5.0)
>>> whole = SufficientStats.from_arrays(t, np.full(10000, 1 / 3), y, d, time=np.arange(10000.0), batch_width=5.0)
>>> merged = halves.merge(rest)
>>> bool(np.allclose(merged.mean_y, whole.mean_y) and np.allclose(merged.m2_y, whole.m2_y, rtol=1e-9))
True
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.units import RPM_PER_RAD_S
from gimbal_friction.streams.residual_row import ResidualRows

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Fine temperature bin [°C].
TEMPERATURE_RESOLUTION_C = 0.1
#: Fine speed bin: ratio of consecutive edges [-] (a tenth of the refit's speed groups of ratio 1.25).
SPEED_RATIO = 1.25 ** 0.1
#: Time batch of stamped samples [s].
BATCH_S = 1.0
#: Without stamps (plain arrays) the time axis is the sample order, in batches of ``n // this`` samples (≥ 1).
ORDINAL_BATCHES = 2000
#: Samples per vectorised accumulation step [-]: bounds the temporary memory, and keeps a step's arrays in the
#: CPU cache (a step is a dozen passes over them; 2^16 samples, 0.5 MB per array, was fastest of 2^14..2^20).
CHUNK = 1 << 16


class Tally(NamedTuple):
    """Row counts and the motor constants the rows were measured with (associative sums, minima and maxima)."""

    rows: int = 0                      #: rows seen [-]
    skipped_nonfinite: int = 0         #: rows with a non-finite temperature, velocity or measurement [-]
    skipped_standstill: int = 0        #: rows at zero velocity (direction unknown) [-]
    kt_sum: float = 0.0                #: Σ K_T over rows that carry one [N·m/A]
    kt_count: int = 0
    kt_min: float = math.inf
    kt_max: float = -math.inf
    i0_sum: float = 0.0                #: Σ I_0 [A]
    i0_count: int = 0
    i0_min: float = math.inf
    i0_max: float = -math.inf

    def merge(self, other: Tally) -> Tally:
        """Both tallies together."""
        return Tally(self.rows + other.rows, self.skipped_nonfinite + other.skipped_nonfinite,
                     self.skipped_standstill + other.skipped_standstill, self.kt_sum + other.kt_sum,
                     self.kt_count + other.kt_count, min(self.kt_min, other.kt_min), max(self.kt_max, other.kt_max),
                     self.i0_sum + other.i0_sum, self.i0_count + other.i0_count, min(self.i0_min, other.i0_min),
                     max(self.i0_max, other.i0_max))

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Mean K_T the rows were measured with [N·m/A] (NaN: not recorded, layout-1 logs)."""
        return self.kt_sum / self.kt_count if self.kt_count else math.nan

    @property
    def no_load_current_a(self) -> float:
        """Mean I_0 the rows were measured with [A] (NaN: not recorded)."""
        return self.i0_sum / self.i0_count if self.i0_count else math.nan


class SufficientStats(NamedTuple):
    """Cells of measured friction (see the module notes), sorted by key; one axis.

    ``exact`` statistics hold one sample per cell (the per-sample reference).
    """

    t_index: IntArray     #: fine temperature bin floor(t / temperature_resolution_c) [-]
    direction: IntArray   #: +1 or −1 [-]
    s_index: IntArray     #: fine speed bin floor(ln n / ln speed_ratio) [-]
    batch: IntArray       #: time batch [-] (the sample ordinal when exact)
    samples: Array        #: samples [-]
    sum_t: Array          #: Σ temperature [°C]
    sum_n: Array          #: Σ speed [rpm]
    mean_y: Array         #: mean |τ| along the motion [N·m]
    m2_y: Array           #: Σ (y − mean)² [N²·m²]
    tally: Tally
    temperature_resolution_c: float = TEMPERATURE_RESOLUTION_C
    speed_ratio: float = SPEED_RATIO
    exact: bool = False

    def __len__(self) -> int:
        """Number of cells [-]."""
        return int(self.samples.shape[0])

    @property
    def n_samples(self) -> int:
        """Samples in all cells [-]."""
        return int(round(float(self.samples.sum())))

    # ------------------------------------------------------------------ construction
    @staticmethod
    def empty(*, temperature_resolution_c: float = TEMPERATURE_RESOLUTION_C, speed_ratio: float = SPEED_RATIO,
              exact: bool = False, tally: Tally | None = None) -> SufficientStats:
        """No cells."""
        i = np.empty(0, dtype=np.int64)
        f = np.empty(0, dtype=np.float64)
        return SufficientStats(i, i, i, i, f, f, f, f, f, tally or Tally(), temperature_resolution_c, speed_ratio,
                               exact)

    @staticmethod
    def from_arrays(temperature_c: ArrayLike, speed_rpm: ArrayLike, measured_abs_nm: ArrayLike,
                    direction: ArrayLike, *, time: ArrayLike | None = None, batch_width: float | None = None,
                    exact: bool = False, temperature_resolution_c: float = TEMPERATURE_RESOLUTION_C,
                    speed_ratio: float = SPEED_RATIO, tally: Tally | None = None) -> SufficientStats:
        """Statistics of samples given as arrays (finite, speed > 0, direction ±1: checked by the caller).

        Parameters
        ----------
        temperature_c, speed_rpm, measured_abs_nm, direction : array_like
            Per sample: [°C], speed magnitude [rpm], friction along the motion [N·m], ±1.
        time : array_like, optional
            Time of every sample (e.g. stamps [s]); default the sample order.
        batch_width : float, optional
            Width of a time batch in the unit of ``time``; default :data:`BATCH_S` with ``time``, else
            ``max(1, n // ORDINAL_BATCHES)`` samples.
        exact : bool
            One cell per sample (the per-sample reference; no binning).
        """
        # (no copies of the inputs: float64 arrays are used as given, a chunk at a time)
        t = np.asarray(temperature_c, dtype=np.float64).reshape(-1)
        speed = np.asarray(speed_rpm, dtype=np.float64).reshape(-1)
        y = np.asarray(measured_abs_nm, dtype=np.float64).reshape(-1)
        direction_in = np.asarray(direction, dtype=np.float64).reshape(-1)
        size = t.shape[0]
        clock: NDArray[np.float64] | None = None
        if time is None:
            width = float(batch_width) if batch_width is not None else float(max(1, size // ORDINAL_BATCHES))
        else:
            clock = np.asarray(time, dtype=np.float64).reshape(-1)
            width = float(batch_width) if batch_width is not None else BATCH_S
        if not (math.isfinite(width) and width > 0.0):
            msg = f'batch width must be > 0, got {width}'
            raise ValueError(msg)
        base_tally = tally if tally is not None else Tally(rows=size)
        if exact:
            n = np.abs(speed)
            d = np.where(direction_in > 0.0, 1, -1).astype(np.int64)
            return SufficientStats(_temperature_bin(t, temperature_resolution_c), d, _speed_bin(n, speed_ratio),
                                   np.arange(size, dtype=np.int64), np.ones(size), t.copy(), n.copy(), y.copy(),
                                   np.zeros(size), base_tally, temperature_resolution_c, speed_ratio, True)
        parts = []
        for a in range(0, size, CHUNK):
            b = min(a + CHUNK, size)
            n = np.abs(speed[a:b])
            positive = direction_in[a:b] > 0.0   # (_cells takes ±1 or this mask)
            batch = (clock[a:b] if clock is not None else np.arange(a, b, dtype=np.float64)) / width
            np.floor(batch, out=batch)
            bad = ~np.isfinite(batch)
            if bad.any():
                batch[bad] = -1.0
            parts.append(_cells(_temperature_bin(t[a:b], temperature_resolution_c), positive,
                                _speed_bin(n, speed_ratio), batch.astype(np.int64), t[a:b], n, y[a:b],
                                temperature_resolution_c, speed_ratio))
        out = SufficientStats.empty(temperature_resolution_c=temperature_resolution_c, speed_ratio=speed_ratio,
                                    tally=base_tally)
        return _merge_cells([out, *parts], base_tally)

    def merge(self, *others: SufficientStats) -> SufficientStats:
        """These statistics and ``others`` together (associative and commutative to rounding).

        Raises:
            ValueError: different bin resolutions, or exact with binned statistics.
        """
        for o in others:
            if (o.temperature_resolution_c, o.speed_ratio, o.exact) != \
                    (self.temperature_resolution_c, self.speed_ratio, self.exact):
                msg = 'cannot merge statistics of different bin resolutions (or exact with binned)'
                raise ValueError(msg)
        tally = self.tally
        for o in others:
            tally = tally.merge(o.tally)
        if self.exact:
            cols = [np.concatenate([getattr(s, name) for s in (self, *others)]) for name in _CELL_FIELDS]
            offset = 0
            batches = []
            for s in (self, *others):  # exact: keep every sample its own cell, in order
                batches.append(s.batch - (s.batch.min() if len(s) else 0) + offset)
                offset += len(s)
            cols[3] = np.concatenate(batches)
            return SufficientStats(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6], cols[7], cols[8],
                                   tally, self.temperature_resolution_c, self.speed_ratio, True)
        return _merge_cells([self, *others], tally)

    def only_direction(self, sign: int) -> SufficientStats:
        """The cells of one direction (``sign`` +1: positive motion, the paper's CW; −1), the same tally."""
        keep = self.direction == (1 if sign > 0 else -1)
        return SufficientStats(self.t_index[keep], self.direction[keep], self.s_index[keep], self.batch[keep],
                               self.samples[keep], self.sum_t[keep], self.sum_n[keep], self.mean_y[keep],
                               self.m2_y[keep], self.tally, self.temperature_resolution_c, self.speed_ratio,
                               self.exact)

    def with_tally(self, tally: Tally) -> SufficientStats:
        """The same cells with another tally."""
        return self._replace(tally=tally)


_CELL_FIELDS = ('t_index', 'direction', 's_index', 'batch', 'samples', 'sum_t', 'sum_n', 'mean_y', 'm2_y')


def _temperature_bin(t: Array, resolution: float) -> IntArray:
    """Fine temperature bin ``floor(t / resolution)`` [-] of temperatures [°C]."""
    b = t / resolution
    np.floor(b, out=b)
    return b.astype(np.int64)


def _speed_bin(n: Array, ratio: float) -> IntArray:
    """Fine speed bin ``floor(ln n / ln ratio)`` [-] of speeds [rpm] (> 0)."""
    b = np.log(n)
    b /= math.log(ratio)
    np.floor(b, out=b)
    return b.astype(np.int64)


def _cells(ti: IntArray, d: IntArray | NDArray[np.bool_], si: IntArray, batch: IntArray, t: Array, n: Array,
           y: Array, resolution: float, ratio: float) -> SufficientStats:
    """Cells of one block of samples: the four keys packed into one integer cell code (mixed radix over the
    block's key ranges), then per-cell sums with ``np.bincount`` (no sort; ``np.unique`` of the codes only when
    the key ranges are too wide for a dense code); ``M2`` is the centred second pass."""
    size = ti.shape[0]
    if size == 0:
        return SufficientStats.empty(temperature_resolution_c=resolution, speed_ratio=ratio)
    positive = d if d.dtype == np.bool_ else d > 0   # d: ±1, or the mask of d > 0
    keys = (ti, si, batch)
    lows = [int(k.min()) for k in keys]
    spans = [int(k.max()) - lo + 1 for k, lo in zip(keys, lows, strict=True)]
    radix = (spans[0], 2, spans[1], spans[2])   # code = ((t·2 + positive)·S + s)·B + batch
    total = math.prod(radix)
    if total < 1 << 62:
        code = ti - lows[0]
        code *= 2
        code += positive
        if spans[1] > 1:   # (a key of one value adds nothing to the code)
            code *= spans[1]
            code += si
            code -= lows[1]
        if spans[2] > 1:
            code *= spans[2]
            code += batch
            code -= lows[2]
        if total <= 4 * size + 4096:
            counts = np.bincount(code, minlength=total)
            cells = np.flatnonzero(counts)
            count = counts[cells].astype(np.float64)
            remap = np.empty(total, dtype=np.int64)
            remap[cells] = np.arange(cells.shape[0])
            inverse = remap[code]
        else:
            cells, inverse, counts = np.unique(code, return_inverse=True, return_counts=True)
            count = counts.astype(np.float64)
        key_t, rest = np.divmod(cells, 2 * spans[1] * spans[2])
        key_d, rest = np.divmod(rest, spans[1] * spans[2])
        key_s, key_b = np.divmod(rest, spans[2])
        key_t += lows[0]
        key_s += lows[1]
        key_b += lows[2]
        key_d = np.where(key_d > 0, 1, -1)
    else:  # (key ranges beyond 2^62 cells: rows of keys)
        stacked: IntArray = np.column_stack((ti, positive, si, batch)).astype(np.int64)
        uniq, inverse, counts = np.unique(stacked, axis=0, return_inverse=True, return_counts=True)
        count = counts.astype(np.float64)
        key_t, key_s, key_b = uniq[:, 0], uniq[:, 2], uniq[:, 3]
        key_d = np.where(uniq[:, 1] > 0, 1, -1)
    inverse = inverse.reshape(-1)
    m = count.shape[0]
    mean_y = _sum(inverse, y, m) / count
    dev = y - mean_y[inverse]
    dev *= dev
    m2 = _sum(inverse, dev, m)
    return SufficientStats(key_t.astype(np.int64), key_d.astype(np.int64), key_s.astype(np.int64),
                           key_b.astype(np.int64), count, _sum(inverse, t, m), _sum(inverse, n, m), mean_y, m2,
                           Tally(), resolution, ratio, False)


def _sum(index: IntArray, weights: Array, m: int) -> Array:
    """Sum of ``weights`` per ``index`` (0 … m−1)."""
    return np.asarray(np.bincount(index, weights=weights, minlength=m), dtype=np.float64)


def _merge_cells(parts: list[SufficientStats], tally: Tally) -> SufficientStats:
    """Cells with equal keys merged (Chan et al. for the centred sums), sorted by (batch, t, direction, speed)."""
    parts = [p for p in parts if len(p)]
    res, ratio = (parts[0].temperature_resolution_c, parts[0].speed_ratio) if parts else \
        (TEMPERATURE_RESOLUTION_C, SPEED_RATIO)
    if not parts:
        return SufficientStats.empty(temperature_resolution_c=res, speed_ratio=ratio, tally=tally)
    cols = {name: np.concatenate([getattr(p, name) for p in parts]) for name in _CELL_FIELDS}
    order = np.lexsort((cols['s_index'], cols['direction'], cols['t_index'], cols['batch']))
    cols = {k: v[order] for k, v in cols.items()}
    keys = np.column_stack([cols['batch'], cols['t_index'], cols['direction'], cols['s_index']])
    new = np.ones(keys.shape[0], dtype=bool)
    new[1:] = np.any(keys[1:] != keys[:-1], axis=1)
    starts = np.flatnonzero(new)
    if starts.shape[0] == keys.shape[0]:
        return SufficientStats(cols['t_index'], cols['direction'], cols['s_index'], cols['batch'], cols['samples'],
                               cols['sum_t'], cols['sum_n'], cols['mean_y'], cols['m2_y'], tally, res, ratio, False)
    group = np.cumsum(new) - 1
    c = cols['samples']
    count = np.add.reduceat(c, starts)
    sum_y = np.add.reduceat(c * cols['mean_y'], starts)
    mean = sum_y / count
    # Chan: M2 = Σ M2_k + Σ c_k (ȳ_k − ȳ)²
    m2 = np.add.reduceat(cols['m2_y'] + c * (cols['mean_y'] - mean[group]) ** 2, starts)
    return SufficientStats(cols['t_index'][starts], cols['direction'][starts], cols['s_index'][starts],
                           cols['batch'][starts], count, np.add.reduceat(cols['sum_t'], starts),
                           np.add.reduceat(cols['sum_n'], starts), mean, m2, tally, res, ratio, False)


# ------------------------------------------------------------------------------------------------------------
# from residual rows


def rows_samples(rows: ResidualRows, joint: str, direction: str = 'both') -> tuple[Array, Array, Array, Array,
                                                                                    Array, Tally]:
    """The refit samples of ``joint`` in ``rows``: temperature [°C], speed [rpm], |friction| along the motion
    [N·m], direction ±1, stamp [s], and the tally (rows, skipped, K_T and I_0 seen).

    Rows with a non-finite temperature, velocity or measurement, or at zero velocity, are skipped and counted;
    ``direction`` 'cw' or 'ccw' keeps positive or negative motion only.
    """
    sel = rows.joint == joint
    if direction != 'both':
        sel = sel & ((rows.velocity_rad_s > 0.0) if direction == 'cw' else (rows.velocity_rad_s < 0.0))
    t = rows.temperature_c[sel]
    v = rows.velocity_rad_s[sel]
    m = rows.measured_nm[sel]
    finite = np.isfinite(t) & np.isfinite(v) & np.isfinite(m)
    moving = finite & (v != 0.0)
    sign = np.sign(v[moving])
    kt = rows.torque_constant_nm_per_a[sel][moving]
    i0 = rows.no_load_current_a[sel][moving]
    kt = kt[np.isfinite(kt)]
    i0 = i0[np.isfinite(i0)]
    tally = Tally(int(sel.sum()), int((~finite).sum()), int((finite & ~moving).sum()),
                  float(kt.sum()), int(kt.shape[0]), float(kt.min()) if kt.size else math.inf,
                  float(kt.max()) if kt.size else -math.inf, float(i0.sum()), int(i0.shape[0]),
                  float(i0.min()) if i0.size else math.inf, float(i0.max()) if i0.size else -math.inf)
    return (t[moving], np.abs(v[moving]) * RPM_PER_RAD_S, m[moving] * sign, sign, rows.stamp_s[sel][moving], tally)


def accumulate_rows(rows: ResidualRows, into: dict[str, SufficientStats], *, joints: list[str] | None = None,
                    direction: str = 'both', batch_s: float = BATCH_S) -> dict[str, SufficientStats]:
    """Add the samples of ``rows`` (one chunk of a residual log) to the per-joint statistics ``into`` (updated in
    place and returned); ``joints`` limits the joints (default: every joint in the rows)."""
    present = sorted({str(j) for j in np.unique(rows.joint).tolist()}) if len(rows) else []
    for joint in present:
        if joints is not None and joint not in joints:
            continue
        t, n, y, d, stamp, tally = rows_samples(rows, joint, direction)
        chunk = SufficientStats.from_arrays(t, n, y, d, time=stamp, batch_width=batch_s, tally=tally)
        into[joint] = into[joint].merge(chunk) if joint in into else chunk
    return into
