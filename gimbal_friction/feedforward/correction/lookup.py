r"""The correction as the feedforward reads it: per call, its part along the motion and its direction-independent
part (pure numpy / floats; the feedforward's hot path).

One job in one module: :class:`Lookup` (the terms of one joint prepared for fast reading, on floats and on arrays:
the same numbers).

The terms of a cell (:mod:`~gimbal_friction.feedforward.correction.fit`) are per direction along the motion. The
feedforward applies them split into the part that follows the sign of the motion (**odd**) and the part that does
not (**even**),

.. math:: c_{odd} = \tfrac12(S_{cw} + S_{ccw}) + m\,\rho(\theta) + h(\theta),\qquad
          c_{even} = \tfrac12(S_{cw} - S_{ccw}) + g(\theta)

.. math:: \tau = \operatorname{clamp}\big(\tanh(v/v_{th})\,(k_d M + c_{odd}) + c_{even},\ \pm\tau_{max}\big)

(:func:`~gimbal_friction.feedforward.rule.corrected_torque_nm`). Away from zero speed this is exactly the learned
value of the direction of motion (cw: :math:`S_{cw} + …`; ccw: :math:`S_{ccw} + …` along the motion); through a
reversal the even part stays, so a torque that does not depend on the direction (an unbalance) is not switched off
and on at every reversal. Each part is bounded by ``max_relative`` × |model| + ``floor_nm`` (clipped lookups are
counted), the even part by ``max_independent_nm`` where that is larger (an unbalance may exceed the friction).

Below the slowest speed learned (``min_speed_rad_s``, where samples near a reversal are refused) the part along the
motion fades linearly to 0 at zero speed: through a reversal the feedforward is the model's (a friction learned at
speed, a Stribeck rise above all, is not what the bristles carry while the motion turns).

Temperature: linear between bin centres, held at the ends; a bin without samples next to one with samples holds its
neighbour's terms (the mean of both neighbours when both have samples), so the correction tapers to 0 one bin
further. Speed: linear in the octave coordinate between octave centres, held beyond. Position: the ripple and the
trend on a grid over the positions seen (half a position bin apart, linear between grid points); the ripple fades to
0 over one longest period beyond them; the trend of each temperature bin holds over the travel that bin's data
covered and falls to 0 over :data:`TREND_TAPER_RAD` beyond it (a change with the angle seen on −10°…+10° is not
extrapolated to +40°: there the feedforward is the model's).

What depends on the temperature only is prepared once per temperature (a controller's calls between two
temperature samples cost a few float operations each).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.feedforward.correction.fit import Params
from gimbal_friction.feedforward.correction.settings import CorrectionSettings

__all__ = ['TREND_TAPER_RAD', 'Lookup', 'PositionTerms', 'ScalarTerms', 'held_params', 'held_ranges', 'trend_taper']

Array = NDArray[np.float64]
#: :data:`ScalarTerms`' position terms: (ripple, trend odd, trend even) lists of one temperature (None when absent),
#: the position grid's origin [rad], its inverse step [1/rad] and its last index
PositionTerms = tuple[list[float] | None, list[float] | None, list[float] | None, float, float, int]
#: :meth:`Lookup.scalar_terms`: the (odd, even) speed lists of one temperature [N·m], the highest speed node,
#: ``min_speed_rad_s`` [rad/s], ``max_relative`` [-], ``floor_nm`` [N·m], ``max_independent_nm`` [N·m] and the
#: :data:`PositionTerms` (None: no position terms)
ScalarTerms = tuple[list[float], list[float], int, float, float, float, float, PositionTerms | None]

#: beyond the travel a temperature bin's data covered its trend with the angle falls linearly to 0 over this [rad]
#: (2°): outside it, the model
TREND_TAPER_RAD = 0.035


def held_params(p: Params, has: NDArray[np.bool_]) -> Params:
    """``p`` with every bin without samples next to one with samples holding its neighbour's terms (the mean of both
    neighbours when both have samples): the speed profile per direction (``has`` (2, bins)), the ripple and the trend
    per bin (either direction)."""
    speed = p.speed_nm.copy()
    ripple, trend = p.ripple.copy(), p.trend_nm.copy()
    for d in range(2):
        _hold(speed[d], has[d])
    any_bin = has[0] | has[1]
    _hold(ripple, any_bin)
    _hold(trend, any_bin)
    return Params(speed, p.periods_rad, ripple, trend)


def held_ranges(ranges: Array, has: NDArray[np.bool_]) -> Array:
    """The travel of every bin (bins, 2) [rad] under the hold rule of :func:`held_params`: a bin without samples next
    to one with samples holds its neighbour's travel (both neighbours': the span of the two); NaN where none."""
    out = np.asarray(ranges, dtype=float).copy()
    nt = has.size
    left = np.zeros(nt, dtype=bool)
    right = np.zeros(nt, dtype=bool)
    left[1:], right[:-1] = has[:-1], has[1:]
    src = out.copy()
    for b in np.flatnonzero(~has & (left | right)).tolist():
        near = [src[k] for k in (b - 1, b + 1) if 0 <= k < nt and has[k] and np.all(np.isfinite(src[k]))]
        out[b] = (min(r[0] for r in near), max(r[1] for r in near)) if near else (math.nan, math.nan)
    return out


def trend_taper(grid: Array, ranges: Array) -> Array:
    """Per temperature bin (bins, grid) the share of its trend applied at the positions ``grid`` [rad]: 1 over the
    travel ``ranges`` (bins, 2) [rad] its data covered, falling linearly to 0 over :data:`TREND_TAPER_RAD` beyond it,
    0 everywhere for a bin without a travel (NaN): a change with the angle is not extrapolated where it was not seen.

    >>> trend_taper(np.array([0.0, 0.1, 0.2, 0.7]), np.array([[-0.2, 0.2], [np.nan, np.nan]])).round(3).tolist()
    [[1.0, 1.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]]
    """
    r = np.asarray(ranges, dtype=float)
    lo, hi = r[:, :1], r[:, 1:]
    g = np.asarray(grid, dtype=float)[None, :]
    with np.errstate(invalid='ignore'):
        outside = np.maximum(np.maximum(lo - g, g - hi), 0.0)
        share = np.clip(1.0 - outside / TREND_TAPER_RAD, 0.0, 1.0)
    return np.asarray(np.where(np.isfinite(lo) & np.isfinite(hi), share, 0.0), dtype=float)


def _hold(a: Array, has: NDArray[np.bool_]) -> None:
    """In place along axis 0 (the temperature bins)."""
    nt = has.size
    left = np.zeros(nt, dtype=bool)
    right = np.zeros(nt, dtype=bool)
    left[1:], right[:-1] = has[:-1], has[1:]
    fill = ~has & (left | right)
    if not fill.any():
        return
    wl = np.where(left & right, 0.5, np.where(left, 1.0, 0.0))
    from_left = np.zeros(a.shape)
    from_right = np.zeros(a.shape)
    from_left[1:], from_right[:-1] = a[:-1], a[1:]
    shape = (nt,) + (1,) * (a.ndim - 1)
    w = wl.reshape(shape)
    a[fill] = (w * from_left + (1.0 - w) * from_right)[fill]


class _AtTemperature:
    """What one temperature's lookups read: lists for floats, the same values as arrays for arrays."""

    __slots__ = ('arrays', 'even', 'odd', 'rip', 'teven', 'todd')

    def __init__(self, odd: list[float], even: list[float], rip: list[float] | None, todd: list[float] | None,
                 teven: list[float] | None) -> None:
        self.odd, self.even, self.rip, self.todd, self.teven = odd, even, rip, todd, teven
        self.arrays: tuple[Array, Array, Array | None, Array | None, Array | None] | None = None

    def as_arrays(self) -> tuple[Array, Array, Array | None, Array | None, Array | None]:
        """The lists as float64 arrays (made once)."""
        if self.arrays is None:
            def conv(x: list[float] | None) -> Array | None:
                return None if x is None else np.asarray(x, dtype=float)
            self.arrays = (np.asarray(self.odd, dtype=float), np.asarray(self.even, dtype=float), conv(self.rip),
                           conv(self.todd), conv(self.teven))
        return self.arrays


#: temperatures whose lists a lookup keeps (a batch of runs at a few plateaus; a bag's samples one after another)
CACHED_TEMPERATURES = 256


class Lookup:
    """The terms of one joint prepared for the feedforward (see the module notes).

    Parameters
    ----------
    settings : CorrectionSettings
        Layout and bound.
    params : Params
        The applied terms.
    has : bool array (2, temperature bins)
        Cells with samples (the hold rule).
    angle_range_rad : (float, float) or None
        Positions seen [rad] (None: no position terms).
    """

    def __init__(self, settings: CorrectionSettings, params: Params, has: NDArray[np.bool_],
                 angle_range_rad: tuple[float, float] | None, bin_ranges_rad: Array | None = None) -> None:
        s = settings
        self.settings = s
        p = held_params(params, has)
        self.params = p
        nt, ns = s.n_temperature, s.n_speed
        self.ns, self.hi = ns, nt - 1
        self.t0, self.inv_bin = s.temperature_min_c + 0.5 * s.temperature_bin_c, 1.0 / s.temperature_bin_c
        self.vmin = s.min_speed_rad_s
        self.rel, self.floor, self.independent = s.max_relative, s.floor_nm, s.max_independent_nm
        self.odd = 0.5 * (p.speed_nm[0] + p.speed_nm[1])       # (bins, octaves)
        self.even = 0.5 * (p.speed_nm[0] - p.speed_nm[1])
        has_rip = p.ripple.size > 0 and bool(np.any(p.ripple))
        has_trend = bool(np.any(p.trend_nm))
        self.positions = angle_range_rad is not None and (has_rip or has_trend)
        self.ripple_on, self.trend_on = has_rip, has_trend
        self.grid0 = 0.0
        self.inv_step = 1.0
        self.n_grid = 0
        #: per temperature bin on the position grid: the trend along the motion and independent of it, tapered to 0
        #: outside the travel the bin's data covered [N·m] (bins, grid)
        self._trend_odd = self._trend_even = np.zeros((nt, 0))
        if self.positions and angle_range_rad is not None:
            margin = float(p.periods_rad.max()) if p.periods_rad.size else 0.0
            lo, hi = angle_range_rad[0] - margin, angle_range_rad[1] + margin
            step = 0.5 * s.position_resolution_rad
            # the grid reaches a trend taper beyond the positions seen (whole steps: the grid points inside stay)
            extra = int(math.ceil(max(TREND_TAPER_RAD - margin, 0.0) / step)) if has_trend else 0
            n = max(int(math.ceil((hi - lo) / step)) + 1, 2) + 2 * extra
            g0 = lo - extra * step
            grid = g0 + step * np.arange(n)
            self.grid0, self.inv_step, self.n_grid = g0, 1.0 / step, n
            taper = np.ones(n)
            if margin > 0.0:
                taper = np.clip(np.minimum(grid - lo, hi - grid) / margin, 0.0, 1.0)
            phase = 2.0 * math.pi * grid[:, None] / p.periods_rad[None, :] if p.periods_rad.size else np.zeros((n, 0))
            self._cos, self._sin = np.cos(phase) * taper[:, None], np.sin(phase) * taper[:, None]
            trig = np.stack([np.sin(grid), np.cos(grid) - 1.0], axis=1)   # (grid, 2)
            if has_trend:
                ranges = np.tile(np.asarray(angle_range_rad, dtype=float), (nt, 1)) if bin_ranges_rad is None \
                    else np.asarray(bin_ranges_rad, dtype=float).reshape(nt, 2).copy()
                # only a bin with an applied term has a travel (what a correction file keeps: a round trip is exact)
                terms = (np.any(params.speed_nm != 0.0, axis=(0, 2)) | np.any(params.trend_nm != 0.0, axis=1)
                         | np.any(params.ripple.reshape(nt, -1) != 0.0, axis=1))
                ranges[~terms] = np.nan
                fade = trend_taper(np.asarray(grid, dtype=np.float64), held_ranges(ranges, has[0] | has[1]))
                self._trend_odd = fade * (p.trend_nm[:, :2] @ trig.T)
                self._trend_even = fade * (p.trend_nm[:, 2:] @ trig.T)
        self.saturations = 0
        self._at_t: float = math.nan
        self._at: _AtTemperature | None = None
        self._cache: dict[float, _AtTemperature] = {}

    # ------------------------------------------------------------------ temperature
    def _bins(self, t: float) -> tuple[int, float]:
        x = (t - self.t0) * self.inv_bin
        if 0.0 < x < self.hi:
            i = int(x)
            return i, x - i
        if x > 0.0:
            return self.hi - 1, 1.0
        return 0, 0.0   # (NaN too)

    def at_temperature(self, t: float) -> _AtTemperature:
        """The lists of temperature ``t`` [°C] (kept for the next calls at the same temperature)."""
        if t == self._at_t and self._at is not None:
            return self._at
        cached = self._cache.get(t)
        if cached is not None:
            self._at_t, self._at = t, cached
            return cached
        i, w = self._bins(t)
        p = self.params
        odd = ((1.0 - w) * self.odd[i] + w * self.odd[i + 1]).tolist()
        even = ((1.0 - w) * self.even[i] + w * self.even[i + 1]).tolist()
        rip = todd = teven = None
        if self.positions:
            if self.ripple_on:
                c = (1.0 - w) * p.ripple[i] + w * p.ripple[i + 1]          # (K, 2)
                rip = (self._cos @ c[:, 0] + self._sin @ c[:, 1]).tolist()
            if self.trend_on:
                todd = ((1.0 - w) * self._trend_odd[i] + w * self._trend_odd[i + 1]).tolist()
                teven = ((1.0 - w) * self._trend_even[i] + w * self._trend_even[i + 1]).tolist()
        at = _AtTemperature(odd, even, rip, todd, teven)
        self._at_t, self._at = t, at
        if t == t:   # (not NaN)
            if len(self._cache) >= CACHED_TEMPERATURES:
                self._cache.clear()
            self._cache[t] = at
        return at

    def scalar_terms(self, t: float) -> ScalarTerms:
        """What :meth:`split_nm` reads at temperature ``t`` [°C], flat (:data:`ScalarTerms`: the lists of
        :meth:`at_temperature` and this lookup's constants), for a caller that inlines :meth:`split_nm`'s operations
        on its per-call path (the feedforward's scalar call: one tuple per temperature instead of about twenty
        attribute reads per call)."""
        at = self.at_temperature(t)
        position_terms = ((at.rip, at.todd, at.teven, self.grid0, self.inv_step, self.n_grid - 1) if self.positions
                          else None)
        return at.odd, at.even, self.ns - 1, self.vmin, self.rel, self.floor, self.independent, position_terms

    # ------------------------------------------------------------------ floats
    def split_nm(self, temperature_c: float, velocity_rad_s: float, position_rad: float, model_nm: float
                 ) -> tuple[float, float]:
        """(odd, even) parts [N·m] at ``temperature_c`` [°C], ``velocity_rad_s`` [rad/s], ``position_rad`` [rad]
        (NaN: no position terms) for the model friction ``model_nm`` [N·m]; each bounded. A model friction that is
        not finite (an absurd speed) gets no correction: (0.0, 0.0)."""
        if model_nm - model_nm != 0.0:   # (inf or NaN: inf - inf and NaN - NaN are NaN, and NaN != 0)
            return 0.0, 0.0
        at = self.at_temperature(temperature_c)
        odd_l, even_l = at.odd, at.even
        a = velocity_rad_s if velocity_rad_s >= 0.0 else -velocity_rad_s
        if self.ns > 1:
            x = math.log2(a / self.vmin) - 0.5 if a > self.vmin else -1.0
            hi = self.ns - 1
            if x <= 0.0:
                odd, even = odd_l[0], even_l[0]
            elif x >= hi:
                odd, even = odd_l[hi], even_l[hi]
            else:
                k = int(x)
                f = x - k
                o0, e0 = odd_l[k], even_l[k]
                odd = o0 + f * (odd_l[k + 1] - o0)
                even = e0 + f * (even_l[k + 1] - e0)
        else:
            odd, even = odd_l[0], even_l[0]
        m = model_nm if model_nm >= 0.0 else -model_nm
        if self.positions and position_rad == position_rad:
            y = (position_rad - self.grid0) * self.inv_step
            last = self.n_grid - 1
            if y <= 0.0:
                j, h = 0, 0.0
            elif y >= last:
                j, h = last - 1, 1.0
            else:
                j = int(y)
                h = y - j
            rip = at.rip
            if rip is not None:
                r0 = rip[j]
                odd += (r0 + h * (rip[j + 1] - r0)) * m
            todd = at.todd
            if todd is not None:
                a0 = todd[j]
                odd += a0 + h * (todd[j + 1] - a0)
                teven = at.teven
                b0 = teven[j]   # type: ignore[index]  # (set with todd)
                even += b0 + h * (teven[j + 1] - b0)   # type: ignore[index]
        if a < self.vmin:   # below the slowest speed learned the part along the motion fades out: the model alone
            odd *= a / self.vmin
        bound = self.rel * m + self.floor
        if not (-bound <= odd <= bound):
            self.saturations += 1
            odd = bound if odd > 0.0 else -bound
        bound = max(bound, self.independent)
        if not (-bound <= even <= bound):
            self.saturations += 1
            even = bound if even > 0.0 else -bound
        return odd, even

    # ------------------------------------------------------------------ arrays
    def terms_array(self, temperature_c: Any, velocity_rad_s: Any, position_rad: Any, model_nm: Any
                    ) -> dict[str, Array]:
        """Every term on arrays, unbounded [N·m], each element with its own temperature, with the operations of
        :meth:`split_nm` (the same numbers to the last bit or two): ``odd_speed``, ``even_speed`` (the speed
        profiles' parts), ``ripple`` (m ρ), ``trend_odd``, ``trend_even``."""
        with np.errstate(over='ignore', invalid='ignore', divide='ignore'):   # (absurd inputs: as on floats)
            return self._terms_array(*(a.ravel() for a in np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (
                temperature_c, velocity_rad_s, position_rad, model_nm)))))

    def _terms_array(self, t: Array, v: Array, pos: Array, m: Array) -> dict[str, Array]:
        n = t.size
        zero = np.zeros(n)
        # temperature: bin and weight as _bins
        x = (t - self.t0) * self.inv_bin
        inside = (x > 0.0) & (x < self.hi)
        i = np.where(inside, np.trunc(np.where(inside, x, 0.0)), np.where(x > 0.0, self.hi - 1, 0)).astype(np.int64)
        w = np.where(inside, x - i, np.where(x > 0.0, 1.0, 0.0))
        w0 = 1.0 - w
        # speed: the octave coordinate and its node as split_nm
        hi = self.ns - 1
        if self.ns > 1:
            a = np.abs(v)
            with np.errstate(divide='ignore', invalid='ignore'):
                xs = np.where(a > self.vmin, np.log2(np.where(a > self.vmin, a, 1.0) / self.vmin) - 0.5, -1.0)
            low, high = ~(xs > 0.0), xs >= hi
            inner = ~low & ~high
            k = np.where(inner, np.trunc(np.where(inner, xs, 0.0)), np.where(high, hi, 0)).astype(np.int64)
            f = np.where(inner, xs - k, 0.0)
            k1 = np.minimum(k + 1, hi)
        else:
            inner = np.zeros(n, dtype=bool)
            k = k1 = np.zeros(n, dtype=np.int64)
            f = zero
        out: dict[str, Array] = {}
        for name, table in (('odd_speed', self.odd), ('even_speed', self.even)):
            o0 = w0 * table[i, k] + w * table[i + 1, k]
            o1 = w0 * table[i, k1] + w * table[i + 1, k1]
            out[name] = np.where(inner, o0 + f * (o1 - o0), o0)
        out['ripple'], out['trend_odd'], out['trend_even'] = zero, zero.copy(), zero.copy()
        if not self.positions:
            return out
        known = ~np.isnan(pos)
        last = self.n_grid - 1
        y = (np.where(known, pos, self.grid0) - self.grid0) * self.inv_step
        below, above = ~(y > 0.0), y >= last
        mid = ~below & ~above
        j = np.where(mid, np.trunc(np.where(mid, y, 0.0)), np.where(above, last - 1, 0)).astype(np.int64)
        h = np.where(mid, y - j, np.where(above, 1.0, 0.0))
        p = self.params
        if self.ripple_on:
            c = w0[:, None, None] * p.ripple[i] + w[:, None, None] * p.ripple[i + 1]       # (n, K, 2)
            tab0 = (self._cos[j] * c[..., 0]).sum(axis=1) + (self._sin[j] * c[..., 1]).sum(axis=1)
            tab1 = (self._cos[j + 1] * c[..., 0]).sum(axis=1) + (self._sin[j + 1] * c[..., 1]).sum(axis=1)
            out['ripple'] = np.where(known, (tab0 + h * (tab1 - tab0)) * np.abs(m), 0.0)
        if self.trend_on:   # (as at_temperature's lists, element by element)
            to, te = self._trend_odd, self._trend_even
            a0 = w0 * to[i, j] + w * to[i + 1, j]
            a1 = w0 * to[i, j + 1] + w * to[i + 1, j + 1]
            b0 = w0 * te[i, j] + w * te[i + 1, j]
            b1 = w0 * te[i, j + 1] + w * te[i + 1, j + 1]
            out['trend_odd'] = np.where(known, a0 + h * (a1 - a0), 0.0)
            out['trend_even'] = np.where(known, b0 + h * (b1 - b0), 0.0)
        return out

    def split_array(self, temperature_c: Any, velocity_rad_s: Any, position_rad: Any, model_nm: Any
                    ) -> tuple[Array, Array]:
        """:meth:`split_nm` on arrays (a whole bag, the loop study): (odd, even) [N·m], each bounded; clipped
        lookups counted the same way."""
        t, v, pos, m = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (
            temperature_c, velocity_rad_s, position_rad, model_nm)))
        shape = t.shape
        terms = self.terms_array(t, v, pos, m)
        odd = terms['odd_speed']
        even = terms['even_speed']
        if self.positions:   # in split_nm's order: ripple, then the trend
            odd = odd + terms['ripple']
            odd = odd + terms['trend_odd']
            even = even + terms['trend_even']
        a = np.abs(v.ravel())
        with np.errstate(over='ignore', invalid='ignore'):
            odd = np.where(a < self.vmin, odd * (a / self.vmin), odd)
        bound = self.rel * np.abs(m.ravel()) + self.floor
        bound_e = np.maximum(bound, self.independent)
        clipped_o = ~((-bound <= odd) & (odd <= bound))
        clipped_e = ~((-bound_e <= even) & (even <= bound_e))
        self.saturations += int(np.count_nonzero(clipped_o) + np.count_nonzero(clipped_e))
        odd = np.where(clipped_o, np.where(odd > 0.0, bound, -bound), odd)
        even = np.where(clipped_e, np.where(even > 0.0, bound_e, -bound_e), even)
        finite = np.isfinite(m.ravel())          # an absurd speed's infinite model: no correction, as on floats
        if not finite.all():
            self.saturations -= int(np.count_nonzero(clipped_o & ~finite) + np.count_nonzero(clipped_e & ~finite))
            odd, even = np.where(finite, odd, 0.0), np.where(finite, even, 0.0)
        return odd.reshape(shape), even.reshape(shape)
