r"""What a correction's rows say: the fit of every term, and the search for ripple periods (pure numpy).

One job in one module: :func:`fit_joint` (the terms of every temperature bin of one joint, from its rows, with the
ripple periods found in the rows themselves by :func:`~gimbal_friction.feedforward.correction.periods.\
strongest_period_GLS_Zechmeister_2009`).

Per temperature bin, both directions together, the residual along the motion of a row of direction d (sign
:math:`s_d` = +1 cw, −1 ccw), speed octave coordinate u, angle θ and model friction m is modelled as

.. math:: r = S_d(u) + m\,\rho(\theta) + h_1\sin\theta + h_2(\cos\theta - 1)
              + s_d\,[g_1\sin\theta + g_2(\cos\theta - 1)]

- :math:`S_d(u)` [N·m], the **speed profile** of direction d: piecewise linear in u = log2(|v| / min_speed) between
  the centres of the speed octaves (so it can rise like Palmgren's viscous torque, fall like a Stribeck curve, or
  step where Palmgren's two branches meet). It is fitted as its part along the motion O = ½(S_cw + S_ccw) and its
  part independent of the direction E = ½(S_cw − S_ccw); neighbouring octaves are tied by ``speed_smoothing`` × n0:
  O to the model's own shape over speed (O_k / m_k alike at neighbouring octaves, m_k the octave's mean |model|: a
  lubricant off its datasheet is a share of a viscous torque that rises from octave to octave), E to a constant (an
  unbalance does not depend on speed). A profile with kinks learned where speed is confounded with position,
  acceleration or time in the data made the loop worse than the model. An octave without data takes its
  neighbours' value for E, while O is 0 there (a level learned at one speed is not carried where nothing showed
  it);
- :math:`\rho(\theta) = \sum_p a_p\cos(2\pi\theta/P_p) + b_p\sin(2\pi\theta/P_p)` [-], the **ripple**, relative to
  the model friction (a race's waviness modulates the friction it carries) and the same in both directions, at the
  periods :math:`P_p` found in the rows (the position bins' averaging is undone: sinc(δ/P)); in a temperature bin
  whose positions span less than a period, that period is left out (it cannot be told from the level there);
- :math:`h` [N·m], a slow change of the friction with the angle (the **trend**, along the motion), and :math:`g`
  [N·m], a torque that does **not** depend on the direction of motion (an unbalance or a cable, :math:`g_1\sin\theta
  + g_2\cos\theta` up to a constant, which :math:`S_{cw} - S_{ccw}` holds): applied without the sign of the motion
  (see :mod:`~gimbal_friction.feedforward.correction.lookup`), so it does not flip at a reversal.

Weighted least squares over the rows (weight = samples), every term shrunk towards 0 like ``prior_samples`` (n0)
samples of zero residual (the level of each part, O and E: :math:`\sum r/(n + n_0)` for one octave; a ripple like
n0 samples at the bin's mean |model|; a trend like n0 samples one radian away). Then bounded: at each speed node
the part along the motion O by ``max_relative`` × the mean |model| + ``floor_nm``, the part independent of the
direction E by that or ``max_independent_nm``, whichever is larger (``saturated`` where the data asked for more), a
ripple's amplitude by ``max_relative``.

Periods: the rows' residual left after the fit, relative to the model and pooled over temperature bins and
directions at each position bin, is searched for its strongest sinusoid between 4 position bins and
``ripple_period_max_rad`` (at most half the travel seen); kept when its amplitude is ``ripple_min_z`` standard
errors and at least ``ripple_min_relative`` of the model friction; then the fit is repeated with it and the search
goes on, up to ``ripple_periods_max`` periods.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.feedforward.correction.periods import Period, strongest_period_GLS_Zechmeister_2009
from gimbal_friction.feedforward.correction.settings import CorrectionSettings
from gimbal_friction.feedforward.correction.stats import JointStats

__all__ = ['Fit', 'Params', 'Rows', 'bin_ranges', 'empty_params', 'fit_joint', 'fit_rows', 'joint_rows',
           'rising_envelope']

Array = NDArray[np.float64]
#: trend coefficients: along the motion (sin θ, cos θ − 1), then direction-independent (sin θ, cos θ − 1)
TREND = ('odd_sin', 'odd_cos', 'even_sin', 'even_cos')


class Params(NamedTuple):
    """The terms of one joint's correction: what a lookup reads (applied), what learning aims at (target)."""

    speed_nm: Array      #: (2, temperature bins, speed octaves) speed profile along the motion [N·m], cw first
    periods_rad: Array   #: (K,) ripple periods [rad]
    ripple: Array        #: (temperature bins, K, 2) relative ripple coefficients (cos, sin) [-]
    trend_nm: Array      #: (temperature bins, 4) trend coefficients (:data:`TREND`) [N·m]

    def copy(self) -> Params:
        """An independent copy."""
        return Params(self.speed_nm.copy(), self.periods_rad.copy(), self.ripple.copy(), self.trend_nm.copy())


def empty_params(s: CorrectionSettings, periods_rad: Array | None = None) -> Params:
    """All terms 0 (the pure model)."""
    nt = s.n_temperature
    p = np.zeros(0) if periods_rad is None else np.asarray(periods_rad, dtype=float)
    return Params(np.zeros((2, nt, s.n_speed)), p, np.zeros((nt, p.size, 2)), np.zeros((nt, 4)))


class Fit(NamedTuple):
    """What the rows of one joint say (:func:`fit_joint`)."""

    params: Params            #: the fitted terms, bounded
    flat_nm: Array            #: (2, temperature bins) level of each cell: its speed profile averaged over its data
    model_nm: Array           #: (2, temperature bins) mean |model| of each cell's samples [N·m] (0: no data)
    samples: Array            #: (2, temperature bins) samples per cell [-]
    saturated: NDArray[np.bool_]   #: (2, temperature bins) a speed node's value was clipped by the bound
    periods: tuple[Period, ...]    #: the periods found and their evidence
    angle_range_rad: tuple[float, float] | None   #: positions seen (position bin centres) [rad]; None: none
    node_model_nm: Array      #: (2, temperature bins, octaves) mean |model| at each speed node [N·m] (0: no data)
    node_weight: Array        #: (2, temperature bins, octaves) the data's weight on each speed node [-]
    bin_ranges_rad: Array     #: (temperature bins, 2) positions each bin's data covered [rad] (NaN: none)


class Rows(NamedTuple):
    """The rows of one joint, decoded (one entry per row with data)."""

    direction: NDArray[np.int64]   #: 0 cw, 1 ccw
    tbin: NDArray[np.int64]        #: temperature bin
    n: Array                       #: samples [-]
    r: Array                       #: mean residual along the motion [N·m]
    m: Array                       #: mean |model| [N·m]
    u: Array                       #: mean octave coordinate [-]
    theta: Array                   #: position bin centre [rad] (NaN: no position)

    def select(self, index: NDArray[np.intp]) -> Rows:
        """The rows at ``index``."""
        return Rows(self.direction[index], self.tbin[index], self.n[index], self.r[index], self.m[index],
                    self.u[index], self.theta[index])


def joint_rows(stats: JointStats) -> Rows:
    """The rows of ``stats`` as means (see :class:`Rows`)."""
    keys, sums = stats.rows()
    d, b, _, j, known = stats.decode(keys)
    n = sums[:, 0]
    s = stats.settings
    theta = np.where(known, (j + 0.5) * s.position_resolution_rad - math.pi, np.nan)
    with np.errstate(invalid='ignore', divide='ignore'):
        return Rows(d, b, n, sums[:, 1] / n, sums[:, 2] / n, sums[:, 3] / n, theta)


def _hats(s: CorrectionSettings, rows: Rows) -> Array:
    """The rows' weights on the speed octave nodes (linear hats in the octave coordinate u) (rows, octaves)."""
    ns = s.n_speed
    h = np.zeros((rows.n.size, ns))
    idx = np.arange(rows.n.size)
    if ns > 1:
        xh = np.clip(rows.u - 0.5, 0.0, ns - 1.0)
        k0 = np.minimum(xh.astype(np.int64), ns - 2)
        f = xh - k0
        h[idx, k0] = 1.0 - f
        h[idx, k0 + 1] = f
    else:
        h[idx, 0] = 1.0
    return h


def _design(s: CorrectionSettings, rows: Rows, periods: Array) -> Array:
    """The rows' design matrix (columns: speed nodes cw, ccw; ripple cos, sin per period; trend)."""
    ns = s.n_speed
    k_per = periods.size
    ncol = 2 * ns + 2 * k_per + (4 if s.trend else 0)
    x = np.zeros((rows.n.size, ncol))
    hats = _hats(s, rows)
    sign = np.where(rows.direction == 0, 1.0, -1.0)
    x[:, :ns] = hats                          # the part along the motion, O: S_cw = O + E, S_ccw = O - E
    x[:, ns:2 * ns] = hats * sign[:, None]    # the part independent of the direction, E
    known = np.isfinite(rows.theta)
    th = np.where(known, rows.theta, 0.0)
    for p, period in enumerate(periods.tolist()):
        phase = 2.0 * math.pi * th / period
        gain = np.sinc(s.position_resolution_rad / period) * rows.m * known   # the bin's average of the sine
        x[:, 2 * ns + 2 * p] = gain * np.cos(phase)
        x[:, 2 * ns + 2 * p + 1] = gain * np.sin(phase)
    if s.trend:
        base = 2 * ns + 2 * k_per
        sign = np.where(rows.direction == 0, 1.0, -1.0)
        sn, cs = np.sin(th) * known, (np.cos(th) - 1.0) * known
        x[:, base], x[:, base + 1], x[:, base + 2], x[:, base + 3] = sn, cs, sign * sn, sign * cs
    return x


def _solve_bin(s: CorrectionSettings, x: Array, rows: Rows, periods: Array) -> Array:
    """Coefficients of one temperature bin's rows (weighted least squares with the priors of the module notes).

    A ripple period enters only where the bin's positions span at least one period (else it would take a share of
    the level it cannot tell apart from it); the trend's prior is that of n0 samples one radian off (a trend needs
    the travel to show it)."""
    ns, n0 = s.n_speed, s.prior_samples
    w = rows.n
    xw = x * w[:, None]
    a = x.T @ xw
    c = xw.T @ rows.r
    lam = s.speed_smoothing * n0
    hw = x[:, :ns] * w[:, None]
    wk = hw.sum(axis=0)
    # the part along the motion is tied to the model's own shape over speed (a lubricant off its datasheet is a
    # share of the viscous torque, which rises ~(nu n)^(2/3) from octave to octave); the part independent of the
    # direction to a constant
    m_node = np.divide(hw.T @ rows.m, wk, out=np.zeros(ns), where=wk > 0.0)
    have = m_node > 0.0
    if have.any():
        m_node = np.interp(np.arange(ns), np.flatnonzero(have), m_node[have])
    else:
        m_node = np.ones(ns)
    for part in range(2):
        block = slice(part * ns, (part + 1) * ns)
        if wk.sum() > 0.0:
            q = wk / wk.sum()
            a[block, block] += n0 * np.outer(q, q)
        for k in range(ns - 1):
            if part == 0:
                mid = 0.5 * (m_node[k] + m_node[k + 1])
                g0, g1 = mid / m_node[k], mid / m_node[k + 1]
            else:
                g0 = g1 = 1.0
            i, j = part * ns + k, part * ns + k + 1
            a[i, i] += lam * g0 * g0
            a[j, j] += lam * g1 * g1
            a[i, j] -= lam * g0 * g1
            a[j, i] -= lam * g0 * g1
    a[np.arange(2 * ns), np.arange(2 * ns)] += 1e-6 * n0 + 1e-12
    known = np.isfinite(rows.theta)
    span = float(rows.theta[known].max() - rows.theta[known].min()) if known.any() else 0.0
    m_bar = float(np.average(rows.m, weights=w)) if w.sum() > 0 else 0.0
    prior = np.zeros(x.shape[1])
    for p, period in enumerate(periods.tolist()):
        col = 2 * ns + 2 * p
        prior[col:col + 2] = n0 * 0.5 * m_bar * m_bar if span >= period else 1e12 * (1.0 + a[col, col])
    if s.trend:
        base = 2 * ns + 2 * periods.size
        prior[base:base + 4] = n0 * np.array([1.0, 0.25, 1.0, 0.25])
    rest = np.arange(2 * ns, x.shape[1])
    a[rest, rest] += prior[rest] + 1e-12
    try:
        return np.asarray(np.linalg.solve(a, c), dtype=float)
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.lstsq(a, c, rcond=None)[0], dtype=float)


def fit_rows(s: CorrectionSettings, rows: Rows, periods: Array
             ) -> tuple[Params, Array, Array, Array, Array, Array]:
    """The unbounded terms of every temperature bin for ``periods`` [rad], the row predictions [N·m], and per cell
    the data-weighted level [N·m], mean |model| [N·m], the per-node mean |model| and data weight (2, bins, octaves)
    [N·m], [-]."""
    nt, ns = s.n_temperature, s.n_speed
    k_per = periods.size
    out = empty_params(s, periods)
    pred = np.zeros(rows.n.size)
    flat = np.zeros((2, nt))
    cell_m = np.zeros((2, nt))
    node_m = np.zeros((2, nt, ns))
    node_w = np.zeros((2, nt, ns))
    x_all = _design(s, rows, periods)
    for b in np.unique(rows.tbin).tolist():
        sel = np.flatnonzero(rows.tbin == b)
        sub = rows.select(sel)
        x = x_all[sel]
        beta = _solve_bin(s, x, sub, periods)
        pred[sel] = x @ beta
        odd, even = beta[:ns], beta[ns:2 * ns]
        speed = np.stack([odd + even, odd - even])
        out.speed_nm[:, b, :] = speed
        out.ripple[b] = beta[2 * ns:2 * ns + 2 * k_per].reshape(k_per, 2)
        if s.trend:
            out.trend_nm[b] = beta[2 * ns + 2 * k_per:]
        hw = x[:, :ns] * sub.n[:, None]
        for d in range(2):
            xd = hw * (sub.direction == d)[:, None]
            wk = xd.sum(axis=0)
            node_w[d, b] = wk
            mine = sub.direction == d
            if wk.sum() > 0.0:
                flat[d, b] = float(wk @ speed[d]) / float(wk.sum())
                cell_m[d, b] = float(np.average(sub.m[mine], weights=sub.n[mine]))
                mk = (xd * sub.m[:, None]).sum(axis=0)
                have = wk > 0.0
                node_m[d, b, have] = mk[have] / wk[have]
                node_m[d, b, ~have] = np.interp(np.flatnonzero(~have), np.flatnonzero(have), node_m[d, b, have])
    return out, pred, flat, cell_m, node_m, node_w


def _fade_unseen(s: CorrectionSettings, p: Params, node_w: Array) -> Params:
    """The part along the motion at speed octaves no data showed set to 0: a speed node counts as seen with at least
    a fifth of ``prior_samples`` samples (either direction); between a seen node and an unseen one the correction
    goes linearly to the model. A level learned at one speed is not carried to speeds where nothing showed it (a
    chamber test at 1/3 rpm says nothing of a reversal's slow end, where a Stribeck rise or a Palmgren branch may
    differ); the part independent of the direction (an unbalance) does not depend on the speed and is kept."""
    seen = node_w.sum(axis=0) >= 0.2 * s.prior_samples                    # (bins, octaves)
    fade = seen.astype(float)
    odd = 0.5 * (p.speed_nm[0] + p.speed_nm[1]) * fade
    even = 0.5 * (p.speed_nm[0] - p.speed_nm[1])
    return Params(np.stack([odd + even, odd - even]), p.periods_rad, p.ripple, p.trend_nm)


def _bound(s: CorrectionSettings, p: Params, cell_m: Array, node_m: Array, samples: Array
           ) -> tuple[Params, NDArray[np.bool_]]:
    """``p`` within the bounds of the module notes, and the cells whose speed nodes were clipped."""
    ref = np.where(node_m > 0.0, node_m, np.where(cell_m > 0.0, cell_m, cell_m[::-1])[..., None])
    bound = np.minimum(s.max_relative * ref[0] + s.floor_nm, s.max_relative * ref[1] + s.floor_nm)
    # the part along the motion within the model's bound, the part independent of it within max_independent_nm too
    odd = 0.5 * (p.speed_nm[0] + p.speed_nm[1])
    even = 0.5 * (p.speed_nm[0] - p.speed_nm[1])
    even_bound = np.maximum(bound, s.max_independent_nm)
    odd_c, even_c = np.clip(odd, -bound, bound), np.clip(even, -even_bound, even_bound)
    speed = np.stack([odd_c + even_c, odd_c - even_c])
    clipped = (np.abs(odd) > bound * (1.0 + 1e-12)) | (np.abs(even) > even_bound * (1.0 + 1e-12))
    saturated = np.any(clipped, axis=1)[None, :] & (samples > 0)
    ripple = p.ripple
    if ripple.size:
        amp = np.hypot(ripple[..., 0], ripple[..., 1])
        scale = np.where(amp > s.max_relative, s.max_relative / np.maximum(amp, 1e-300), 1.0)
        ripple = ripple * scale[..., None]
    m_bin = cell_m.max(axis=0)
    trend_bound = 10.0 * np.maximum(s.max_relative * m_bin + s.floor_nm, s.max_independent_nm)
    trend = np.clip(p.trend_nm, -trend_bound[:, None], trend_bound[:, None])
    return Params(speed, p.periods_rad, ripple, trend), saturated


def _pooled_leftover(s: CorrectionSettings, rows: Rows, pred: Array) -> tuple[Array, Array, Array]:
    """The rows' residual after the fit relative to |model|, pooled per position bin: (angle [rad], mean [-],
    weight)."""
    known = np.isfinite(rows.theta) & (rows.m > 0.0) & (rows.n > 0.0)
    th = rows.theta[known]
    y = (rows.r[known] - pred[known]) / rows.m[known]
    w = rows.n[known] * rows.m[known] ** 2
    if th.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    uniq, inv = np.unique(th, return_inverse=True)
    wsum = np.bincount(inv, weights=w)
    ysum = np.bincount(inv, weights=w * y)
    return np.asarray(uniq, dtype=float), np.asarray(ysum / wsum, dtype=float), np.asarray(wsum, dtype=float)


def fit_joint(stats: JointStats, periods: tuple[Period, ...] | None = None) -> Fit:
    """The terms of one joint from its rows (see the module notes); ``periods`` given: used as they are (no
    search); None: searched in the rows."""
    s = stats.settings
    rows = joint_rows(stats)
    samples = np.zeros((2, s.n_temperature))
    np.add.at(samples, (rows.direction, rows.tbin), rows.n)
    known = np.isfinite(rows.theta)
    angle_range = (float(rows.theta[known].min()), float(rows.theta[known].max())) if known.any() else None
    found: list[Period] = list(periods) if periods is not None else []
    if periods is None and s.ripple_periods_max > 0 and angle_range is not None:
        p_min = 4.0 * s.position_resolution_rad
        for _ in range(s.ripple_periods_max):
            _, pred, *_ = fit_rows(s, rows, np.array([p.period_rad for p in found]))
            th, y, w = _pooled_leftover(s, rows, pred)
            new = strongest_period_GLS_Zechmeister_2009(th, y, w, p_min, s.ripple_period_max_rad)
            if new is None or not (new.z >= s.ripple_min_z and new.amplitude >= s.ripple_min_relative):
                break
            if any(abs(1.0 / new.period_rad - 1.0 / p.period_rad) < 1.0 / new.span_rad for p in found):
                break
            found.append(new)
    params, _, _, cell_m, node_m, node_w = fit_rows(s, rows, np.array([p.period_rad for p in found]))
    bounded, saturated = _bound(s, _fade_unseen(s, params, node_w), cell_m, node_m, samples)
    # each cell's level: its bounded profile averaged over its data
    wsum = node_w.sum(axis=2)
    flat = np.divide((node_w * bounded.speed_nm).sum(axis=2), wsum, out=np.zeros(wsum.shape), where=wsum > 0.0)
    return Fit(bounded, flat, cell_m, samples, saturated, tuple(found), angle_range, node_m, node_w,
               bin_ranges(rows, s.n_temperature))


def bin_ranges(rows: Rows, n_temperature: int) -> Array:
    """The positions each temperature bin's rows covered (temperature bins, 2): [lowest, highest] position bin
    centre [rad], NaN where a bin has no row with a position (the travel a bin's trend was seen on)."""
    out = np.full((n_temperature, 2), np.nan)
    known = np.isfinite(rows.theta)
    if known.any():
        tb, th = rows.tbin[known], rows.theta[known]
        lo, hi = np.full(n_temperature, np.inf), np.full(n_temperature, -np.inf)
        np.minimum.at(lo, tb, th)
        np.maximum.at(hi, tb, th)
        have = np.isfinite(lo)
        out[have, 0], out[have, 1] = lo[have], hi[have]
    return out


def rising_envelope(s: CorrectionSettings, speed_nm: Array, node_model_nm: Array, node_weight: Array) -> Array:
    """``speed_nm`` (2, bins, octaves) with its part along the motion O lowered where the friction it makes, model
    + O, falls with speed (a Stribeck curve): there a positive O is held to the lowest friction at any higher speed
    with data (never below 0), so what the correction adds never makes the friction fall as the speed rises (the
    part independent of the direction is left as it is).

    A feedforward that follows a friction falling with speed, a millisecond late, feeds the stick-slip it should
    cancel: on generated truths with a strong Stribeck effect even the truth's own static map made the loop worse
    than the model's feedforward (up to 1.4x), and a correction that had learned the fall did too (1.1-1.3x)."""
    out = speed_nm.copy()
    odd = 0.5 * (speed_nm[0] + speed_nm[1])                         # (bins, octaves)
    even = 0.5 * (speed_nm[0] - speed_nm[1])
    w = node_weight.sum(axis=0)
    m = np.divide((node_model_nm * node_weight).sum(axis=0), w, out=np.zeros(w.shape), where=w > 0.0)
    seen = w >= 0.2 * s.prior_samples
    total = np.where(seen, m + odd, np.inf)
    floor = np.minimum.accumulate(total[:, ::-1], axis=1)[:, ::-1]    # lowest friction at this or any higher speed
    # only what the correction adds is lowered, never below 0 (the model's own shape is the model's)
    held = np.where(seen & np.isfinite(floor) & (odd > 0.0), np.clip(floor - m, 0.0, np.maximum(odd, 0.0)), odd)
    out[0] = held + even
    out[1] = held - even
    return out
