r"""A learned correction to the physics friction torque, learned from residuals and guarded by out-of-sample scores
(pure numpy; no rclpy, no I/O).

One job in one module: :class:`Correction` (its rows, its fit, its guard and what the feedforward reads share one
state per joint).

The physics model gives the friction magnitude ``k_d(T) M(T, |v|)`` [N·m]; a real gimbal adds what the model leaves
out (a lubricant off its datasheet, a CW/CCW asymmetry, a Stribeck rise at low speed, a position ripple at periods
nobody gave, an unbalance torque, a temperature sensor offset). The correction learns that residue from the
estimator's accepted samples (residual = measured − model friction, along the motion):

- **rows** (:mod:`~gimbal_friction.feedforward.correction.stats`): every accepted sample is kept in sums per
  direction × temperature bin × speed octave × position bin; nothing is fitted into a sample, so any term can be
  fitted again from them;
- **fit** (:mod:`~gimbal_friction.feedforward.correction.fit`): per temperature bin a speed profile per direction, a
  ripple at the periods found in the residuals, a trend with the angle along the motion and a torque independent of
  the direction (an unbalance); shrunk towards 0 where data is thin and bounded by ``max_relative`` × |model| +
  ``floor_nm``. This is the **candidate**;
- **guard** (test, then train): every sample is scored by the candidate *before* it is learned (:meth:`score`; once
  the sample's cell has learned from twice ``prior_samples`` and ``guard_block_samples`` samples of its own): the
  squared residual of the model alone, with the candidate, and with the candidate less each of its terms (the speed
  profile, its shape, the ripple, the trend). A cell is applied only once ``guard_min_samples`` samples scored it and
  it cuts the squared residual by ``guard_z`` standard errors; a term only where dropping it would cost ⅔ of that;
  and a cell only where both directions of its temperature bin were measured at a common speed and the other
  direction's cell was judged too (:func:`identifiable_bins`: the torque independent of the direction is told from
  friction by the two directions alone; a cell applied while the other waits for its scores would turn half of an
  unbalance into a change of the friction).
  Elsewhere the cell or term holds back to the model, and :meth:`verdicts` says which, why and with what figures.
  The result is the **target**;
- **applied** (what :meth:`split_nm` reads, :mod:`~gimbal_friction.feedforward.correction.lookup`): the target at
  once (:meth:`settle`, batch) or moved towards it at a limited rate
  (:class:`~gimbal_friction.feedforward.correction.learner.Learner`, in service).

The feedforward adds the applied correction as a part along the motion and a part independent of it:
``τ = clamp(tanh(v/v_th) (k_d M + c_odd) + c_even, ±τ_max)`` (see the lookup module); an empty correction is
exactly the model.

>>> from gimbal_friction.feedforward.correction.settings import model_identity
>>> c = Correction(CorrectionSettings(guard_min_samples=0, guard_z=0.0), model_identity({'elevation': {}}))
>>> c.split_nm('elevation', -40.0, 0.03, 0.0, 3.1e-3)       # empty: exactly the model
(0.0, 0.0)
>>> n = 400
>>> for v in (0.03, -0.03):                                   # 0.2 N*mm more friction than the model, both ways
...     _ = c.learn_residuals('elevation', [-40.0] * n, [v] * n, [0.0] * n, [2e-4 * np.sign(v)] * n, [3.1e-3] * n)
>>> c.settle(); round(c.along_nm('elevation', -40.0, 0.03, 0.0, 3.1e-3) * 1e3, 4)   # N*mm: 0.2 * 800 / (800 + 50)
0.1882
>>> abs(c.split_nm('elevation', -40.0, -0.03, 0.0, 3.1e-3)[1]) < 1e-15   # nothing independent of the direction
True
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.xp import ARRAY, SCALAR
from gimbal_friction.feedforward.correction.fit import Fit, Params, empty_params, fit_joint, rising_envelope
from gimbal_friction.feedforward.correction.lookup import Lookup
from gimbal_friction.feedforward.correction.periods import Period
from gimbal_friction.feedforward.correction.settings import (
    DIRECTIONS,
    CorrectionError,
    CorrectionSettings,
    ModelIdentity,
)
from gimbal_friction.feedforward.correction.stats import REASONS, JointStats, gate_code, row_key

__all__ = ['GUARD_TERMS', 'Correction', 'Verdict', 'applied_bound_nm', 'identifiable_bins']

Array = NDArray[np.float64]
#: what the guard compares the candidate with: the model alone (``correction``), the candidate without its speed
#: profile (``speed``), with a flat profile (``shape``), without its ripple (``ripple``), without its trend
#: (``trend``)
GUARD_TERMS = ('correction', 'speed', 'shape', 'ripple', 'trend')
#: columns of a cell's guard scores: samples scored, Σ squared residual of the model, of the candidate, then per
#: term of :data:`GUARD_TERMS` ΣD and ΣD² over closed blocks of D = Σ over a block of ``guard_block_samples``
#: consecutive samples of d = (squared residual without the term) − (with the candidate); then the blocks closed,
#: the samples of the open block and, per term, its running Σd
GUARD_COLUMNS = ('n', 'e_model', 'e_full', *(f'{k}_{t}' for t in GUARD_TERMS for k in ('d', 'dd')), 'blocks',
                 'open_n', *(f'open_{t}' for t in GUARD_TERMS))
#: index of the first column the guard's forgetting leaves alone (the open block)
_OPEN = GUARD_COLUMNS.index('open_n')
_BLOCKS = GUARD_COLUMNS.index('blocks')
#: a search for ripple periods is repeated when a joint's samples have grown by this factor since the last one [-]
SEARCH_GROWTH = 1.25
#: ... and needs at least this many samples with a position [-]
SEARCH_MIN_SAMPLES = 500


def applied_bound_nm(stats: JointStats) -> Array:
    """The bound of an applied speed node per temperature bin [N·m]: B + max(B, ``max_independent_nm``) with B =
    ``max_relative`` × the largest mean |model| of the bin's rows + ``floor_nm`` (its part along the motion within B,
    its part independent of the direction within the larger; 0 where the bin has no rows: nothing may be applied
    there); a trend coefficient's is 10 × this. What learning keeps to and what a file is checked against."""
    s = stats.settings
    keys, sums = stats.rows()
    out = np.zeros(s.n_temperature)
    if keys.size:
        _, b, *_ = stats.decode(keys)
        np.maximum.at(out, b, sums[:, 2] / sums[:, 0])
        have = np.bincount(b, minlength=s.n_temperature) > 0
        base = s.max_relative * out + s.floor_nm
        out = np.where(have, base + np.maximum(base, s.max_independent_nm), 0.0)
    return out


class Verdict(NamedTuple):
    """The guard's verdict on one cell (direction × temperature bin)."""

    applied: bool            #: the cell's correction is applied (else: held back to the model)
    reason: str              #: why not (empty when applied)
    scored: float            #: samples that scored it out of sample (forgetting) [-]
    rms_model_nm: float      #: RMS residual of the model on them [N·m]
    rms_with_nm: float       #: RMS residual with the candidate on them [N·m]
    z: dict[str, float]      #: per term of :data:`GUARD_TERMS`: its gain in standard errors [-]
    kept: tuple[str, ...]    #: the terms applied (of speed, shape, ripple, trend)


class _Joint:
    """The state of one joint."""

    __slots__ = ('angle_range', 'applied', 'bin_ranges', 'candidate', 'guard', 'searched_at', 'stats', 'target')

    def __init__(self, s: CorrectionSettings) -> None:
        self.stats = JointStats(s)
        self.guard = np.zeros((2, s.n_temperature, len(GUARD_COLUMNS)))
        self.applied = empty_params(s)
        self.candidate: Fit | None = None
        self.target = empty_params(s)
        self.searched_at = 0.0
        #: positions the applied terms were fitted over [rad] (None: none; the lookup's position grid)
        self.angle_range: tuple[float, float] | None = None
        #: per temperature bin, the positions its data covered [rad] (bins, 2; NaN: none); None: ``angle_range`` for
        #: every bin (a file written before the travel was kept per bin)
        self.bin_ranges: Array | None = None


class Correction:
    """A learned correction of the joints of ``identity`` (the model the residuals are taken against) laid out by
    ``settings`` (see the module notes). ConfigError: invalid settings, no joint."""

    def __init__(self, settings: CorrectionSettings, identity: ModelIdentity) -> None:
        settings.validate()
        if not identity.joints:
            raise ConfigError('joints', 'a correction needs at least one joint')
        self.settings, self.identity = settings, identity
        self._joints = {j: _Joint(settings) for j in identity.joints}
        #: per joint, what the feedforward reads (None: nothing applied, exactly the model)
        self.lookups: dict[str, Lookup | None] = dict.fromkeys(identity.joints)
        self._saturations_before = 0
        #: per joint, the ripple periods of the candidate and their evidence
        self.periods: dict[str, tuple[Period, ...]] = dict.fromkeys(identity.joints, ())

    # ------------------------------------------------------------------ state
    def joint(self, joint: str) -> _Joint:
        """The state of ``joint`` (CorrectionError for an unknown one)."""
        try:
            return self._joints[joint]
        except KeyError:
            raise CorrectionError(f'joint {joint!r} is not in this correction '
                                  f'({", ".join(self.identity.joints)})') from None

    def stats(self, joint: str) -> JointStats:
        """The rows of ``joint``."""
        return self.joint(joint).stats

    def applied(self, joint: str) -> Params:
        """The applied terms of ``joint`` (what the lookups read, before the hold rule)."""
        return self.joint(joint).applied

    def set_applied(self, joint: str, params: Params, angle_range_rad: tuple[float, float] | None = None,
                    bin_ranges_rad: Array | None = None) -> None:
        """Apply ``params`` to ``joint``, fitted over the positions ``angle_range_rad`` [rad] (None: those of the
        last fit), each temperature bin over ``bin_ranges_rad`` (bins, 2) [rad] (None: ``angle_range_rad`` for
        every bin, or the last fit's); the lookups follow at once."""
        st = self.joint(joint)
        st.applied = params
        if angle_range_rad is not None:
            st.angle_range = angle_range_rad
            st.bin_ranges = None if bin_ranges_rad is None else np.asarray(bin_ranges_rad, dtype=float).copy()
        elif st.candidate is not None:
            st.angle_range = st.candidate.angle_range_rad
            st.bin_ranges = st.candidate.bin_ranges_rad.copy()
        self.rebuild(joint)

    def guard_scores(self, joint: str) -> Array:
        """The guard's sums of ``joint`` (2, temperature bins, :data:`GUARD_COLUMNS`)."""
        return self.joint(joint).guard

    @property
    def lookup_saturations(self) -> int:
        """Lookups whose value the bound clipped [-]."""
        return self._saturations_before + sum(lut.saturations for lut in self.lookups.values() if lut is not None)

    def has_data(self, joint: str) -> NDArray[np.bool_]:
        """Cells (2, temperature bins) with samples."""
        return self.stats(joint).cell_counts().reshape(2, self.settings.n_temperature) > 0

    def lookup_has(self, joint: str) -> NDArray[np.bool_]:
        """Cells (2, temperature bins) the lookup's hold rule counts as learned: with samples, and scored by at least
        ``guard_min_samples`` of them (a cell still waiting for its scores is no learned zero: its neighbour's value
        holds over it, so a temperature between the two does not read a fraction of the neighbour's, nor a
        temperature sensor's noise a steep slope)."""
        scored = self.joint(joint).guard[..., 0] >= self.settings.guard_min_samples
        return self.has_data(joint) & scored

    def rebuild(self, joint: str | None = None) -> None:
        """Rebuild the lookups of ``joint`` (all: None) from the applied terms."""
        for j in (self.identity.joints if joint is None else (joint,)):
            st = self.joint(j)
            old = self.lookups[j]
            if old is not None:
                self._saturations_before += old.saturations
            p = st.applied
            if not (np.any(p.speed_nm) or np.any(p.ripple) or np.any(p.trend_nm)):
                self.lookups[j] = None
                continue
            self.lookups[j] = Lookup(self.settings, p, self.lookup_has(j), st.angle_range, st.bin_ranges)

    # ------------------------------------------------------------------ lookup (the feedforward's hot path)
    def split_nm(self, joint: str, temperature_c: float, velocity_rad_s: float, position_rad: float,
                 model_nm: float) -> tuple[float, float]:
        """The applied correction's (odd, even) parts [N·m] for motion at ``velocity_rad_s`` [rad/s] at
        ``temperature_c`` [°C] and position ``position_rad`` [rad] (NaN: no position terms), for the model friction
        ``model_nm`` [N·m]: ``τ = tanh(v/v_th) (model + odd) + even``. (0.0, 0.0) where nothing is learned."""
        lut = self.lookups[joint]
        if lut is None:
            return 0.0, 0.0
        return lut.split_nm(temperature_c, velocity_rad_s, position_rad, model_nm)

    def along_nm(self, joint: str, temperature_c: float, velocity_rad_s: float, position_rad: float,
                 model_nm: float) -> float:
        """The applied correction along the motion [N·m] away from zero speed: odd + sign(v) even (what the
        feedforward adds to the model friction in the direction of ``velocity_rad_s``)."""
        odd, even = self.split_nm(joint, temperature_c, velocity_rad_s, position_rad, model_nm)
        return odd + even if velocity_rad_s >= 0.0 else odd - even

    def split_nm_array(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                       position_rad: ArrayLike, model_nm: ArrayLike) -> tuple[Array, Array]:
        """:meth:`split_nm` on arrays (the same numbers)."""
        lut = self.lookups[joint]
        shape = np.broadcast_shapes(*(np.shape(a) for a in (temperature_c, velocity_rad_s, position_rad, model_nm)))
        if lut is None:
            return np.zeros(shape), np.zeros(shape)
        return lut.split_array(temperature_c, velocity_rad_s, position_rad, model_nm)

    def along_nm_array(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                       position_rad: ArrayLike, model_nm: ArrayLike) -> Array:
        """:meth:`along_nm` on arrays."""
        odd, even = self.split_nm_array(joint, temperature_c, velocity_rad_s, position_rad, model_nm)
        v = np.broadcast_to(np.asarray(velocity_rad_s, dtype=float), odd.shape)
        return np.asarray(np.where(v >= 0.0, odd + even, odd - even), dtype=float)

    # ------------------------------------------------------------------ learning
    def gate(self, temperature_c: ArrayLike, velocity_rad_s: ArrayLike, residual_nm: ArrayLike, model_nm: ArrayLike,
             temperature_fresh: ArrayLike = True) -> NDArray[np.int64]:
        """Gate codes of residual samples (0 accepted, else the index of the reason in ``REASONS``)."""
        t, v, r, m, f = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (
            temperature_c, velocity_rad_s, residual_nm, model_nm)), np.asarray(temperature_fresh))
        with np.errstate(invalid='ignore', over='ignore'):
            return np.asarray(gate_code(self.settings, t, v, r, m, f.astype(bool), ARRAY), dtype=np.int64).ravel()

    @staticmethod
    def _arrays(*cols: ArrayLike) -> list[Array]:
        try:
            return [a.ravel() for a in np.broadcast_arrays(*(np.asarray(c, dtype=float) for c in cols))]
        except ValueError:
            raise CorrectionError('temperature, velocity, position, residual and model arrays must have one length'
                                  ) from None

    def add_residuals(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike, position_rad: ArrayLike,
                      residual_nm: ArrayLike, model_nm: ArrayLike, temperature_fresh: ArrayLike = True
                      ) -> dict[str, int]:
        """Keep residual samples of ``joint`` in its rows without scoring them (see :meth:`learn_residuals`).

        ``residual_nm`` = measured friction − model friction, both signed like the motion [N·m]; ``model_nm`` the
        model friction [N·m]; temperature [°C], velocity [rad/s], position [rad]. Returns the refused samples per
        reason. Raises CorrectionError for an unknown joint or arrays of different lengths.
        """
        return self._gated(joint, False, temperature_c, velocity_rad_s, position_rad, residual_nm, model_nm,
                           temperature_fresh)

    def _gated(self, joint: str, scored: bool, *cols: ArrayLike) -> dict[str, int]:
        """Gate the samples ``cols`` (as :meth:`add_residuals`), score the accepted ones with ``scored``, keep them;
        the refused ones per reason."""
        st = self.joint(joint)
        t, v, p, r, m, fresh = self._arrays(*cols)
        code = self.gate(t, v, r, m, fresh)
        ok = code == 0
        if scored:
            self.score(joint, t[ok], v[ok], p[ok], r[ok], m[ok])
        self._keep(st, t[ok], v[ok], p[ok], r[ok], m[ok])
        return {REASONS[k]: int(n) for k, n in enumerate(np.bincount(code, minlength=len(REASONS))) if k and n}

    def _keep(self, st: _Joint, t: Array, v: Array, p: Array, r: Array, m: Array) -> None:
        """Add accepted samples to the rows."""
        if t.size == 0:
            return
        with np.errstate(invalid='ignore'):
            keys, cells, u = row_key(self.settings, t, v, p, ARRAY)
        along = np.where(v > 0.0, r, -r)
        st.stats.add(np.asarray(keys, dtype=np.int64), np.asarray(cells, dtype=np.int64), np.asarray(u), along,
                     np.abs(m))

    def learn_residuals(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                        position_rad: ArrayLike, residual_nm: ArrayLike, model_nm: ArrayLike,
                        temperature_fresh: ArrayLike = True) -> dict[str, int]:
        """Test, then train: score the accepted samples by the current candidate (:meth:`score`), then keep them
        (:meth:`add_residuals`); the candidate is not refitted (:meth:`refit`). Units as :meth:`add_residuals`."""
        return self._gated(joint, True, temperature_c, velocity_rad_s, position_rad, residual_nm, model_nm,
                           temperature_fresh)

    def score(self, joint: str, t: Array, v: Array, p: Array, r: Array, m: Array) -> None:
        """Score accepted samples (arrays, units as :meth:`add_residuals`) by the candidate before they are learned:
        the guard's sums of every cell (see the module notes), forgetting with ``guard_memory_samples``."""
        st = self.joint(joint)
        s = self.settings
        if t.size == 0:
            return
        nt = s.n_temperature
        d = np.where(v > 0.0, 0, 1)
        b = np.minimum(np.maximum(((t - s.temperature_min_c) / s.temperature_bin_c).astype(np.int64), 0), nt - 1)
        # a candidate scores a sample once its cell learned from enough samples of its own (an early candidate
        # fitted to a handful would otherwise weigh on the scores for as long as they remember)
        fit = st.candidate
        if fit is None:
            return
        mature = fit.samples[d, b] >= max(2.0 * s.guard_block_samples, 2.0 * s.prior_samples)
        if not mature.all():
            t, v, p, r, m, d, b = (a[mature] for a in (t, v, p, r, m, d, b))
            if t.size == 0:
                return
        sign = np.where(v > 0.0, 1.0, -1.0)
        along = sign * r
        e_model = along * along
        cand = self._candidate_lookups(st)
        cols = np.zeros((t.size, len(GUARD_COLUMNS)))
        cols[:, 0] = 1.0
        cols[:, 1] = e_model
        if cand is None:
            cols[:, 2] = e_model
        else:
            full_l, flat_l = cand
            tm = full_l.terms_array(t, v, p, m)
            fl = flat_l.terms_array(t, v, p, m)
            bound = s.max_relative * np.abs(m) + s.floor_nm
            bound_e = np.maximum(bound, s.max_independent_nm)

            def pred(odd: Array, even: Array) -> Array:
                return np.clip(odd, -bound, bound) + sign * np.clip(even, -bound_e, bound_e)

            os_, es_, rp, to, te = tm['odd_speed'], tm['even_speed'], tm['ripple'], tm['trend_odd'], tm['trend_even']
            full = pred(os_ + rp + to, es_ + te)
            e_full = (along - full) ** 2
            cols[:, 2] = e_full
            without = {'correction': np.zeros(t.size), 'speed': pred(rp + to, te),
                       'shape': pred(fl['odd_speed'] + rp + to, fl['even_speed'] + te),
                       'ripple': pred(os_ + to, es_ + te), 'trend': pred(os_ + rp, es_)}
            for i, term in enumerate(GUARD_TERMS):
                dd = (along - without[term]) ** 2 - e_full
                cols[:, 3 + 2 * i] = dd
                cols[:, 4 + 2 * i] = dd * dd
        cell = d * nt + b
        n_terms = len(GUARD_TERMS)
        counts = np.bincount(cell, minlength=2 * nt)
        g = st.guard.reshape(2 * nt, -1)
        # batch means: consecutive samples are not independent (a kHz stream sees the same ripple and temperature
        # for a while), so the per-term differences are summed over blocks of guard_block_samples samples and the
        # blocks' sums are what the standard errors are taken from
        blk_len = max(1, s.guard_block_samples)
        order = np.argsort(cell, kind='stable')
        starts = np.cumsum(counts) - counts
        rank = np.empty(cell.size, dtype=np.int64)
        rank[order] = np.arange(cell.size) - starts[cell[order]]
        over = g[:, _OPEN] >= blk_len                                  # (guard_block_samples was lowered)
        if over.any():
            g[over, 3:3 + 2 * n_terms:2] += g[over, _OPEN + 1:]
            g[over, 4:4 + 2 * n_terms:2] += g[over, _OPEN + 1:] ** 2
            g[over, _BLOCKS] += 1.0
            g[over, _OPEN:] = 0.0
        open_n = np.round(g[:, _OPEN]).astype(np.int64)
        blk = (open_n[cell] + rank) // blk_len
        nb = int(blk.max()) + 1
        key = cell * nb + blk
        total = open_n + counts
        closed = total // blk_len                                     # blocks of this call that close
        shut = np.arange(nb)[None, :] < closed[:, None]
        new_open = np.zeros((2 * nt, n_terms))
        d_add = np.zeros((2 * nt, n_terms))
        dd_add = np.zeros((2 * nt, n_terms))
        rows = np.arange(2 * nt)
        for i in range(n_terms):
            bs = np.asarray(np.bincount(key, weights=cols[:, 3 + 2 * i], minlength=2 * nt * nb),
                            dtype=np.float64).reshape(2 * nt, nb)
            bs[:, 0] += g[:, _OPEN + 1 + i]
            d_add[:, i] = np.where(shut, bs, 0.0).sum(axis=1)
            dd_add[:, i] = np.where(shut, bs * bs, 0.0).sum(axis=1)
            new_open[:, i] = np.where(closed < nb, bs[rows, np.minimum(closed, nb - 1)], 0.0)
        decay = (1.0 - 1.0 / s.guard_memory_samples) ** counts
        g[:, :_OPEN] *= decay[:, None]
        g[:, 0] += counts
        g[:, 1] += np.bincount(cell, weights=cols[:, 1], minlength=2 * nt)
        g[:, 2] += np.bincount(cell, weights=cols[:, 2], minlength=2 * nt)
        g[:, 3:3 + 2 * n_terms:2] += d_add
        g[:, 4:4 + 2 * n_terms:2] += dd_add
        g[:, _BLOCKS] += closed
        g[:, _OPEN] = total - closed * blk_len
        g[:, _OPEN + 1:] = new_open

    def _candidate_lookups(self, st: _Joint) -> tuple[Lookup, Lookup] | None:
        """Lookups of the candidate and of the candidate with flat speed profiles (None: no candidate)."""
        fit = st.candidate
        if fit is None:
            return None
        has = fit.samples > 0
        p = fit.params
        flat = Params(np.repeat(fit.flat_nm[..., None], p.speed_nm.shape[2], axis=2), p.periods_rad, p.ripple,
                      p.trend_nm)
        return (Lookup(self.settings, p, has, fit.angle_range_rad, fit.bin_ranges_rad),
                Lookup(self.settings, flat, has, fit.angle_range_rad, fit.bin_ranges_rad))

    def refit(self, joint: str, search: bool | None = None) -> Fit:
        """Fit the candidate of ``joint`` from its rows; ripple periods searched again with ``search`` (None: when
        its samples grew by :data:`SEARCH_GROWTH` since the last search, and at the first with enough samples)."""
        st = self.joint(joint)
        n = st.stats.samples()
        if search is None:
            search = n >= SEARCH_MIN_SAMPLES and (st.searched_at == 0.0 or n >= SEARCH_GROWTH * st.searched_at)
        if search:
            fit = fit_joint(st.stats)
            st.searched_at = float(max(n, 1))
            self.periods[joint] = fit.periods
        else:
            fit = fit_joint(st.stats, self.periods[joint])
        st.candidate = fit
        st.target = self._targets(joint, fit)
        if fit.angle_range_rad is not None:
            st.angle_range = fit.angle_range_rad
            st.bin_ranges = fit.bin_ranges_rad.copy()
        return fit

    # ------------------------------------------------------------------ the guard
    def verdicts(self, joint: str) -> list[list[Verdict]]:
        """The guard's verdict on every cell of ``joint``: ``[direction][temperature bin]``; a bin's two cells are
        applied only once both were judged, where both directions were measured at a common speed (the pairing rule:
        :func:`identifiable_bins`)."""
        s = self.settings
        g = self.joint(joint).guard
        out = []
        for d in range(2):
            row = []
            for b in range(s.n_temperature):
                c = g[d, b]
                n = float(c[0])
                z = {}
                for i, term in enumerate(GUARD_TERMS):
                    sd, sdd = float(c[3 + 2 * i]), float(c[4 + 2 * i])
                    z[term] = sd / math.sqrt(sdd) if sdd > 0.0 else 0.0
                rms_m = math.sqrt(c[1] / n) if n > 0 else math.nan
                rms_w = math.sqrt(c[2] / n) if n > 0 else math.nan
                if n < s.guard_min_samples or (s.guard_z > 0.0 and c[_BLOCKS] < 2.0):
                    reason = f'scored by {n:.0f} of {s.guard_min_samples} samples'
                elif not z['correction'] >= s.guard_z:
                    reason = (f'cuts the squared residual by {z["correction"]:.1f} standard errors, needs '
                              f'{s.guard_z:g}')
                else:
                    reason = ''
                kept = tuple(t for t in GUARD_TERMS[1:] if z[t] >= 2.0 * s.guard_z / 3.0) if not reason else ()
                row.append(Verdict(not reason, reason, n, rms_m, rms_w, z, kept))
            out.append(row)
        waiting = (g[..., 0] < s.guard_min_samples) | ((s.guard_z > 0.0) & (g[..., _BLOCKS] < 2.0))
        return _paired(out, waiting, self.joint(joint).candidate)

    def _targets(self, joint: str, fit: Fit) -> Params:
        """The candidate with the guard's verdicts applied: a cell held back is 0, a term not kept is dropped (the
        speed profile's shape: flattened to the cell's level)."""
        p = fit.params.copy()
        s = self.settings
        ver = self.verdicts(joint)
        keep_ripple = np.zeros(s.n_temperature, dtype=bool)
        keep_trend = np.zeros(s.n_temperature, dtype=bool)
        any_ok = np.zeros(s.n_temperature, dtype=bool)
        veto_ripple = np.zeros(s.n_temperature, dtype=bool)
        veto_trend = np.zeros(s.n_temperature, dtype=bool)
        for d in range(2):
            for b in range(s.n_temperature):
                v = ver[d][b]
                if not v.applied:
                    p.speed_nm[d, b] = 0.0
                    continue
                any_ok[b] = True
                if 'speed' not in v.kept:
                    p.speed_nm[d, b] = 0.0
                elif 'shape' not in v.kept:
                    p.speed_nm[d, b] = fit.flat_nm[d, b]
                keep_ripple[b] |= 'ripple' in v.kept
                veto_ripple[b] |= 'ripple' not in v.kept
                keep_trend[b] |= 'trend' in v.kept
                veto_trend[b] |= 'trend' not in v.kept
        p.ripple[~(any_ok & keep_ripple & ~veto_ripple)] = 0.0
        p.trend_nm[~(any_ok & keep_trend & ~veto_trend)] = 0.0
        if not s.falling_friction:
            p.speed_nm[:] = rising_envelope(s, p.speed_nm, fit.node_model_nm, fit.node_weight)
        return p

    def target(self, joint: str) -> Params:
        """The target of ``joint`` (the candidate with the guard's verdicts; :meth:`refit` updates it)."""
        return self.joint(joint).target

    def settle(self, guarded: bool = True) -> None:
        """Batch learning: refit every joint (ripple periods searched) and apply its target at once; with
        ``guarded`` false, the candidate itself (every term, no guard: for a correction learned without scores)."""
        for j in self.identity.joints:
            fit = self.refit(j, search=True)
            self.joint(j).applied = (self.joint(j).target if guarded else fit.params).copy()
        self.rebuild()

    def reset(self) -> None:
        """Back to the pure model: no rows, no scores, nothing applied."""
        s = self.settings
        for j, st in self._joints.items():
            st.stats.clear()
            st.guard[:] = 0.0
            st.applied, st.target, st.candidate, st.searched_at = empty_params(s), empty_params(s), None, 0.0
            st.angle_range = st.bin_ranges = None
            self.periods[j] = ()
        self.rebuild()

    def copy(self) -> Correction:
        """An independent copy."""
        return copy.deepcopy(self)

    def with_settings(self, settings: CorrectionSettings) -> Correction:
        """A copy with other settings of the same layout (bound, prior, gate, guard): rows, scores and applied terms
        kept; the candidate and the target follow the new settings at the next :meth:`refit`."""
        from gimbal_friction.feedforward.correction.settings import LAYOUT
        for name in LAYOUT:
            if getattr(settings, name) != getattr(self.settings, name):
                raise CorrectionError(f'{name} is {getattr(self.settings, name)!r} in the correction, '
                                      f'{getattr(settings, name)!r} asked: another layout')
        out = Correction(settings, self.identity)
        for j, st in self._joints.items():
            mine = out.joint(j)
            mine.stats = st.stats.copy()
            mine.stats.settings = settings
            mine.guard = st.guard.copy()
            mine.applied = _resize(st.applied, settings)
            mine.searched_at = st.searched_at
            mine.angle_range = st.angle_range
            mine.bin_ranges = None if st.bin_ranges is None else st.bin_ranges.copy()
            out.periods[j] = self.periods[j]
        out.rebuild()
        return out

    # ------------------------------------------------------------------ reports
    def cells(self, joint: str) -> list[dict[str, Any]]:
        """One record per cell with data, in [N·m] and [°C] (the status topic's cells): ``direction``, ``bin``,
        ``centre_c``, ``samples``, ``mean_nm`` (mean residual), ``std_error_nm``, ``value_nm`` (the applied speed
        profile over the cell's data, its level), ``speed_nm`` (the applied profile per speed octave), ``applied``,
        ``held_back`` (the guard's reason, empty when applied), ``terms`` (kept), ``scored``, ``rms_model_nm``,
        ``rms_with_nm``, ``z`` (per guard term), ``saturated``."""
        s = self.settings
        st = self.joint(joint)
        counts = st.stats.cell_counts()
        keys, sums = st.stats.rows()
        cell_of_row = keys // ((s.n_position + 1) * s.n_speed)
        total = np.bincount(cell_of_row, weights=sums[:, 1], minlength=2 * s.n_temperature)
        ver = self.verdicts(joint)
        fit = st.candidate
        out = []
        for c in np.flatnonzero(counts).tolist():
            d, b = divmod(c, s.n_temperature)
            k = int(counts[c])
            mean = float(total[c]) / k
            var = (float(st.stats.cell_sq[c]) - k * mean * mean) / (k - 1) if k > 1 else math.nan
            prof = st.applied.speed_nm[d, b]
            sel = cell_of_row == c
            level = _profile_level(prof, sums[sel, 3] / sums[sel, 0], sums[sel, 0])
            v = ver[d][b]
            out.append({'direction': DIRECTIONS[d], 'bin': b, 'centre_c': s.centre_c(b), 'samples': k,
                        'mean_nm': mean, 'std_error_nm': math.sqrt(max(var, 0.0) / k) if k > 1 else None,
                        'value_nm': level, 'speed_nm': prof.tolist(), 'applied': v.applied,
                        'held_back': v.reason, 'terms': list(v.kept), 'scored': v.scored,
                        'rms_model_nm': v.rms_model_nm, 'rms_with_nm': v.rms_with_nm, 'z': v.z,
                        'saturated': bool(fit.saturated[d, b]) if fit is not None else False})
        return out

    def unbalance_nm(self, joint: str) -> dict[str, Any]:
        """The applied torque independent of the direction of motion (an unbalance, a cable, or a CW/CCW
        difference of the friction): per temperature bin with data, its level ½(S_cw − S_ccw) over the speed
        octaves' mean [N·m] and its change with the angle (sin, cos − 1 coefficients) [N·m]."""
        st = self.joint(joint)
        has = self.has_data(joint)
        both = has[0] & has[1]
        p = st.applied
        out = []
        for b in np.flatnonzero(both).tolist():
            even = 0.5 * (p.speed_nm[0, b] - p.speed_nm[1, b])
            out.append({'centre_c': self.settings.centre_c(b), 'level_nm': float(even.mean()),
                        'sin_nm': float(p.trend_nm[b, 2]), 'cos_nm': float(p.trend_nm[b, 3])})
        return {'bins': out, 'max_abs_nm': max((abs(x['level_nm']) + abs(x['sin_nm']) for x in out), default=0.0)}

    def summary(self) -> dict[str, Any]:
        """Per joint and in total: cells with data, samples, cells applied and held back, saturated cells, the
        largest |applied value| [N·m], |relative ripple| [-] and |direction-independent torque| [N·m], the ripple
        periods [rad] with their evidence; and the clipped lookups."""
        joints = {}
        for j in self.identity.joints:
            st = self.joint(j)
            counts = st.stats.cell_counts()
            ver = self.verdicts(j)
            flat_ver = [ver[c // self.settings.n_temperature][c % self.settings.n_temperature]
                        for c in np.flatnonzero(counts).tolist()]
            p = st.applied
            sat = st.candidate.saturated if st.candidate is not None else np.zeros((2, 1), dtype=bool)
            amp = np.hypot(p.ripple[..., 0], p.ripple[..., 1]) if p.ripple.size else np.zeros(1)
            joints[j] = {'cells_with_data': int(np.count_nonzero(counts)), 'samples': int(counts.sum()),
                         'cells_applied': sum(v.applied for v in flat_ver),
                         'cells_held_back': sum(not v.applied for v in flat_ver),
                         'saturated_cells': int(np.count_nonzero(sat)),
                         'max_abs_correction_nm': float(np.abs(p.speed_nm).max()) if p.speed_nm.size else 0.0,
                         'max_abs_ripple': float(amp.max()) if amp.size else 0.0,
                         'max_abs_unbalance_nm': self.unbalance_nm(j)['max_abs_nm'],
                         'periods': [{'period_rad': q.period_rad, 'period_deg': math.degrees(q.period_rad),
                                      'amplitude': q.amplitude, 'z': q.z, 'power': q.power, 'points': q.samples}
                                     for q in self.periods[j]]}
        out: dict[str, Any] = {k: sum(d[k] for d in joints.values()) for k in (
            'cells_with_data', 'samples', 'cells_applied', 'cells_held_back', 'saturated_cells')}
        for k in ('max_abs_correction_nm', 'max_abs_ripple', 'max_abs_unbalance_nm'):
            out[k] = max(d[k] for d in joints.values())
        return {**out, 'lookup_saturations': self.lookup_saturations, 'joints': joints}

    # ------------------------------------------------------------------ identity
    def check_identity(self, expected: ModelIdentity, source: str = 'correction') -> None:
        """Raise CorrectionError (one line) unless this correction was learned against ``expected``."""
        fix = ('use the configuration it was learned with (the refitted parameters: --config / --params-file), '
               'or relearn it')
        if self.identity.joints != expected.joints:
            raise CorrectionError(f'{source} is for joints {", ".join(self.identity.joints)}, the model has '
                                  f'{", ".join(expected.joints)}: {fix}')
        if self.identity.params_sha256 != expected.params_sha256:
            raise CorrectionError(f'{source} was learned against model parameters {self.identity.params_sha256[:12]}, '
                                  f'the model is {expected.params_sha256[:12]}: {fix}')

    @classmethod
    def from_residuals(cls, settings: CorrectionSettings, identity: ModelIdentity,
                       samples: Mapping[str, tuple[ArrayLike, ...]], chunk: int = 250
                       ) -> tuple[Correction, dict[str, dict[str, int]]]:
        """Learned from residual arrays per joint in time order: ``(temperature_c, velocity_rad_s, position_rad,
        residual_nm, model_nm[, temperature_fresh])`` (units as :meth:`add_residuals`), test then train in blocks
        of ``chunk`` samples or a twentieth of those learned already, whichever is more, then settled; also the
        refused samples per joint."""
        c = cls(settings, identity)
        refused: dict[str, dict[str, int]] = {}
        for j, cols in samples.items():
            arrays = [np.atleast_1d(np.asarray(a)) for a in cols]
            n = max(a.size for a in arrays)
            mine: dict[str, int] = {}
            k0 = 0
            while k0 < n:
                step = max(chunk, c.stats(j).samples() // 20)
                part = [a[k0:k0 + step] if a.size == n else a for a in arrays]
                for reason, k in c.learn_residuals(j, *part).items():
                    mine[reason] = mine.get(reason, 0) + k
                c.refit(j)
                k0 += step
            refused[j] = mine
        c.settle()
        return c, refused


def identifiable_bins(samples: Array, node_weight: Array) -> NDArray[np.bool_]:
    """Temperature bins (bins,) where a torque independent of the direction can be told from friction: both
    directions measured (``samples`` (2, bins) [-]) at a common speed, i.e. at least one speed node that each
    direction's data weighs (``node_weight`` (2, bins, octaves) [-]) with a sample or more (the two directions' speeds
    within an octave of each other; how many samples it takes is the guard's to say).

    A cell's value S_d is the friction's change along the motion O plus, signed by the direction, the torque that does
    not depend on it E (S_cw = O + E, S_ccw = O − E): with one direction alone, or the two at speeds that do not
    meet, O and E are one unknown, and a bin that applied one of them would split it half and half into a friction
    change and an unbalance that did not exist (at a plateau where the friction is small beside an unbalance this made
    a chamber's correction 9 times worse than the model in the loop).

    >>> w = np.zeros((2, 3, 4)); w[0, :, 1] = 100.0; w[1, 0, 1] = 2.0; w[1, 1, 3] = 100.0
    >>> identifiable_bins(np.array([[9.0, 9.0, 9.0], [9.0, 9.0, 0.0]]), w).tolist()
    [True, False, False]
    """
    seen = node_weight >= 1.0
    return np.asarray((samples[0] > 0.0) & (samples[1] > 0.0) & np.any(seen[0] & seen[1], axis=-1), dtype=bool)


def _paired(ver: list[list[Verdict]], waiting: NDArray[np.bool_], fit: Fit | None) -> list[list[Verdict]]:
    """The guard's per-cell verdicts ``ver`` with the pairing rule: a cell is applied only where its bin's
    direction-independent part is identifiable (:func:`identifiable_bins`) and the cell of the other direction was
    judged by the guard too (``waiting`` (2, bins): still short of its out-of-sample scores). A cell applied while its
    partner waits would apply half of the torque independent of the direction that both learned as a change of the
    friction; a partner the guard judged and held back says the model is right in that direction (a CW/CCW
    asymmetry), and the cell is applied alone."""
    if fit is None:
        return ver
    ok = identifiable_bins(fit.samples, fit.node_weight)
    out = [list(row) for row in ver]
    for d in range(2):
        for b, v in enumerate(ver[d]):
            if not v.applied:
                continue
            other = ver[1 - d][b]
            if not ok[b]:
                why = ('the other direction was not measured at a common speed: a torque independent of the '
                       'direction cannot be told from friction')
            elif waiting[1 - d, b]:
                why = f'the {DIRECTIONS[1 - d]} cell is not judged yet ({other.reason})'
            else:
                continue
            out[d][b] = v._replace(applied=False, reason=why, kept=())
    return out


def _profile_level(profile: Array, u: Array, n: Array) -> float:
    """A speed profile [N·m] (per octave node) averaged over rows at octave coordinates ``u`` [-] with ``n`` samples:
    the level the rows see (linear between octave centres, as the fit and the lookup read it)."""
    ns = profile.size
    if ns == 1 or n.sum() <= 0.0:
        return float(profile[0])
    x = np.clip(u - 0.5, 0.0, ns - 1.0)
    k0 = np.minimum(x.astype(np.int64), ns - 2)
    f = x - k0
    at = (1.0 - f) * profile[k0] + f * profile[k0 + 1]
    return float(np.average(at, weights=n))


def _resize(p: Params, s: CorrectionSettings) -> Params:
    """``p`` for settings with the same layout (a copy)."""
    return Params(p.speed_nm.copy(), p.periods_rad.copy(), p.ripple.copy(), p.trend_nm.copy()) \
        if p.speed_nm.shape[2] == s.n_speed else Params(np.repeat(p.speed_nm.mean(axis=2, keepdims=True), s.n_speed,
                                                                  axis=2), p.periods_rad.copy(), p.ripple.copy(),
                                                        p.trend_nm.copy())


_ = SCALAR
