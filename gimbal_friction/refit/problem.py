"""The refit's least-squares problem: points (fine bins), groups (plateaus by temperature bin, direction and speed)
and their weights, the robust loss, the solve and the covariance."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from gimbal_friction.common.errors import FitError
from gimbal_friction.common.units import NM_PER_NMM
from gimbal_friction.estimation.plateaus import plateau_of
from gimbal_friction.refit.model import SampleModel
from gimbal_friction.refit.results import ASYMMETRY_PARAMETERS, OFFSET, SPEED_BIN_RATIO, Array
from gimbal_friction.refit.sufficient import SufficientStats

# ------------------------------------------------------------------------------------------------------------
# points (fine bins), groups and weights


class _Points(NamedTuple):
    """Fine bins of the statistics: the model is evaluated at their mean temperature and speed."""

    weight: Array                # samples [-]
    t: Array                     # mean temperature [°C]
    n: Array                     # mean speed [rpm]
    d: Array                     # ±1
    y: Array                     # mean |τ| [N·m]
    m2: Array                    # Σ (y − ȳ)² [N²·m²]
    cell_point: NDArray[np.intp]  # point of every cell of the statistics


def _points(stats: SufficientStats) -> _Points:
    c = stats.samples
    if stats.exact:
        return _Points(c, stats.sum_t / c, stats.sum_n / c, stats.direction.astype(float), stats.mean_y, stats.m2_y,
                       np.arange(len(stats), dtype=np.intp))
    keys = np.column_stack([stats.t_index, stats.direction, stats.s_index])
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1).astype(np.intp)
    m = int(inverse.max()) + 1 if inverse.size else 0
    count = _sum(inverse, c, m)
    y = _sum(inverse, c * stats.mean_y, m) / count
    m2 = _sum(inverse, stats.m2_y + c * (stats.mean_y - y[inverse]) ** 2, m)
    d = np.zeros(m)
    d[inverse] = stats.direction
    return _Points(count, _sum(inverse, stats.sum_t, m) / count, _sum(inverse, stats.sum_n, m) / count, d, y, m2,
                   inverse)


def _sum(index: NDArray[np.intp], weights: Array, m: int) -> Array:
    """Sum of ``weights`` per ``index`` (0 … m−1)."""
    return np.asarray(np.bincount(index, weights=weights, minlength=m), dtype=np.float64)


class _Groups(NamedTuple):
    of: NDArray[np.intp]         # group of every point (−1: dropped)
    size: Array                  # samples per group
    t_bin: Array                 # bin centre [°C]
    direction: NDArray[np.int64]
    speed_bin: NDArray[np.int64]
    all_index: NDArray[np.intp]  # group of every point among all groups (used or not)
    all_count: Array
    all_keys: list[tuple[float, int, int]]
    used: NDArray[np.bool_]      # per entry of all_keys


def _group(pts: _Points, bin_width_c: float, min_bin_samples: int) -> _Groups:
    t_bin = plateau_of(pts.t, bin_width_c)  # the one plateau rule (replay's summary and report use it too)
    s_bin = np.round(np.log(pts.n) / math.log(SPEED_BIN_RATIO)).astype(np.int64)
    d = np.where(pts.d > 0, 1, -1).astype(np.int64)
    keys = np.column_stack([t_bin, d.astype(float), s_bin.astype(float)])
    uniq_arr, all_index = np.unique(keys, axis=0, return_inverse=True)
    all_index = all_index.reshape(-1).astype(np.intp)
    uniq = [(float(a), int(b), int(c)) for a, b, c in uniq_arr.tolist()]
    all_count = _sum(all_index, pts.weight, len(uniq))
    used = all_count >= min_bin_samples
    remap = np.full(len(uniq), -1, dtype=np.intp)
    remap[used] = np.arange(int(used.sum()))
    index = remap[all_index]
    sel = np.flatnonzero(used)
    return _Groups(index, all_count[used], np.array([uniq[i][0] for i in sel]),
                   np.array([uniq[i][1] for i in sel], dtype=np.int64),
                   np.array([uniq[i][2] for i in sel], dtype=np.int64), all_index, all_count, uniq, used)


def _group_mean(index: NDArray[np.intp], size: Array, weights: Array, values: Array) -> Array:
    """Sample-weighted mean of point ``values`` per group (``index`` of the used points)."""
    return np.bincount(index, weights=weights * values, minlength=size.shape[0]) / size


def _group_se(stats: SufficientStats, pts: _Points, groups: _Groups, tau0: Array, mean_abs: Array,
              floor_rel: float) -> Array:
    """Standard error of each group mean: max(i.i.d., batch means) combined with a relative floor, [N·m].

    i.i.d.: the sample standard deviation of (measured − base model) from the points' centred sums. Batch means:
    the group's cells in time order cut into 10 consecutive stretches of (nearly) equal sample counts, as
    ``numpy.array_split`` cuts samples; a cell goes to the stretch its first sample falls in.
    """
    k = groups.size.shape[0]
    used_pt = groups.of >= 0
    idx = groups.of[used_pt]
    c = pts.weight[used_pt]
    r = (pts.y - tau0)[used_pt]
    r_mean = np.bincount(idx, weights=c * r, minlength=k) / groups.size
    ss = np.bincount(idx, weights=pts.m2[used_pt] + c * (r - r_mean[idx]) ** 2, minlength=k)
    n = groups.size
    s = np.sqrt(np.where(n > 1.0, ss / np.maximum(n - 1.0, 1.0), 0.0))
    se = s / np.sqrt(n)
    # batch means over the cells
    cell_group = groups.of[pts.cell_point]
    keep = cell_group >= 0
    cg = cell_group[keep]
    cc = stats.samples[keep]
    cr = stats.mean_y[keep] - tau0[pts.cell_point[keep]]
    order = np.lexsort((np.flatnonzero(keep), stats.batch[keep], cg))
    cg, cc, cr = cg[order], cc[order], cr[order]
    bounds = np.searchsorted(cg, np.arange(k + 1))
    for j in range(k):
        a, b = int(bounds[j]), int(bounds[j + 1])
        total = int(round(float(n[j])))
        if total < 20 or b - a < 2:
            continue
        counts = cc[a:b]
        first = np.concatenate([[0.0], np.cumsum(counts)[:-1]])  # position of each cell's first sample
        size, extra = divmod(total, 10)
        edges = np.array([i * size + min(i, extra) for i in range(11)], dtype=float)
        which = np.searchsorted(edges, first, side='right') - 1
        bsum = np.bincount(which, weights=counts * cr[a:b], minlength=10)
        bcnt = np.bincount(which, weights=counts, minlength=10)
        ok = bcnt > 0
        if int(ok.sum()) < 2:
            continue
        means = bsum[ok] / bcnt[ok]
        se[j] = max(float(se[j]), float(np.std(means, ddof=1)) / math.sqrt(int(ok.sum())))
    return np.maximum(np.hypot(se, floor_rel * mean_abs), 1e-12)


# ------------------------------------------------------------------------------------------------------------
# the fit


def _rho(z: Array, loss: str) -> Array:
    if loss == 'linear':
        return z
    if loss == 'soft_l1':
        return 2.0 * (np.sqrt(1.0 + z) - 1.0)
    if loss == 'huber':
        return np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    if loss == 'cauchy':
        return np.log1p(z)
    return np.arctan(z)


def _cost(r: Array, loss: str, f_scale: float) -> float:
    return float(0.5 * f_scale**2 * np.sum(_rho((r / f_scale) ** 2, loss)))


class _Solution(NamedTuple):
    values: dict[str, float]       # all fit parameters and the offset
    internal: Array
    jac_internal: Array            # weighted jacobian of the group residuals, internal parameters
    to_raw: Array                  # d(raw active)/d(internal active)
    residuals: Array               # weighted group residuals
    cost: float
    nfev: int
    message: str
    status: int


class _Problem:
    """Weighted group residuals r_j = (ȳ_j − mean model_j)/se_j as a function of the active parameters."""

    def __init__(self, model: SampleModel, pts: _Points, groups: _Groups, y_mean: Array, se: Array, x_ref: float,
                 loss: str, f_scale: float, max_nfev: int, absolute: bool) -> None:
        self.model = model
        self.pts = pts
        self.groups = groups
        self.y_mean = y_mean
        self.se = se
        self.x_ref = x_ref
        self.loss = loss
        self.f_scale = f_scale
        self.max_nfev = max_nfev
        self.base = model.values()
        self.used = groups.of >= 0
        self.absolute = absolute  # weights are 1/standard error (False: relative, scale from the residuals)
        self.offset_limit = float(np.min(np.abs(y_mean))) if y_mean.size else 0.0

    # internal <-> raw: a' = a + b x_ref (centred Walther form), everything else raw
    def _to_values(self, names: Sequence[str], theta: Array) -> dict[str, float]:
        v = dict(self.base)
        v.update({name: float(x) for name, x in zip(names, theta, strict=False)})
        if 'walther_a' in names:
            v['walther_a'] = v['walther_a'] - v['walther_b'] * self.x_ref
        return v

    def internal0(self, names: Sequence[str]) -> Array:
        v = self.base
        return np.array([v['walther_a'] + v['walther_b'] * self.x_ref if name == 'walther_a' else v[name]
                         for name in names])

    def bounds(self, names: Sequence[str]) -> tuple[Array, Array]:
        v = self.base
        lo, hi = [], []
        for name, x0 in zip(names, self.internal0(names), strict=False):
            if name == 'walther_a':
                lo.append(x0 - 0.3)
                hi.append(x0 + 0.3)
            elif name == 'walther_b':
                lo.append(3.0 * v[name])
                hi.append(v[name] / 3.0)
            elif name == 'viscosity_offset_cst':
                lo.append(-1.0)
                hi.append(100.0)
            elif name in ASYMMETRY_PARAMETERS:
                lo.append(-0.9)
                hi.append(0.9)
            elif name == OFFSET:
                lo.append(-self.offset_limit)
                hi.append(self.offset_limit)
            else:
                top = {'palmgren_factor': 100.0, 'sliding_friction_coefficient': 2.0}.get(name, 10.0)
                lo.append(x0 / 20.0)
                hi.append(min(top, 20.0 * x0) if x0 > 0.0 else top)
        return np.array(lo), np.array(hi)

    def residuals(self, names: Sequence[str], theta: Array) -> Array:
        v = self._to_values(names, theta)
        tau = self.model.torque_nmm(v)[self.used] * NM_PER_NMM
        g = self.groups
        return (self.y_mean - _group_mean(g.of[self.used], g.size, self.pts.weight[self.used], tau)) / self.se

    def jacobian(self, names: Sequence[str], theta: Array) -> Array:
        v = self._to_values(names, theta)
        raw = self.model.jacobian_nmm(v, names)[self.used] * NM_PER_NMM
        if 'walther_a' in names and 'walther_b' in names:  # d/db at fixed a' = d/db raw − x_ref d/da raw
            ia, ib = names.index('walther_a'), names.index('walther_b')
            raw[:, ib] = raw[:, ib] - self.x_ref * raw[:, ia]
        g = self.groups
        idx = g.of[self.used]
        w = self.pts.weight[self.used]
        cols = [np.bincount(idx, weights=w * raw[:, k], minlength=g.size.shape[0]) / g.size
                for k in range(len(names))]
        return -np.column_stack(cols) / self.se[:, None]

    def solve(self, names: Sequence[str]) -> _Solution:
        x0 = self.internal0(names)
        lo, hi = self.bounds(names)
        cost0 = _cost(self.residuals(names, x0), self.loss, self.f_scale)
        with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
            res = least_squares(lambda th: self.residuals(names, th), x0, jac=lambda th: self.jacobian(names, th),
                                bounds=(lo, hi), method='trf', x_scale='jac', loss=self.loss,
                                f_scale=self.f_scale, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                                max_nfev=self.max_nfev)
        if res.status <= 0 or not np.all(np.isfinite(res.fun)) or not np.all(np.isfinite(res.x)):
            msg = (f'the fit of {", ".join(_label(n) for n in names)} did not converge after {res.nfev} evaluations '
                   f'({res.message})')
            raise FitError(msg)
        if res.cost > cost0 * (1.0 + 1e-9) + 1e-300:
            msg = (f'the fit of {", ".join(_label(n) for n in names)} diverged: the cost rose from {cost0:.6g} to '
                   f'{res.cost:.6g}')
            raise FitError(msg)
        span = hi - lo
        for name, x, low, high, width in zip(names, res.x, lo, hi, span, strict=False):
            if (x - low <= 1e-6 * width and low != 0.0) or high - x <= 1e-6 * width:
                raw = self._to_values(names, res.x)[name]
                msg = (f'the fit diverged: {_label(name)} ran to the edge of its plausible range ({raw:.6g}); the '
                       'data do not support a physical value (check the logs, the temperature sensor and the base '
                       'parameters)')
                raise FitError(msg)
        values = self._to_values(names, res.x)
        nu = self.model.viscosity_cst(values)
        if not np.all(nu > 0.0):
            msg = 'the fit diverged: the refitted viscosity is not positive at some data temperatures'
            raise FitError(msg)
        to_raw = np.eye(len(names))
        if 'walther_a' in names and 'walther_b' in names:
            to_raw[names.index('walther_a'), names.index('walther_b')] = -self.x_ref
        return _Solution(values, res.x, self.jacobian(names, res.x), to_raw, res.fun, float(res.cost),
                         int(res.nfev), str(res.message), int(res.status))


def _label(name: str) -> str:
    return 'the torque offset' if name == OFFSET else name


def _covariance(sol: _Solution, absolute: bool) -> tuple[Array, int]:
    """Covariance of the internal parameters and the degrees of freedom.

    With absolute weights (1/se) it is scaled by max(1, χ²/dof); with relative weights (no absolute scale) by
    χ²/dof, and infinite without degrees of freedom.
    """
    J = sol.jac_internal
    m, p = J.shape
    dof = m - p
    chi2 = float(sol.residuals @ sol.residuals)
    if absolute:
        s2 = max(1.0, chi2 / dof) if dof > 0 else 1.0
    else:
        s2 = chi2 / dof if dof > 0 else math.inf
    try:
        cov = np.linalg.inv(J.T @ J) * s2
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.inf)
    return cov, dof


def _distinct_viscous_temperatures(pts: _Points, groups: _Groups, upper: NDArray[np.bool_],
                                   min_bin_samples: int) -> list[float]:
    """Temperature bins of used groups with at least half (and ``min_bin_samples``) of their samples in the upper
    Palmgren branch."""
    g = groups
    used = g.of >= 0
    n_upper = np.bincount(g.of[used], weights=pts.weight[used] * upper[used].astype(float),
                          minlength=g.size.shape[0])
    ok = (n_upper >= min_bin_samples) & (n_upper >= 0.5 * g.size)
    return sorted({float(x) for x in g.t_bin[ok]})
