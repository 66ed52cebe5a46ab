r"""A learned additive correction to the physics friction torque, learned from residuals (pure numpy; no rclpy).

One job in one module: the correction (its cells, lookups and learning update share one layout).

The physics model gives the friction magnitude ``k_d(T) M(T, |v|)`` [N·m]; a real gimbal adds what the model
leaves out (cold CW/CCW asymmetry, position ripple, a lubricant off its datasheet, a temperature sensor offset).
:class:`Correction` holds that residue as a correction ``c`` *along the motion* [N·m] (positive: more friction than
the model in that direction), which the feedforward adds to the model magnitude before its smooth sign:

.. math:: \tau = \operatorname{clamp}\big(\tanh(v/v_{th})\,(k_d M + c),\ \pm\tau_{max}\big),\qquad
          |c| \le r_{max}\,k_d M + c_{floor}

Cells: temperature bin (default 5 °C wide, centred on multiples of 5 °C, -60…120 °C) × direction (``cw``: v > 0,
``ccw``: v < 0). Within a cell the correction is

.. math:: c = c_0 + b\,x + \rho(\theta)\,|k_d M|,\qquad x = \big(\max(|v|, v_{min}) / v_{ref}\big)^{2/3}

- ``c_0`` [N·m], the cell's value: its residuals' mean shrunk towards zero with a prior of ``n0`` samples
  (``prior_samples``), :math:`S / (n + n_0)`, so an empty correction is exactly 0 and a thin cell stays near 0;
- ``b x``, the speed term (``speed_term``): x is the speed shape of Palmgren's viscous torque (Eq. 9,
  M_L ∝ (ν n)^(2/3)), held below the gate's ``min_speed_rad_s``; b [N·m] is a ridge regression of the residuals on
  x from the speed changes met within each position bin (so a ripple met at the slow end of a motion is not taken
  for speed), shrunk to 0 where the speeds hardly vary (``speed_prior_spread``): a lubricant off its datasheet is
  followed at every speed, and a cell learned at one speed keeps its value at every speed;
- ``ρ(θ) |k_d M|``, with a position map (``position_bins`` over ``position_period_rad``, 0 = none), the ripple as a
  fraction ρ [-] of the model friction (a race's waviness modulates the friction it carries, so a map learned at one
  speed holds at another): per position bin the residual left after c_0 and b x over its Σ|model| (with n0 prior
  samples), smoothed to its first ``harmonics`` Fourier harmonics over the period (like ODrive's anticogging map;
  looked up at the *reference* position).

Per node (direction × temperature bin × position bin) a cell keeps the sums learning resumes from (samples, Σr,
Σx, Σx², Σx·r, Σ|model|; Σr² per cell). A cell's value is held within ``max_relative`` × its mean ``|model|`` +
``floor_nm`` (``saturated`` otherwise), ρ within ± ``max_relative``; the lookup bounds the whole correction by
``max_relative`` × the caller's ``|model|`` + ``floor_nm`` and counts the lookups it clipped
(:attr:`Correction.lookup_saturations`). Lookup interpolates linearly in temperature between bin centres (clamped at
the ends; an empty bin next to a learned one holds its value, :meth:`Correction.held`, so the correction tapers to 0
only one bin further) and in position between position-bin centres (periodic): pure float math on lists precomputed
whenever the values change (:meth:`Correction.along_nm`; on arrays :meth:`Correction.along_nm_array`, the same numbers).

File: :mod:`gimbal_friction.feedforward.correction_file` (YAML with units, the model's identity, per-cell values and
sample counts; :meth:`Correction.save` is atomic, :meth:`Correction.load` refuses a bad file with one line).

Learning: :meth:`Correction.add_residuals` (arrays: the chamber test, ``refit``) and :meth:`Learner.update` (one
sample: in service) share the gate and the cell rule (written once against ``xp``), and the value rule.
The learner moves the applied values at a limited rate (at most ``max_rate_nm_per_min`` per minute, at the speeds and
friction the cell has seen).

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
#: the speed term is held above this speed [rad/s] (about 1000 rpm: beyond any gimbal; keeps it finite)
MAX_SPEED_RAD_S = 100.0
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
    max_relative: float = setting(0.5, '-', 'bound: |correction| <= this x |model| + the absolute floor')
    floor_nm: float = setting(2e-5, 'N*m', 'absolute part of the bound')
    min_speed_rad_s: float = setting(0.005, 'rad/s', 'samples slower than this (near a reversal) are not learned')
    position_bins: int = setting(0, '-', 'bins of the position map over its period (0: no map)')
    position_period_rad: float = setting(2.0 * math.pi, 'rad', 'period of the position map (ripple period)')
    harmonics: int = setting(4, '-', 'Fourier harmonics kept in the position map')
    speed_term: bool = setting(True, '-', 'learn and apply, per cell, a term in (|v| / the reference speed)^(2/3) '
                               "(the speed dependence of Palmgren's viscous torque, Eq. 9: a lubricant off its "
                               'datasheet); false: one value per cell')
    speed_reference_rad_s: float = setting(0.0349066, 'rad/s', 'speed where the speed term is 1 (default 1/3 rpm)')
    speed_prior_spread: float = setting(0.2, '-', 'the speed term is shrunk towards 0 like n0 prior samples whose '
                                        "speed term spreads by this fraction of the cell's mean one")

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
            ('speed_term', isinstance(self.speed_term, bool), 'must be true or false'),
            ('speed_reference_rad_s', 1e-4 <= self.speed_reference_rad_s <= 100.0, 'must lie in [1e-4, 100] [rad/s]'),
            ('speed_prior_spread', 1e-3 <= self.speed_prior_spread <= 10.0, 'must lie in [1e-3, 10] [-]'),
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


def speed_term(s: CorrectionSettings, v: Any, xp: Any) -> Any:
    """The speed term x = (clip(|v|, ``min_speed_rad_s``, :data:`MAX_SPEED_RAD_S`) / ``speed_reference_rad_s``)^(2/3)
    [-] at velocity ``v`` [rad/s]: the shape of Palmgren's viscous torque in speed (Eq. 9, M_L ∝ (ν n)^(2/3)), held
    below the slowest speed learned (the gate's ``min_speed_rad_s``) rather than extrapolated towards zero speed, and
    above :data:`MAX_SPEED_RAD_S` (so an absurd velocity gives a finite term; the bound then clips the correction).

    >>> s = CorrectionSettings()
    >>> round(speed_term(s, -8 * 0.0349066, SCALAR), 12), speed_term(s, 0.0, SCALAR) == speed_term(s, 0.005, SCALAR)
    (4.0, True)
    """
    return (xp.clip(xp.abs(v), s.min_speed_rad_s, MAX_SPEED_RAD_S) / s.speed_reference_rad_s) ** (2.0 / 3.0)


class _Lookup:
    """Precomputed lists of one joint for :meth:`Correction.along_nm`, per direction: the value at speed term 0 per
    temperature bin (``cw``, ``ccw``), the speed coefficient per temperature bin (``sl_*``; None: all 0) and the
    relative ripple per (temperature bin, position bin) (``rp_*``; None: no map or all 0)."""

    __slots__ = ('ccw', 'cw', 'floor', 'hi', 'inv_bin', 'npos', 'rel', 'rp_ccw', 'rp_cw', 'scale', 'sl_ccw', 'sl_cw',
                 't0')
    cw: list[float]
    ccw: list[float]
    sl_cw: list[float] | None
    sl_ccw: list[float] | None
    rp_cw: list[float] | None
    rp_ccw: list[float] | None

    def __init__(self, s: CorrectionSettings, values: Array, speed_nm: Array, speed_ref: Array, ripple: Array) -> None:
        nt, npos = s.n_temperature, s.n_position
        v = (values - speed_nm * speed_ref).reshape(2, nt)   # at speed term 0 (exactly ``values`` without one)
        self.cw, self.ccw = v[0].tolist(), v[1].tolist()
        sl = speed_nm.reshape(2, nt)
        self.sl_cw, self.sl_ccw = (sl[0].tolist(), sl[1].tolist()) if np.any(sl) else (None, None)
        rp = ripple.reshape(2, nt * npos)
        self.rp_cw, self.rp_ccw = (rp[0].tolist(), rp[1].tolist()) if s.position_bins and np.any(rp) else (None, None)
        self.t0 = s.temperature_min_c + 0.5 * s.temperature_bin_c
        self.inv_bin, self.hi, self.npos = 1.0 / s.temperature_bin_c, nt - 1, npos
        self.scale = npos / s.position_period_rad
        self.rel, self.floor = s.max_relative, s.floor_nm


class LearnedFit(NamedTuple):
    """What a correction's sums say for one joint (:meth:`Correction.fit`)."""

    values_nm: Array                #: value per cell at its mean speed term [N·m] (shrunk, bounded)
    speed_nm: Array                 #: coefficient of the speed term per cell [N·m] (0 unless speed_term)
    speed_mean: Array               #: mean speed term per cell [-] (0: no data)
    ripple: Array                   #: relative ripple per node [-] (position map; 0 without one)
    model_mean_nm: Array            #: mean |model| per cell [N·m] (0: no data)
    saturated: NDArray[np.bool_]    #: the cell's value was clipped by the bound


class Correction:
    """A learned correction of the joints of ``identity`` (the model the residuals are taken against,
    :func:`model_identity`) laid out by ``settings`` (see the module notes). ConfigError: invalid settings, no joint.
    """

    #: the arrays that hold a correction's state (sums learning resumes from, applied values), per joint
    STATE = ('count', 'sum_nm', 'sum_speed', 'sum_speed_sq', 'sum_speed_res_nm', 'sum_model_nm', 'sum_sq_nm2',
             'values_nm', 'speed_nm', 'speed_ref', 'ripple')

    def __init__(self, settings: CorrectionSettings, identity: ModelIdentity) -> None:
        settings.validate()
        if not identity.joints:
            raise ConfigError('joints', 'a correction needs at least one joint')
        self.settings, self.identity = settings, identity
        s = settings
        nc, nn = 2 * s.n_temperature, 2 * s.n_temperature * s.n_position
        joints = identity.joints
        # sums per node (direction, temperature bin, position bin)
        self.count = {j: np.zeros(nn, dtype=np.int64) for j in joints}  #: samples [-]
        self.sum_nm = {j: np.zeros(nn) for j in joints}                 #: Σ residual r [N·m]
        self.sum_speed = {j: np.zeros(nn) for j in joints}              #: Σ speed term x [-]
        self.sum_speed_sq = {j: np.zeros(nn) for j in joints}           #: Σ x² [-]
        self.sum_speed_res_nm = {j: np.zeros(nn) for j in joints}       #: Σ x·r [N·m]
        self.sum_model_nm = {j: np.zeros(nn) for j in joints}           #: Σ |model| [N·m]
        self.sum_sq_nm2 = {j: np.zeros(nc) for j in joints}             #: Σ r² per cell [N²·m²]
        # applied: per cell c = value + speed_nm (x - speed_ref), plus ripple(θ) |model| with a position map
        self.values_nm = {j: np.zeros(nc) for j in joints}   #: value per cell at the speed term speed_ref [N·m]
        self.speed_nm = {j: np.zeros(nc) for j in joints}    #: coefficient of the speed term per cell [N·m]
        self.speed_ref = {j: np.zeros(nc) for j in joints}   #: reference speed term per cell [-]
        self.ripple = {j: np.zeros(nn) for j in joints}      #: relative ripple per node [-]
        self.lookup_saturations = 0  #: lookups whose value the bound clipped [-]
        #: per joint, :meth:`held` of the applied values (what the lookups read)
        self._held: dict[str, tuple[Array, Array, Array, Array]] = {}
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
        self._held = {j: self.held(j) for j in self.values_nm}
        self.lookups = {j: (_Lookup(self.settings, *self._held[j])
                            if np.any(v) or np.any(self.speed_nm[j]) or np.any(self.ripple[j]) else None)
                        for j, v in self.values_nm.items()}

    def held(self, joint: str) -> tuple[Array, Array, Array, Array]:
        """The applied values, speed coefficients, reference speed terms and ripple of ``joint`` as looked up: a
        cell without samples next to one with samples (the temperature bin beside it, same direction) holds its
        neighbour's (the mean of both neighbours when both have samples), so a temperature between a learned bin's
        centre and an empty neighbour's reads the learned value; one bin further the correction tapers to 0 over a
        bin. (A plateau 3 °C off a bin centre would otherwise read 60 % of its cell.)"""
        s = self.settings
        nt, npos = s.n_temperature, s.n_position
        has = self.count[joint].reshape(2, nt, npos).sum(axis=2) > 0
        out = [a.reshape(2, nt, -1).copy() for a in (self.values_nm[joint], self.speed_nm[joint],
                                                    self.speed_ref[joint], self.ripple[joint])]
        if has.any():
            left = np.zeros((2, nt), dtype=bool)
            right = np.zeros((2, nt), dtype=bool)
            left[:, 1:], right[:, :-1] = has[:, :-1], has[:, 1:]
            fill = ~has & (left | right)
            weight_left = np.where(left & right, 0.5, np.where(left, 1.0, 0.0))[..., None]
            for a in out:
                from_left = np.zeros(a.shape)
                from_right = np.zeros(a.shape)
                from_left[:, 1:], from_right[:, :-1] = a[:, :-1], a[:, 1:]
                a[fill] = (weight_left * from_left + (1.0 - weight_left) * from_right)[fill]
        values, speed, ref, ripple = (a.ravel() for a in out)
        return values, speed, ref, ripple

    # ------------------------------------------------------------------ lookup (the feedforward's hot path)
    def along_nm(self, joint: str, temperature_c: float, velocity_rad_s: float, position_rad: float,
                 model_nm: float) -> float:
        """Correction along the motion [N·m] for motion at ``velocity_rad_s`` [rad/s] (``>= 0``: cw) at
        ``temperature_c`` [°C] and reference position ``position_rad`` [rad] (NaN: the position map is skipped),
        for the model friction ``model_nm`` [N·m], bounded by ``max_relative`` × ``|model_nm|`` + ``floor_nm``: the
        cell's value and speed term interpolated in temperature, plus the relative ripple at the position ×
        ``|model_nm|``. Add it to the model magnitude before the smooth sign. Exactly 0.0 for a joint without a
        learned value; unknown joint: KeyError."""
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
        cw = velocity_rad_s >= 0.0
        vals = lut.cw if cw else lut.ccw
        a = vals[i]
        c = a + w * (vals[i + 1] - a)
        slopes = lut.sl_cw if cw else lut.sl_ccw
        if slopes is not None:  # the speed term, its coefficient interpolated the same way
            a = slopes[i]
            c += (a + w * (slopes[i + 1] - a)) * speed_term(self.settings, velocity_rad_s, SCALAR)
        m = abs(model_nm)
        ripple = lut.rp_cw if cw else lut.rp_ccw
        if ripple is not None:
            npos = lut.npos
            y = (position_rad * lut.scale) % npos - 0.5
            if y == y:  # (a NaN position: no ripple)
                if y < 0.0:
                    y += npos
                j = int(y)
                u = y - j
                j1 = j + 1 if j + 1 < npos else 0
                r0 = i * npos
                a = ripple[r0 + j]
                a += u * (ripple[r0 + j1] - a)
                r0 += npos
                b = ripple[r0 + j]
                c += (a + w * (b + u * (ripple[r0 + j1] - b) - a)) * m
        bound = lut.rel * m + lut.floor
        if -bound <= c <= bound:
            return c
        self.lookup_saturations += 1
        return bound if c > 0.0 else -bound

    def along_nm_array(self, joint: str, temperature_c: ArrayLike, velocity_rad_s: ArrayLike, position_rad: ArrayLike,
                       model_nm: ArrayLike) -> Array:
        """:meth:`along_nm` on arrays (a whole bag, the loop study): the same operations in the same order, so the
        same numbers (tested); clipped lookups are counted the same way. Units as :meth:`along_nm`."""
        t, v, p, m = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (temperature_c, velocity_rad_s,
                                                                               position_rad, model_nm)))
        lut = self.lookups[joint]
        if lut is None:
            return np.zeros(t.shape)
        s = self.settings
        nt = s.n_temperature
        x = (t - lut.t0) * lut.inv_bin
        inside = (x > 0.0) & (x < lut.hi)
        i = np.where(inside, np.trunc(np.where(inside, x, 0.0)), np.where(x > 0.0, lut.hi - 1, 0)).astype(np.int64)
        w = np.where(inside, x - i, np.where(x > 0.0, 1.0, 0.0))
        d = np.where(v >= 0.0, 0, 1)
        held_values, held_speed, held_ref, held_ripple = self._held[joint]
        vals = (held_values - held_speed * held_ref).reshape(2, nt)
        a = vals[d, i]
        c = a + w * (vals[d, i + 1] - a)
        if lut.sl_cw is not None:
            sl = held_speed.reshape(2, nt)
            a = sl[d, i]
            c = c + (a + w * (sl[d, i + 1] - a)) * speed_term(s, v, ARRAY)
        m = np.abs(m)
        if lut.rp_cw is not None:
            npos = lut.npos
            rp = held_ripple.reshape(2, nt, npos)
            with np.errstate(invalid='ignore'):
                y = (p * lut.scale) % npos - 0.5
            mapped = ~np.isnan(y)
            y = np.where(mapped, np.where(y < 0.0, y + npos, y), 0.0)
            j = y.astype(np.int64)
            u = y - j
            j1 = np.where(j + 1 < npos, j + 1, 0)
            a = rp[d, i, j]
            a = a + u * (rp[d, i, j1] - a)
            b = rp[d, i + 1, j]
            c = np.where(mapped, c + (a + w * (b + u * (rp[d, i + 1, j1] - b) - a)) * m, c)
        bound = lut.rel * m + lut.floor
        clipped = ~((-bound <= c) & (c <= bound))
        self.lookup_saturations += int(np.count_nonzero(clipped))
        return np.asarray(np.where(clipped, np.where(c > 0.0, bound, -bound), c), dtype=np.float64)

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
        vv = v.ravel()[ok]
        node, cell, along, mabs = cell_of(s, t.ravel()[ok], vv, p.ravel()[ok], r.ravel()[ok], m.ravel()[ok], ARRAY)
        x = speed_term(s, vv, ARRAY)
        nn, nc = self.count[joint].size, self.sum_sq_nm2[joint].size
        self.count[joint] += np.bincount(node, minlength=nn)
        for name, weights in (('sum_nm', along), ('sum_speed', x), ('sum_speed_sq', x * x),
                              ('sum_speed_res_nm', x * along), ('sum_model_nm', mabs)):
            getattr(self, name)[joint] += np.bincount(node, weights=weights, minlength=nn)
        self.sum_sq_nm2[joint] += np.bincount(cell, weights=along * along, minlength=nc)
        return {REASONS[k]: int(n) for k, n in enumerate(np.bincount(code, minlength=len(REASONS))) if k and n}

    def _add_one(self, joint: str, t_c: float, v: float, p: float, r: float, m: float, fresh: bool) -> str | None:
        """:meth:`add_residuals` for one sample (the same rules on floats); the reason if refused."""
        s = self.settings
        code = gate_code(s, t_c, v, p, r, m, fresh, SCALAR)
        if code:
            return REASONS[code]
        node, cell, along, mabs = cell_of(s, t_c, v, p, r, m, SCALAR)
        x = speed_term(s, v, SCALAR)
        self.count[joint][node] += 1
        self.sum_nm[joint][node] += along
        self.sum_speed[joint][node] += x
        self.sum_speed_sq[joint][node] += x * x
        self.sum_speed_res_nm[joint][node] += x * along
        self.sum_model_nm[joint][node] += mabs
        self.sum_sq_nm2[joint][cell] += along * along
        return None

    def targets(self, joint: str) -> tuple[Array, NDArray[np.bool_]]:
        """The learned (shrunk, bounded) value of every cell [N·m] at its mean speed term and whether each cell
        saturated (:meth:`fit`)."""
        f = self.fit(joint)
        return f.values_nm, f.saturated

    def fit(self, joint: str) -> LearnedFit:
        r"""What the sums of ``joint`` say (:class:`LearnedFit`), per cell (direction × temperature bin):

        - the speed coefficient b [N·m] of the residual r on the speed term x (:func:`speed_term`), from the
          variation of x *within* each position bin (so a ripple met at the slow end of a motion is not taken for
          speed), ridge-shrunk with ``prior_samples`` n0 and ``speed_prior_spread`` ρ; 0 unless ``speed_term``:

          .. math:: b = \frac{\sum_{bins} \sum (x - \bar x_{bin})(r - \bar r_{bin})}
                             {\sum_{bins} \sum (x - \bar x_{bin})^2 + n_0 (\rho \bar x)^2}

          (a cell learned at one speed keeps b near 0: its value holds at every speed);
        - the value at the cell's mean speed term x̄ [N·m]: the mean residual shrunk towards 0,
          ``S / (n + n0)``, bounded by ``max_relative`` × the cell's mean ``|model|`` + ``floor_nm``;
        - with a position map, the relative ripple of each position bin [-]: the bin's residual left after the value
          and the speed term, over its ``Σ|model|`` (with n0 prior samples at the cell's mean ``|model|``),
          smoothed to ``harmonics`` Fourier harmonics; bounded by ``max_relative``. Relative, because a race's
          ripple scales with the friction it modulates (a map learned at one speed holds at another).
        """
        s = self.settings
        nc, npos, n0 = 2 * s.n_temperature, s.n_position, s.prior_samples
        n = self.count[joint].reshape(nc, npos).astype(float)
        total = self.sum_nm[joint].reshape(nc, npos)
        xs = self.sum_speed[joint].reshape(nc, npos)
        ms = self.sum_model_nm[joint].reshape(nc, npos)
        n_cell, s_cell = n.sum(axis=1), total.sum(axis=1)
        have = n_cell > 0
        mean = np.divide(s_cell, n_cell, out=np.zeros(nc), where=have)
        x_bar = np.divide(xs.sum(axis=1), n_cell, out=np.zeros(nc), where=have)
        m_bar = np.divide(ms.sum(axis=1), n_cell, out=np.zeros(nc), where=have)
        b = np.zeros(nc)
        if s.speed_term:
            inv_n = np.divide(1.0, n, out=np.zeros(n.shape), where=n > 0)
            sxx = np.maximum((self.sum_speed_sq[joint].reshape(nc, npos) - xs * xs * inv_n).sum(axis=1), 0.0)
            sxy = (self.sum_speed_res_nm[joint].reshape(nc, npos) - xs * total * inv_n).sum(axis=1)
            den = sxx + n0 * (s.speed_prior_spread * x_bar) ** 2
            b = np.divide(sxy, den, out=np.zeros(nc), where=have & (den > 0.0))
        value = s_cell / (n_cell + n0)
        bound = s.max_relative * m_bar + s.floor_nm
        ripple = np.zeros((nc, npos))
        if s.position_bins:
            left = total - n * mean[:, None] - b[:, None] * (xs - n * x_bar[:, None])   # after value and speed term
            den_m = ms + n0 * m_bar[:, None]
            raw = np.divide(left, den_m, out=np.zeros(left.shape), where=den_m > 0.0)
            ripple = np.clip(raw @ self._smooth, -s.max_relative, s.max_relative)
        return LearnedFit(np.clip(value, -bound, bound), b, x_bar, ripple.ravel(), m_bar,
                          (np.abs(value) > bound) & have)

    def settle(self) -> None:
        """Apply the learned values at once (batch learning; the :class:`Learner` moves them at a limited rate)."""
        for j in self.values_nm:
            f = self.fit(j)
            self.values_nm[j], self.speed_nm[j], self.speed_ref[j], self.ripple[j] = (f.values_nm, f.speed_nm,
                                                                                      f.speed_mean, f.ripple)
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
        node = {name: getattr(self, name)[joint].reshape(2 * nt, npos) for name in (
            'count', 'sum_nm', 'sum_speed', 'sum_speed_sq', 'sum_speed_res_nm', 'sum_model_nm', 'ripple')}
        n = node['count']
        out = []
        for c in np.flatnonzero(n.sum(axis=1)).tolist():
            k, b = int(n[c].sum()), c % nt
            total = float(node['sum_nm'][c].sum())
            mean = total / k
            var = (float(self.sum_sq_nm2[joint][c]) - k * mean * mean) / (k - 1) if k > 1 else math.nan
            rec = {'direction': DIRECTIONS[c // nt], 'bin': b, 'centre_c': s.temperature_min_c + (b + 0.5) *
                   s.temperature_bin_c, 'value_nm': float(self.values_nm[joint][c]),
                   'speed_nm': float(self.speed_nm[joint][c]), 'speed_ref': float(self.speed_ref[joint][c]),
                   'samples': k, 'sum_nm': total, 'mean_nm': mean,
                   'std_error_nm': math.sqrt(max(var, 0.0) / k) if k > 1 else None,
                   'sum_sq_nm2': float(self.sum_sq_nm2[joint][c]),
                   'sum_abs_model_nm': float(node['sum_model_nm'][c].sum()),
                   'sum_speed': float(node['sum_speed'][c].sum()), 'sum_speed_sq': float(node['sum_speed_sq'][c].sum()),
                   'sum_speed_residual_nm': float(node['sum_speed_res_nm'][c].sum()),
                   'saturated': bool(sat[c])}
            if s.position_bins:
                rp = node['ripple'][c]
                rec |= {'ripple_relative': rp.tolist(), 'position_samples': n[c].tolist(),
                        'position_sums_nm': node['sum_nm'][c].tolist(),
                        'position_speed_sums': node['sum_speed'][c].tolist(),
                        'position_speed_sq_sums': node['sum_speed_sq'][c].tolist(),
                        'position_speed_residual_sums_nm': node['sum_speed_res_nm'][c].tolist(),
                        'position_model_sums_nm': node['sum_model_nm'][c].tolist(),
                        'harmonics_cos': (self._cos @ rp * 2.0 / npos).tolist(),
                        'harmonics_sin': (self._sin @ rp * 2.0 / npos).tolist()}
            out.append(rec)
        return out

    def summary(self) -> dict[str, Any]:
        """Cells with data, samples, largest |value| [N·m], largest |speed coefficient| [N·m], largest |relative
        ripple| [-] and saturated cells, per joint and in total."""
        joints = {}
        for j in self.identity.joints:
            n_cell = self.count[j].reshape(2 * self.settings.n_temperature, -1).sum(axis=1)
            joints[j] = {'cells_with_data': int(np.count_nonzero(n_cell)), 'samples': int(n_cell.sum()),
                         'max_abs_correction_nm': float(np.abs(self.values_nm[j]).max()),
                         'max_abs_speed_nm': float(np.abs(self.speed_nm[j]).max()),
                         'max_abs_ripple': float(np.abs(self.ripple[j]).max()),
                         'saturated_cells': int(np.count_nonzero(self.targets(j)[1]))}
        out: dict[str, Any] = {k: sum(d[k] for d in joints.values()) for k in ('cells_with_data', 'samples',
                                                                              'saturated_cells')}
        for k in ('max_abs_correction_nm', 'max_abs_speed_nm', 'max_abs_ripple'):
            out[k] = max(d[k] for d in joints.values())
        return {**out, 'lookup_saturations': self.lookup_saturations, 'joints': joints}

    # ------------------------------------------------------------------ file
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
    at every :meth:`update`, its applied values every ``step_period_s`` (and at :meth:`step`), a cell once its
    temperature bin has samples in both directions, each node moving towards its learned value by at most
    ``max_rate_nm_per_min`` per minute (the step's time is capped at
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
        npos, nt = c.settings.n_position, c.settings.n_temperature
        changed = False
        for j, values in c.values_nm.items():
            f = c.fit(j)
            coef, ref, ripple = c.speed_nm[j], c.speed_ref[j], c.ripple[j]
            # a cell moves once its temperature bin has samples in both directions: learned one direction at a time,
            # a direction-independent torque (an unbalance, a cable) would be compensated in one direction only and
            # kick the rate loop's integrator at every reversal
            has = c.count[j].reshape(2, nt, npos).sum(axis=2) > 0
            paired = np.tile(has[0] & has[1], 2)
            f = f._replace(values_nm=np.where(paired, f.values_nm, values), speed_nm=np.where(paired, f.speed_nm, coef),
                           ripple=np.where(np.repeat(paired, npos), f.ripple, ripple))
            # the applied values move to the new mean speed term with the applied correction unchanged, then all
            # move towards the learned ones: a value by at most ``limit``, the speed coefficient by at most ``limit``
            # per unit of the mean speed term and the relative ripple by at most ``limit`` per mean |model| (so the
            # correction changes by about ``limit`` at the speeds seen)
            new_ref = np.where(f.speed_mean > 0.0, f.speed_mean, ref)
            moved = values + coef * (new_ref - ref)
            new = moved + np.clip(f.values_nm - moved, -limit, limit)
            coef_limit = limit / np.maximum(new_ref, 1e-3)
            new_coef = coef + np.clip(f.speed_nm - coef, -coef_limit, coef_limit)
            ripple_limit = np.repeat(limit / np.maximum(f.model_mean_nm, c.settings.floor_nm + 1e-9), npos)
            new_ripple = ripple + np.clip(f.ripple - ripple, -ripple_limit, ripple_limit)
            if not (np.array_equal(new, values) and np.array_equal(new_coef, coef)
                    and np.array_equal(new_ripple, ripple)):
                c.values_nm[j], c.speed_nm[j], c.speed_ref[j], c.ripple[j] = new, new_coef, new_ref, new_ripple
                changed = True
        if changed:
            c.rebuild()
        return changed

    def freeze(self, frozen: bool = True) -> None:
        """Stop (or, with False, resume) learning; the applied correction stays as it is."""
        self.frozen = frozen

    def reset(self) -> None:
        """Back to the pure model at once: an empty correction (the counters of refused samples stay)."""
        c = self.correction
        for name in Correction.STATE:
            for a in getattr(c, name).values():
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
