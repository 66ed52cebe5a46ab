r"""A learned additive correction to the physics friction torque, learned from residuals (pure numpy; no rclpy).

One job in one module: the correction (its cells, lookups and learning update share one layout).

The physics model gives the friction magnitude ``k_d(T) M(T, |v|)`` [N·m]; a real gimbal adds what the model
leaves out (cold CW/CCW asymmetry, position ripple, a lubricant off its datasheet, a temperature sensor offset).
:class:`Correction` holds that residue as a correction ``c`` *along the motion* [N·m] (positive: more friction than
the model in that direction), which the feedforward adds to the model magnitude before its smooth sign:

.. math:: \tau = \operatorname{clamp}\big(\tanh(v/v_{th})\,(k_d M + c),\ \pm\tau_{max}\big),\qquad
          |c| \le r_{max}\,k_d M + c_{floor}

Cells: temperature bin (default 5 °C wide, centred on multiples of 5 °C, -60…120 °C) × direction (``cw``: v > 0,
``ccw``: v < 0) × position bin (``position_bins`` over ``position_period_rad``, 0 = no position map). A cell holds
the sample count ``n``, the sum ``S`` of residuals along the motion [N·m], their sum of squares and the sum of
``|model|``. Its value is shrunk towards zero with a prior of ``n0`` samples (``prior_samples``):

.. math:: c_{cell} = S / (n + n_0)

so an empty correction is exactly 0 and a thin cell stays near 0. With a position map the cell's deviation from its
mean in each position bin, shrunk the same way, is smoothed to its first ``harmonics`` Fourier harmonics over the
period (like ODrive's anticogging map; looked up at the *reference* position). A cell's value is held within
``max_relative`` × its mean ``|model|`` + ``floor_nm`` (``saturated`` otherwise); the lookup applies the same bound
with the caller's model torque and counts the lookups it clipped (:attr:`Correction.lookup_saturations`).
Lookup interpolates linearly in temperature between bin centres (clamped at the ends) and in position between
position-bin centres (periodic): pure float math on lists precomputed whenever the values change
(:meth:`Correction.along_nm`; on arrays :meth:`Correction.along_nm_array`, the same numbers). A map per cell
follows a ripple that grows in the cold; each position bin has the prior n0 too, so a map needs about
``position_bins`` times the data of its cell's mean. There is no speed axis: a residual that depends on speed (the
viscous part of a lubricant shift) is learned as its mean over the speeds seen (refit the lubricant for that).

File: :mod:`gimbal_friction.feedforward.correction_file` (YAML with units, the model's identity, per-cell values and
sample counts; :meth:`Correction.save` is atomic, :meth:`Correction.load` refuses a bad file with one line).

Learning: :meth:`Correction.add_residuals` (arrays: the chamber test, ``refit``) and :meth:`Learner.update` (one
sample: in service) share the gate and the cell rule (written once against ``xp``), and the value rule.
The learner publishes rate-limited values (at most ``max_rate_nm_per_min`` per node per minute).

>>> ident = model_identity({'elevation': {'walther_a': 8.6195}})
>>> c = Correction(CorrectionSettings(prior_samples=10.0), ident)
>>> c.along_nm('elevation', -40.0, 0.03, 0.0, 3.1e-3)          # empty: exactly the model
0.0
>>> rej = c.add_residuals('elevation', [-40.0] * 30, [0.03] * 30, [0.0] * 30, [2e-4] * 30, [3.1e-3] * 30)
>>> c.settle(); round(c.along_nm('elevation', -40.0, 0.03, 0.0, 3.1e-3) * 1e3, 4)   # N*mm: 30/(30+10) of 0.2
0.15
>>> c.along_nm('elevation', -40.0, -0.03, 0.0, 3.1e-3)         # the other direction has no data
0.0
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ConfigError, GimbalFrictionError, check_rules
from gimbal_friction.common.settings import setting
from gimbal_friction.common.xp import ARRAY, SCALAR

__all__ = ['DIRECTIONS', 'REASONS', 'Correction', 'CorrectionError', 'CorrectionSettings',
           'Learner', 'LearningSettings', 'ModelIdentity', 'cell_of', 'gate_code', 'model_identity']

DIRECTIONS = ('cw', 'ccw')
#: reason of a refused sample, by gate code (0 = accepted)
REASONS = ('', 'non-finite', 'stale temperature', 'near reversal', 'temperature outside the bins')
R_FROZEN, R_UNKNOWN = 'frozen', 'unknown joint'
Array = NDArray[np.float64]


class CorrectionError(GimbalFrictionError, ValueError):
    """A correction file or correction input cannot be used; the message is one line naming cause and fix."""


@dataclass(frozen=True)
class CorrectionSettings:
    """Layout, shrinkage, bound and gate of a correction (stored in its file; units in the names)."""

    temperature_min_c: float = setting(-62.5, 'degC', 'lower edge of the first temperature bin')
    temperature_max_c: float = setting(122.5, 'degC', 'upper edge of the last temperature bin')
    temperature_bin_c: float = setting(5.0, 'degC', 'width of a temperature bin (default: centred on multiples of 5)')
    prior_samples: float = setting(50.0, '-', 'n0: a cell holds sum/(n + n0), shrunk towards 0 where data is thin')
    max_relative: float = setting(0.5, '-', 'bound: |correction| <= this x |model| + floor_nm')
    floor_nm: float = setting(2e-5, 'N*m', 'absolute part of the bound')
    min_speed_rad_s: float = setting(0.005, 'rad/s', 'samples slower than this (near a reversal) are not learned')
    position_bins: int = setting(0, '-', 'bins of the position map over position_period_rad (0: no map)')
    position_period_rad: float = setting(2.0 * math.pi, 'rad', 'period of the position map (ripple period)')
    harmonics: int = setting(4, '-', 'Fourier harmonics kept in the position map')

    @property
    def n_temperature(self) -> int:
        """Number of temperature bins [-]."""
        return int(round((self.temperature_max_c - self.temperature_min_c) / self.temperature_bin_c))

    @property
    def n_position(self) -> int:
        """Position nodes per cell [-] (1 without a position map)."""
        return max(self.position_bins, 1)

    def edges_c(self) -> list[float]:
        """Temperature bin edges [°C]."""
        return [self.temperature_min_c + k * self.temperature_bin_c for k in range(self.n_temperature + 1)]

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        span = (self.temperature_max_c - self.temperature_min_c) / self.temperature_bin_c \
            if self.temperature_bin_c > 0.0 else 0.0
        p = self.position_bins
        check_rules(self, [
            ('temperature_bin_c', self.temperature_bin_c > 0.0, 'must be > 0 [degC]'),
            ('temperature_max_c', 2 <= round(span) <= 10000 and abs(span - round(span)) < 1e-6,
             'must exceed temperature_min_c by 2 to 10000 whole temperature_bin_c [degC]'),
            ('prior_samples', 0.0 < self.prior_samples <= 1e9, 'must lie in (0, 1e9] [-]'),
            ('max_relative', 0.0 <= self.max_relative <= 10.0, 'must lie in [0, 10] [-]'),
            ('floor_nm', 0.0 <= self.floor_nm <= 1.0, 'must lie in [0, 1] [N*m]'),
            ('min_speed_rad_s', 0.0 < self.min_speed_rad_s <= 10.0, 'must lie in (0, 10] [rad/s]'),
            ('position_bins', p == 0 or 4 <= p <= 4096, 'must be 0 (no map) or in [4, 4096] [-]'),
            ('position_period_rad', 0.0 < self.position_period_rad <= 2.0 * math.pi + 1e-12,
             'must lie in (0, 2 pi] [rad]'),
            ('harmonics', p == 0 or 1 <= self.harmonics < p / 2, 'must lie in [1, position_bins / 2) [-]'),
        ])


@dataclass(frozen=True)
class LearningSettings:
    """Settings of in-service learning (:class:`Learner`)."""

    max_rate_nm_per_min: float = setting(3e-4, 'N*m/min', 'largest change of the applied correction per minute')
    step_period_s: float = setting(1.0, 's', 'the published values move towards the learned ones this often')

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        check_rules(self, [('max_rate_nm_per_min', 0.0 < self.max_rate_nm_per_min <= 1.0,
                            'must lie in (0, 1] [N*m/min]'),
                           ('step_period_s', 0.0 < self.step_period_s <= 3600.0, 'must lie in (0, 3600] [s]')])


class ModelIdentity(NamedTuple):
    """The model a correction was learned against: the joints, in order, and a hash of their parameters."""

    joints: tuple[str, ...]
    params_sha256: str


def model_identity(axes: Mapping[str, Any]) -> ModelIdentity:
    """Identity of ``axes`` (joint → AxisParams, or any mapping of parameter name → value).

    Numbers are compared as floats (``1`` and ``1.0`` hash alike); key order does not matter; the joint order does.

    >>> a = model_identity({'elevation': {'walther_a': 8.6195, 'ball_count': 7}})
    >>> a == model_identity({'elevation': {'ball_count': 7.0, 'walther_a': 8.6195}}), a.params_sha256[:12]
    (True, '88c61a634b86')
    """
    def norm(v: Any) -> Any:
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v

    canon = []
    for joint, params in axes.items():
        values = params.to_mapping() if hasattr(params, 'to_mapping') else dict(params)
        canon.append([joint, {str(k): norm(v) for k, v in values.items()}])
    text = json.dumps(canon, sort_keys=True, separators=(',', ':'))
    return ModelIdentity(tuple(axes), hashlib.sha256(text.encode()).hexdigest())


# ------------------------------------------------------------------------------------------- the rules (xp)
def gate_code(s: CorrectionSettings, t_c: Any, v: Any, p: Any, r: Any, m: Any, fresh: Any, xp: Any) -> Any:
    """Gate of a residual sample: 0 accepted, else the index of its reason in :data:`REASONS`.

    ``t_c`` temperature [°C], ``v`` velocity [rad/s], ``p`` position [rad] (checked only with a position map),
    ``r`` residual and ``m`` model torque [N·m], ``fresh`` the temperature was fresh.

    >>> s = CorrectionSettings()
    >>> [REASONS[gate_code(s, -40.0, v, 0.0, 1e-4, 3e-3, True, SCALAR)] for v in (0.03, 0.001, float('nan'))]
    ['', 'near reversal', 'non-finite']
    """
    ok = xp.isfinite(t_c) & xp.isfinite(v) & xp.isfinite(r) & xp.isfinite(m)
    if s.position_bins:
        ok = ok & xp.isfinite(p)
    code = xp.where(t_c < s.temperature_min_c, 4, xp.where(t_c > s.temperature_max_c, 4, 0))
    code = xp.where(xp.abs(v) < s.min_speed_rad_s, 3, code)
    code = xp.where(fresh, code, 2)
    return xp.where(ok, code, 1)


def cell_of(s: CorrectionSettings, t_c: Any, v: Any, p: Any, r: Any, m: Any, xp: Any) -> tuple[Any, Any, Any, Any]:
    """Flat node index (direction, temperature bin, position bin), cell index (direction, temperature bin), the
    residual along the motion [N·m] and ``|model|`` [N·m] of accepted samples (see :func:`gate_code`)."""
    nt, npos = s.n_temperature, s.n_position
    cell = xp.where(v > 0.0, 0, nt) + xp.floor_index((t_c - s.temperature_min_c) / s.temperature_bin_c, nt - 1)
    pj = xp.floor_index(((p / s.position_period_rad) % 1.0) * npos, npos - 1) if s.position_bins else 0
    return cell * npos + pj, cell, xp.where(v > 0.0, r, -r), xp.abs(m)


class _Lookup:
    """Precomputed lists of one joint for :meth:`Correction.along_nm`."""

    __slots__ = ('ccw', 'cw', 'dc_ccw', 'dc_cw', 'floor', 'hi', 'inv_bin', 'npos', 'rel', 'scale', 't0')
    cw: list[float]
    ccw: list[float]
    dc_cw: list[float]
    dc_ccw: list[float]

    def __init__(self, s: CorrectionSettings, values: Array) -> None:
        nt, npos = s.n_temperature, s.n_position
        v = values.reshape(2, nt, npos)
        self.cw, self.ccw = v[0].ravel().tolist(), v[1].ravel().tolist()
        self.dc_cw, self.dc_ccw = v[0].mean(axis=1).tolist(), v[1].mean(axis=1).tolist()
        self.t0 = s.temperature_min_c + 0.5 * s.temperature_bin_c
        self.inv_bin, self.hi, self.npos = 1.0 / s.temperature_bin_c, nt - 1, npos
        self.scale = npos / s.position_period_rad
        self.rel, self.floor = s.max_relative, s.floor_nm


class Correction:
    """A learned correction of the joints of ``identity`` (the model the residuals are taken against,
    :func:`model_identity`) laid out by ``settings`` (see the module notes). ConfigError: invalid settings, no joint.
    """

    def __init__(self, settings: CorrectionSettings, identity: ModelIdentity) -> None:
        settings.validate()
        if not identity.joints:
            raise ConfigError('joints', 'a correction needs at least one joint')
        self.settings, self.identity = settings, identity
        s = settings
        nc, nn = 2 * s.n_temperature, 2 * s.n_temperature * s.n_position
        self.count = {j: np.zeros(nn, dtype=np.int64) for j in identity.joints}   #: samples per node [-]
        self.sum_nm = {j: np.zeros(nn) for j in identity.joints}                  #: Σ residual per node [N·m]
        self.sum_sq_nm2 = {j: np.zeros(nc) for j in identity.joints}              #: Σ residual² per cell [N²·m²]
        self.sum_model_nm = {j: np.zeros(nc) for j in identity.joints}            #: Σ |model| per cell [N·m]
        self.values_nm = {j: np.zeros(nn) for j in identity.joints}               #: applied value per node [N·m]
        self.lookup_saturations = 0  #: lookups whose value the bound clipped [-]
        #: per joint, the lookup lists of its learned values (None: nothing learned, the correction is 0 there)
        self.lookups: dict[str, _Lookup | None] = {}
        pos = (np.arange(s.n_position) + 0.5) / s.n_position
        k = np.arange(1, s.harmonics + 1)[:, None] if s.position_bins else np.zeros((0, 1))
        self._cos, self._sin = np.cos(2 * np.pi * k * pos), np.sin(2 * np.pi * k * pos)   # (K, P)
        # keep harmonics 1..K of the bin means, undoing the bin average's attenuation sinc(pi k / P)
        gain = 2.0 / s.n_position / np.sinc(k / s.n_position)
        self._smooth = (self._cos * gain).T @ self._cos + (self._sin * gain).T @ self._sin   # (P, P)
        self.rebuild()

    def rebuild(self) -> None:
        """Recompute the lookup lists after the values changed."""
        self.lookups = {j: (_Lookup(self.settings, v) if np.any(v) else None) for j, v in self.values_nm.items()}

    # ------------------------------------------------------------------ lookup (the feedforward's hot path)
    def along_nm(self, joint: str, temperature_c: float, velocity_rad_s: float, position_rad: float,
                 model_nm: float) -> float:
        """Correction along the motion [N·m] for motion at ``velocity_rad_s`` [rad/s] (``>= 0``: cw) at
        ``temperature_c`` [°C] and reference position ``position_rad`` [rad] (NaN: the position map is skipped),
        bounded by ``max_relative`` × ``|model_nm|`` [N·m] + ``floor_nm``. Add it to the model magnitude before the
        smooth sign. Exactly 0.0 for a joint without a learned value; unknown joint: KeyError."""
        lut = self.lookups[joint]
        if lut is None:
            return 0.0
        x = (temperature_c - lut.t0) * lut.inv_bin
        if 0.0 < x < lut.hi:
            i = int(x)
            w = x - i
        elif x > 0.0:
            i, w = lut.hi - 1, 1.0
        else:
            i, w = 0, 0.0  # (NaN too)
        npos = lut.npos
        if npos == 1:  # no position map
            vals = lut.cw if velocity_rad_s >= 0.0 else lut.ccw
            a = vals[i]
            c = a + w * (vals[i + 1] - a)
        else:
            y = (position_rad * lut.scale) % npos - 0.5
            if y != y:  # a NaN position: the cells' means
                vals = lut.dc_cw if velocity_rad_s >= 0.0 else lut.dc_ccw
                a = vals[i]
                return self._bounded(a + w * (vals[i + 1] - a), lut, model_nm)
            vals = lut.cw if velocity_rad_s >= 0.0 else lut.ccw
            if y < 0.0:
                y += npos
            j = int(y)
            u = y - j
            j1 = j + 1 if j + 1 < npos else 0
            r0 = i * npos
            a = vals[r0 + j]
            a += u * (vals[r0 + j1] - a)
            r0 += npos
            b = vals[r0 + j]
            c = a + w * (b + u * (vals[r0 + j1] - b) - a)
        bound = lut.rel * abs(model_nm) + lut.floor
        if -bound <= c <= bound:
            return c
        return self._bounded(c, lut, model_nm)

    def along_nm_array(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike, position_rad: ArrayLike,
                       model_nm: ArrayLike) -> Array:
        """:meth:`along_nm` on arrays (a whole bag, the loop study): the same operations in the same order, so the
        same numbers (tested); clipped lookups are counted the same way. Units as :meth:`along_nm`."""
        t, v, p, m = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (temperature_c, velocity_rad_s,
                                                                               position_rad, model_nm)))
        lut = self.lookups[joint]
        if lut is None:
            return np.zeros(t.shape)
        vals = self.values_nm[joint].reshape(2, self.settings.n_temperature, lut.npos)
        x = (t - lut.t0) * lut.inv_bin
        inside = (x > 0.0) & (x < lut.hi)
        i = np.where(inside, np.trunc(np.where(inside, x, 0.0)), np.where(x > 0.0, lut.hi - 1, 0)).astype(np.int64)
        w = np.where(inside, x - i, np.where(x > 0.0, 1.0, 0.0))
        d = np.where(v >= 0.0, 0, 1)
        dc = vals.mean(axis=2)
        a = dc[d, i]
        c = a + w * (dc[d, i + 1] - a)
        if lut.npos > 1:
            with np.errstate(invalid='ignore'):
                y = (p * lut.scale) % lut.npos - 0.5
            mapped = ~np.isnan(y)
            y = np.where(mapped, np.where(y < 0.0, y + lut.npos, y), 0.0)
            j = y.astype(np.int64)
            u = y - j
            j1 = np.where(j + 1 < lut.npos, j + 1, 0)
            a = vals[d, i, j]
            a = a + u * (vals[d, i, j1] - a)
            b = vals[d, i + 1, j]
            c = np.where(mapped, a + w * (b + u * (vals[d, i + 1, j1] - b) - a), c)
        bound = lut.rel * np.abs(m) + lut.floor
        clipped = ~((-bound <= c) & (c <= bound))
        self.lookup_saturations += int(np.count_nonzero(clipped))
        return np.asarray(np.where(clipped, np.where(c > 0.0, bound, -bound), c), dtype=np.float64)

    def _bounded(self, c: float, lut: _Lookup, model_nm: float) -> float:
        """``c`` [N·m] within the bound of ``model_nm`` [N·m]; a clipped value is counted."""
        bound = lut.rel * abs(model_nm) + lut.floor
        if -bound <= c <= bound:
            return c
        self.lookup_saturations += 1
        return bound if c > 0.0 else -bound

    # ------------------------------------------------------------------ learning (shared by batch and online)
    def add_residuals(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike, position_rad: ArrayLike,
                      residual_nm: ArrayLike, model_nm: ArrayLike, temperature_fresh: ArrayLike = True
                      ) -> dict[str, int]:
        """Accumulate residual samples of ``joint`` (arrays; the values are not changed: :meth:`settle`).

        ``residual_nm`` = measured friction − model friction, both signed like the motion [N·m]; ``model_nm`` the
        model friction [N·m]; temperature [°C], velocity [rad/s], position [rad]. Returns the refused samples per
        reason. Raises CorrectionError for an unknown joint or arrays of different lengths.
        """
        if joint not in self.count:
            raise CorrectionError(f'joint {joint!r} is not in this correction ({", ".join(self.identity.joints)})')
        try:
            t, v, p, r, m, f = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (
                temperature_c, velocity_rad_s, position_rad, residual_nm, model_nm)), np.asarray(temperature_fresh))
        except ValueError:
            raise CorrectionError('temperature, velocity, position, residual and model arrays must have one length'
                                  ) from None
        s = self.settings
        with np.errstate(invalid='ignore'):
            code = np.asarray(gate_code(s, t, v, p, r, m, f.astype(bool), ARRAY)).ravel()
        ok = code == 0
        node, cell, along, mabs = cell_of(s, t.ravel()[ok], v.ravel()[ok], p.ravel()[ok], r.ravel()[ok],
                                          m.ravel()[ok], ARRAY)
        nn, nc = self.count[joint].size, self.sum_sq_nm2[joint].size
        self.count[joint] += np.bincount(node, minlength=nn)
        self.sum_nm[joint] += np.bincount(node, weights=along, minlength=nn)
        self.sum_sq_nm2[joint] += np.bincount(cell, weights=along * along, minlength=nc)
        self.sum_model_nm[joint] += np.bincount(cell, weights=mabs, minlength=nc)
        return {REASONS[k]: int(n) for k, n in enumerate(np.bincount(code, minlength=len(REASONS))) if k and n}

    def _add_one(self, joint: str, t_c: float, v: float, p: float, r: float, m: float, fresh: bool) -> str | None:
        """:meth:`add_residuals` for one sample (the same rules on floats); the reason if refused."""
        s = self.settings
        code = gate_code(s, t_c, v, p, r, m, fresh, SCALAR)
        if code:
            return REASONS[code]
        node, cell, along, mabs = cell_of(s, t_c, v, p, r, m, SCALAR)
        self.count[joint][node] += 1
        self.sum_nm[joint][node] += along
        self.sum_sq_nm2[joint][cell] += along * along
        self.sum_model_nm[joint][cell] += mabs
        return None

    def targets(self, joint: str) -> tuple[Array, NDArray[np.bool_]]:
        """The learned (shrunk, smoothed, bounded) value of every node [N·m] and whether each cell saturated."""
        s = self.settings
        nc, npos, n0 = 2 * s.n_temperature, s.n_position, s.prior_samples
        n = self.count[joint].reshape(nc, npos).astype(float)
        total = self.sum_nm[joint].reshape(nc, npos)
        n_cell, s_cell = n.sum(axis=1), total.sum(axis=1)
        value = (s_cell / (n_cell + n0))[:, None] * np.ones(npos)
        mean = np.divide(s_cell, n_cell, out=np.zeros(nc), where=n_cell > 0)
        if s.position_bins:
            value = value + ((total - n * mean[:, None]) / (n + n0)) @ self._smooth
        bound = (s.max_relative * np.divide(self.sum_model_nm[joint], n_cell, out=np.zeros(nc), where=n_cell > 0)
                 + s.floor_nm)[:, None]
        return np.clip(value, -bound, bound).ravel(), (np.abs(value) > bound).any(axis=1) & (n_cell > 0)

    def settle(self) -> None:
        """Apply the learned values at once (batch learning; the :class:`Learner` moves them at a limited rate)."""
        for j in self.values_nm:
            self.values_nm[j] = self.targets(j)[0]
        self.rebuild()

    @classmethod
    def from_residuals(cls, settings: CorrectionSettings, identity: ModelIdentity,
                       samples: Mapping[str, tuple[ArrayLike, ...]]) -> tuple[Correction, dict[str, dict[str, int]]]:
        """Learned from residual arrays per joint: ``(temperature_c, velocity_rad_s, position_rad, residual_nm,
        model_nm[, temperature_fresh])`` (units as :meth:`add_residuals`); also the refused samples per joint."""
        c = cls(settings, identity)
        refused = {j: c.add_residuals(j, *cols) for j, cols in samples.items()}
        c.settle()
        return c, refused

    # ------------------------------------------------------------------ reports
    def cells(self, joint: str) -> list[dict[str, Any]]:
        """One record per cell with data, in [N·m] and [°C] (the file's and the status topic's cells)."""
        s = self.settings
        nt, npos = s.n_temperature, s.n_position
        _, sat = self.targets(joint)
        n = self.count[joint].reshape(2 * nt, npos)
        tot = self.sum_nm[joint].reshape(2 * nt, npos)
        val = self.values_nm[joint].reshape(2 * nt, npos)
        out = []
        for c in np.flatnonzero(n.sum(axis=1)).tolist():
            k, b = int(n[c].sum()), c % nt
            mean = float(tot[c].sum()) / k
            var = (float(self.sum_sq_nm2[joint][c]) - k * mean * mean) / (k - 1) if k > 1 else math.nan
            rec = {'direction': DIRECTIONS[c // nt], 'bin': b, 'centre_c': s.temperature_min_c + (b + 0.5) *
                   s.temperature_bin_c, 'value_nm': float(val[c].mean()), 'samples': k, 'sum_nm': float(tot[c].sum()),
                   'mean_nm': mean, 'std_error_nm': math.sqrt(max(var, 0.0) / k) if k > 1 else None,
                   'sum_sq_nm2': float(self.sum_sq_nm2[joint][c]),
                   'sum_abs_model_nm': float(self.sum_model_nm[joint][c]),
                   'saturated': bool(sat[c])}
            if s.position_bins:
                dev = val[c] - val[c].mean()
                rec |= {'values_nm': val[c].tolist(), 'position_samples': n[c].tolist(),
                        'position_sums_nm': tot[c].tolist(),
                        'harmonics_cos_nm': (self._cos @ dev * 2.0 / npos).tolist(),
                        'harmonics_sin_nm': (self._sin @ dev * 2.0 / npos).tolist()}
            out.append(rec)
        return out

    def summary(self) -> dict[str, Any]:
        """Cells with data, samples, largest |value| [N·m] and saturated cells, per joint and in total."""
        joints = {}
        for j in self.identity.joints:
            n_cell = self.count[j].reshape(2 * self.settings.n_temperature, -1).sum(axis=1)
            joints[j] = {'cells_with_data': int(np.count_nonzero(n_cell)), 'samples': int(n_cell.sum()),
                         'max_abs_correction_nm': float(np.abs(self.values_nm[j]).max()),
                         'saturated_cells': int(np.count_nonzero(self.targets(j)[1]))}
        out: dict[str, Any] = {k: sum(d[k] for d in joints.values()) for k in ('cells_with_data', 'samples',
                                                                              'saturated_cells')}
        out['max_abs_correction_nm'] = max(d['max_abs_correction_nm'] for d in joints.values())
        return {**out, 'lookup_saturations': self.lookup_saturations, 'joints': joints}

    # ------------------------------------------------------------------ file
    def check_identity(self, expected: ModelIdentity, source: str = 'correction') -> None:
        """Raise CorrectionError (one line) unless this correction was learned against ``expected``."""
        if self.identity.joints != expected.joints:
            raise CorrectionError(f'{source} is for joints {", ".join(self.identity.joints)}, the model has '
                                  f'{", ".join(expected.joints)}: relearn it or delete the file')
        if self.identity.params_sha256 != expected.params_sha256:
            raise CorrectionError(f'{source} was learned against model parameters {self.identity.params_sha256[:12]}, '
                                  f'the model is {expected.params_sha256[:12]}: relearn it or delete the file')

    def to_mapping(self) -> dict[str, Any]:
        """The file's content (plain Python values; :mod:`~gimbal_friction.feedforward.correction_file`)."""
        from gimbal_friction.feedforward.correction_file import to_mapping
        return to_mapping(self)

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the YAML file atomically (:func:`~gimbal_friction.feedforward.correction_file.save`)."""
        from gimbal_friction.feedforward.correction_file import save
        save(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str], expected: ModelIdentity | None = None) -> Correction:
        """Read a file written by :meth:`save`; with ``expected``, refuse one learned against another model
        (:func:`~gimbal_friction.feedforward.correction_file.load`). Raises CorrectionError (one line)."""
        from gimbal_friction.feedforward.correction_file import load
        return load(path, expected)


class Learner:
    """Learns a :class:`Correction` online from accepted estimator samples (the in-service learning).

    ``correction`` (learned so far, e.g. :meth:`Correction.load`, or empty) is updated in place: its accumulators
    at every :meth:`update`, its applied values every ``step_period_s`` (and at :meth:`step`), each node moving
    towards its learned value by at most ``max_rate_nm_per_min`` per minute (the step's time is capped at
    ``step_period_s``, so a pause does not allow a jump). Lookups use ``learner.correction``.
    """

    def __init__(self, correction: Correction, settings: LearningSettings) -> None:
        settings.validate()
        self.correction, self.settings = correction, settings
        self.frozen = False
        self.accepted = 0                      #: samples learned [-]
        self.rejected: dict[str, int] = {}     #: samples refused, per reason [-]
        self._last_step_s: float | None = None

    def update(self, joint: str, temperature_c: float, velocity_rad_s: float, position_rad: float, residual_nm: float,
               model_nm: float, now_s: float, temperature_fresh: bool = True) -> str | None:
        """Learn one accepted estimator sample at time ``now_s`` [s] (units as :meth:`Correction.add_residuals`);
        returns the reason if the sample was refused (frozen, unknown joint, or the gate of :func:`gate_code`)."""
        if self.frozen:
            reason: str | None = R_FROZEN
        elif joint not in self.correction.count:
            reason = R_UNKNOWN
        else:
            reason = self.correction._add_one(joint, temperature_c, velocity_rad_s, position_rad, residual_nm,
                                              model_nm, temperature_fresh)
        if reason is None:
            self.accepted += 1
        else:
            self.rejected[reason] = self.rejected.get(reason, 0) + 1
        if self._last_step_s is None or not 0.0 <= now_s - self._last_step_s < self.settings.step_period_s:
            self.step(now_s)
        return reason

    def step(self, now_s: float) -> bool:
        """Move the applied values towards the learned ones for the time since the last step (at most
        ``step_period_s``) [s]; True if a value changed. Nothing moves while frozen or when time runs backwards."""
        last, self._last_step_s = self._last_step_s, now_s
        if self.frozen or last is None or not now_s > last:
            return False
        c = self.correction
        limit = self.settings.max_rate_nm_per_min * min(now_s - last, self.settings.step_period_s) / 60.0
        changed = False
        for j, values in c.values_nm.items():
            target = c.targets(j)[0]
            new = values + np.clip(target - values, -limit, limit)
            if not np.array_equal(new, values):
                c.values_nm[j], changed = new, True
        if changed:
            c.rebuild()
        return changed

    def freeze(self, frozen: bool = True) -> None:
        """Stop (or, with False, resume) learning; the applied correction stays as it is."""
        self.frozen = frozen

    def reset(self) -> None:
        """Back to the pure model at once: an empty correction (the counters of refused samples stay)."""
        c = self.correction
        for arrays in (c.count, c.sum_nm, c.sum_sq_nm2, c.sum_model_nm, c.values_nm):
            for a in arrays.values():
                a[:] = 0
        self.accepted = 0
        c.rebuild()

    def snapshot(self) -> Correction:
        """An independent copy of the correction, to save or publish."""
        return copy.deepcopy(self.correction)

    @property
    def state(self) -> str:
        """``frozen``, ``saturated`` (a cell's learned value is clipped by the bound) or ``active``."""
        if self.frozen:
            return 'frozen'
        return 'saturated' if self.correction.summary()['saturated_cells'] else 'active'

    def cells(self, joint: str) -> list[dict[str, Any]]:
        """:meth:`Correction.cells` with each cell's ``state`` (``frozen``, ``saturated`` or ``active``)."""
        return [{**rec, 'state': 'frozen' if self.frozen else 'saturated' if rec['saturated'] else 'active'}
                for rec in self.correction.cells(joint)]

    def summary(self) -> dict[str, Any]:
        """:meth:`Correction.summary` with the state and the accepted/refused sample counts (status, diagnostics)."""
        return {'state': self.state, 'accepted': self.accepted, 'rejected': dict(self.rejected),
                **self.correction.summary()}
