r"""A dynamic (pre-sliding) feedforward term: a Dahl state instead of the smooth sign, learned and guarded per
temperature bin (pure numpy; no rclpy, no I/O).

One job in one module: the state update, the torque rule that reads it, the identification of its parameter from
friction samples around reversals and the guard that decides where it is applied (they share one parameter, the
pre-sliding distance per temperature bin, and must change together).

**The term.** The static feedforward (:mod:`gimbal_friction.feedforward.rule`) switches the friction's sign with the
velocity, ``τ = clamp(tanh(v/v_th) (k_d M + c_odd) + c_even, ±τ_max)``: a function of the present velocity. A real
contact does not switch with the velocity but with the *displacement*: after a reversal the bristles (LuGre) or the
elasto-slide elements (GMS) load like a spring until they slide, and a velocity that dithers around zero at a
reversal (the loop's own chatter) moves the contact by micro-radians, not across its whole pre-sliding range. The
dynamic term replaces the smooth sign by a normalised Dahl state ``s ∈ [−1, 1]`` per joint,

.. math::

    \frac{ds}{dt} = \frac{u - |u|\, s}{\delta(T)}, \qquad
    \tau = \operatorname{clamp}\big(s\, (k_d M + c_{odd}) + c_{even},\ \pm\tau_{max}\big)

driven by the velocity the feedforward uses ``u`` [rad/s] (the reference joint velocity while fresh, else the
measured one: the node's ``velocity_source``), with ``δ(T)`` [rad] the pre-sliding distance of the temperature bin
(Dahl 1968 with exponent 1, in the normalised form: the torque after a reversal from −L rises as
``L (1 − 2 e^{−x/δ})`` over the displacement ``x`` since the reversal, initial stiffness ``2 L/δ``, and settles at
the static level ``L`` once ``x ≫ δ``). With ``u`` held over a step ``h`` the update is exact
(:func:`dahl_step`): ``s ← sgn u + (s − sgn u) e^{−|u| h/δ}``, unconditionally stable and never outside [−1, 1].
Away from reversals ``s = sgn u`` and the torque is the static feedforward's (``tanh`` is 1 there too).

**Identification** (:meth:`PreslidingTerm.learn`). From friction samples that the estimator takes through reversals
(Eq. 23: K_T I − J α̂, the measured friction signed like the motion) on the ticks of a motion with the feedforward's
velocity, level and temperature known at every tick (:class:`ReversalRun`): for every distance of a log grid
(:attr:`PreslidingSettings.grid_rad`) the Dahl state is run over the whole motion and its torque ``s L + c_even``
compared with the samples near reversals (where the static sign or the slowest candidate has not settled); the sum
of squared differences is kept per temperature bin, per candidate and for the static rule ``tanh(u/v_th) L +
c_even``. The distance of a bin is the candidate of least sum (the least-squares fit on the grid, refined by a
parabola through its neighbours in log δ). Nothing of a simulator's truth enters: the samples, the velocity and the
feedforward's own level.

**Guard** (test, then train; the static correction's rule, :mod:`gimbal_friction.feedforward.correction.core`): the
samples are taken reversal by reversal in time order; each reversal is first scored by the distance fitted from the
reversals *before* it (its squared error against the static rule's), then learned. A bin is applied only when at
least ``min_reversals`` reversals scored it and their mean cut of the squared error is ``guard_z`` standard errors
above 0 (reversals are the blocks: the samples of one reversal are not independent; each reversal's gain is
``(E_static − E_dynamic)/(E_static + E_dynamic)`` ∈ [−1, 1] of its squared errors, so a long hold does not outweigh
every reversal) and the squared error summed over them is lower with the term. Elsewhere the term is off: the
torque is exactly today's static feedforward.

References (equations in docs/model.md, "Pre-sliding feedforward"):

- P. R. Dahl, "A solid friction model", The Aerospace Corporation, TOR-0158(3107-18)-1, 1968.
- C. Canudas de Wit, H. Olsson, K. J. Åström, P. Lischinsky, "A new model for control of systems with friction",
  IEEE Trans. Automatic Control 40(3), 419–425, 1995 (LuGre: the same state with a speed-dependent level).
- F. Al-Bender, V. Lampaert, J. Swevers, "The generalized Maxwell-slip model: a novel model for friction simulation
  and compensation", IEEE Trans. Automatic Control 50(11), 1883–1887, 2005 (several elements: a hysteresis the one
  Dahl state approximates).

Units: torque [N·m], angle [rad], velocity [rad/s], time [s], temperature [°C].
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import ConfigError, check_rules
from gimbal_friction.common.settings import setting

__all__ = ['PreslidingSettings', 'PreslidingTerm', 'ReversalRun', 'dahl_step', 'dahl_step_scalar',
           'presliding_torque_nm']

Array = NDArray[np.float64]
#: near-reversal runs of ticks less than this apart are one reversal [-]
MERGE_TICKS = 20
#: a reversal scores the guard with at least this many samples [-]
MIN_EVENT_SAMPLES = 5


@dataclass(frozen=True)
class PreslidingSettings:
    """Layout, grid and guard of a pre-sliding term (units in the names)."""

    temperature_min_c: float = setting(-62.5, 'degC', 'lower edge of the first temperature bin')
    temperature_max_c: float = setting(122.5, 'degC', 'upper edge of the last temperature bin')
    temperature_bin_c: float = setting(5.0, 'degC', "width of a temperature bin (the correction's)")
    distance_min_rad: float = setting(1e-6, 'rad', 'shortest pre-sliding distance delta tried')
    distance_max_rad: float = setting(2e-4, 'rad', 'longest pre-sliding distance delta tried')
    distance_steps: int = setting(24, '-', 'distances tried, log-spaced between the two')
    min_reversals: int = setting(6, '-', 'a bin is applied once this many reversals scored it out of sample')
    guard_z: float = setting(3.0, '-', 'a bin is applied where its mean cut of the squared error over reversals is '
                             'this many standard errors above 0')
    max_step_s: float = setting(0.05, 's', 'a gap between updates longer than this restarts the state at the static '
                                'sign')
    velocity_threshold_rad_s: float = setting(0.002, 'rad/s', "the static rule's v_th the term is judged against "
                                              "(the feedforward's velocity_threshold_rad_s)")
    delivery_delay_s: float = setting(0.0, 's', 'time from the inputs of a torque to its application (the '
                                      "feedforward's transport latency): a torque is judged against the friction "
                                      'this much later')

    @property
    def n_temperature(self) -> int:
        """Number of temperature bins [-]."""
        return int(round((self.temperature_max_c - self.temperature_min_c) / self.temperature_bin_c))

    @property
    def grid_rad(self) -> Array:
        """The pre-sliding distances tried [rad], log-spaced."""
        return np.geomspace(self.distance_min_rad, self.distance_max_rad, self.distance_steps)

    def bin_of(self, temperature_c: ArrayLike) -> NDArray[np.int64]:
        """Temperature bin of temperatures [°C] (clamped to the first and last)."""
        t = np.asarray(temperature_c, dtype=float)
        b = np.floor((np.where(np.isfinite(t), t, self.temperature_min_c) - self.temperature_min_c)
                     / self.temperature_bin_c)
        return np.clip(b, 0, self.n_temperature - 1).astype(np.int64)

    def validate(self) -> None:
        """Raises ConfigError naming the setting and the rule it breaks."""
        span = (self.temperature_max_c - self.temperature_min_c) / self.temperature_bin_c \
            if self.temperature_bin_c > 0.0 else 0.0
        check_rules(self, [
            ('temperature_bin_c', self.temperature_bin_c > 0.0, 'must be > 0 [degC]'),
            ('temperature_max_c', 2 <= round(span) <= 10000 and abs(span - round(span)) < 1e-6,
             'must exceed temperature_min_c by 2 to 10000 whole temperature_bin_c [degC]'),
            ('distance_min_rad', 1e-9 <= self.distance_min_rad <= 1e-2, 'must lie in [1e-9, 1e-2] [rad]'),
            ('distance_max_rad', self.distance_min_rad < self.distance_max_rad <= 1.0,
             'must lie in (distance_min_rad, 1] [rad]'),
            ('distance_steps', 3 <= self.distance_steps <= 200, 'must be an integer in [3, 200] [-]'),
            ('min_reversals', 2 <= self.min_reversals <= 10**6, 'must be an integer in [2, 1e6] [-]'),
            ('guard_z', 0.0 <= self.guard_z <= 100.0, 'must lie in [0, 100] [-]'),
            ('max_step_s', 0.0 < self.max_step_s <= 10.0, 'must lie in (0, 10] [s]'),
            ('velocity_threshold_rad_s', 1e-6 <= self.velocity_threshold_rad_s <= 10.0,
             'must lie in [1e-6, 10] [rad/s]'),
            ('delivery_delay_s', 0.0 <= self.delivery_delay_s <= 1.0, 'must lie in [0, 1] [s]'),
        ])


# ---------------------------------------------------------------------------------------------------- the state
def dahl_step(state: ArrayLike, velocity_rad_s: ArrayLike, step_s: ArrayLike, distance_rad: ArrayLike) -> Array:
    """The normalised Dahl state after a step ``step_s`` [s] with the velocity ``velocity_rad_s`` [rad/s] held, for
    the pre-sliding distance ``distance_rad`` [rad] (> 0): the exact solution of ``ds/dt = (u − |u| s)/δ``,
    ``s ← sgn u + (s − sgn u) e^{−|u| h/δ}`` [-] (at u = 0 the state is kept).

    >>> s = -1.0
    >>> for _ in range(10):                 # 10 µrad after a reversal, δ = 10 µrad: 1 − 2/e
    ...     s = dahl_step(s, 1e-3, 1e-3, 1e-5)
    >>> round(float(s), 6), round(1.0 - 2.0 / math.e, 6)
    (0.264241, 0.264241)
    """
    u = np.asarray(velocity_rad_s, dtype=float)
    sign = np.sign(u)
    decay = np.exp(-np.abs(u) * np.asarray(step_s, dtype=float) / np.asarray(distance_rad, dtype=float))
    return np.asarray(sign + (np.asarray(state, dtype=float) - sign) * decay)


def dahl_step_scalar(state: float, velocity_rad_s: float, step_s: float, distance_rad: float) -> float:
    """:func:`dahl_step` on floats (the in-process call; the same numbers)."""
    u = velocity_rad_s
    sign = 1.0 if u > 0.0 else (-1.0 if u < 0.0 else 0.0)
    return sign + (state - sign) * math.exp(-(u if u >= 0.0 else -u) * step_s / distance_rad)


def presliding_torque_nm(state: ArrayLike, level_nm: ArrayLike, even_nm: ArrayLike, max_torque_nm: float) -> Array:
    """``clamp(s L + c_even, ±τ_max)`` [N·m]: the feedforward torque with the Dahl state ``state`` [-] in place of
    the smooth sign, ``level_nm`` = k_d M + c_odd [N·m] the static level along the motion, ``even_nm`` the part
    independent of the direction [N·m]."""
    return np.asarray(np.clip(np.asarray(state, dtype=float) * np.asarray(level_nm, dtype=float)
                              + np.asarray(even_nm, dtype=float), -max_torque_nm, max_torque_nm))


# ---------------------------------------------------------------------------------------------------- learning
class ReversalRun(NamedTuple):
    """One continuous motion at the feedforward's rate, every array of shape (ticks,), in time order."""

    time_s: Array          #: time of each tick [s]
    velocity_rad_s: Array  #: the velocity the feedforward uses (reference while fresh, else measured) [rad/s]
    temperature_c: Array   #: temperature the feedforward uses [°C] (NaN: none, the tick is not learned)
    level_nm: Array        #: static level along the motion k_d M + c_odd [N·m] (>= 0)
    even_nm: Array         #: the part independent of the direction c_even [N·m]
    friction_nm: Array     #: the estimator's friction sample of the tick, signed like the motion [N·m] (NaN: none)


class PreslidingTerm:
    """The pre-sliding term of the joints ``joints``: per joint and temperature bin a fitted distance and the guard's
    sums (see the module notes). ConfigError: invalid settings, no joint."""

    def __init__(self, settings: PreslidingSettings, joints: Sequence[str]) -> None:
        settings.validate()
        if not joints:
            raise ConfigError('joints', 'a pre-sliding term needs at least one joint')
        self.settings = settings
        self.joints = tuple(joints)
        nt, k = settings.n_temperature, settings.distance_steps
        #: per joint: Σ squared error of each candidate per bin (bins, candidates) [N²·m²]
        self._sse = {j: np.zeros((nt, k)) for j in self.joints}
        #: per joint: Σ squared error of the static rule per bin [N²·m²]
        self._sse_static = {j: np.zeros(nt) for j in self.joints}
        #: per joint: the guard's sums per bin: reversals scored, Σg, Σg², Σd (per reversal scored out of sample,
        #: d = the static rule's squared error − the candidate's [N²·m²], g = d / their sum [-], in [−1, 1])
        self._guard = {j: np.zeros((nt, 4)) for j in self.joints}
        #: per joint: samples learned per bin [-]
        self._samples = {j: np.zeros(nt) for j in self.joints}
        #: per joint: the applied distance per bin [rad] (NaN: off)
        self.distances: dict[str, Array] = {j: np.full(nt, np.nan) for j in self.joints}

    def _check(self, joint: str) -> None:
        if joint not in self._sse:
            raise ConfigError('joint', f'not in this pre-sliding term ({", ".join(self.joints)})', joint)

    # ------------------------------------------------------------------ lookup
    def distance_rad(self, joint: str, temperature_c: ArrayLike) -> Array:
        """The applied distance [rad] at temperatures [°C] (NaN: the term is off there, the static sign)."""
        return np.asarray(self.distances[joint][self.settings.bin_of(temperature_c)])

    @property
    def active(self) -> bool:
        """Any bin of any joint applied."""
        return any(bool(np.isfinite(d).any()) for d in self.distances.values())

    # ------------------------------------------------------------------ fit
    def fitted_rad(self, joint: str) -> Array:
        """The least-squares distance per bin from everything learned [rad] (NaN: no samples)."""
        self._check(joint)
        sse = self._sse[joint]
        grid = np.log(self.settings.grid_rad)
        out = np.full(sse.shape[0], np.nan)
        for b in np.flatnonzero(self._samples[joint] > 0):
            out[b] = math.exp(_parabola_min(grid, sse[b]))
        return out

    def _candidate_index(self, joint: str) -> NDArray[np.int64]:
        return np.asarray(np.argmin(self._sse[joint], axis=1), dtype=np.int64)

    def learn(self, joint: str, runs: Sequence[ReversalRun]) -> dict[str, int]:
        """Test, then train, reversal by reversal in time order over ``runs`` (see the module notes), then apply the
        bins the guard lets through. Returns counts: ``ticks``, ``samples`` (near reversals), ``reversals``."""
        self._check(joint)
        s = self.settings
        grid = s.grid_rad
        counts = {'ticks': 0, 'samples': 0, 'reversals': 0}
        for run in runs:
            counts['ticks'] += int(run.time_s.size)
            run = _delayed(run, s.delivery_delay_s)
            states = _dahl_states(run, grid, s)
            static = np.tanh(run.velocity_rad_s / s.velocity_threshold_rad_s)
            near = _near_reversal(run.velocity_rad_s, static, states[:, -1])
            ok = near & np.isfinite(run.friction_nm) & np.isfinite(run.temperature_c) & \
                np.isfinite(run.level_nm) & np.isfinite(run.even_nm)
            events = _events(near, run.velocity_rad_s)
            bins = s.bin_of(run.temperature_c)
            for start, stop in events:
                sel = np.flatnonzero(ok[start:stop]) + start
                if sel.size == 0:
                    continue
                f = run.friction_nm[sel]
                lev = run.level_nm[sel]
                even = run.even_nm[sel]
                e_cand = ((states[sel] * lev[:, None] + even[:, None]) - f[:, None]) ** 2   # (samples, candidates)
                e_static = (static[sel] * lev + even - f) ** 2
                b_all = bins[sel]
                for b in np.unique(b_all):
                    mine = b_all == b
                    # test: the candidate fitted from the reversals before this one
                    if self._samples[joint][b] > 0 and mine.sum() >= MIN_EVENT_SAMPLES:
                        k = int(self._candidate_index(joint)[b])
                        e_s, e_d = float(e_static[mine].sum()), float(e_cand[mine, k].sum())
                        gain = (e_s - e_d) / (e_s + e_d) if e_s + e_d > 0.0 else 0.0
                        self._guard[joint][b] += (1.0, gain, gain * gain, e_s - e_d)
                    # train
                    self._sse[joint][b] += e_cand[mine].sum(axis=0)
                    self._sse_static[joint][b] += float(e_static[mine].sum())
                    self._samples[joint][b] += float(mine.sum())
                counts['samples'] += int(sel.size)
                counts['reversals'] += 1
        self.apply(joint)
        return counts

    def verdicts(self, joint: str) -> list[dict[str, Any]]:
        """Per bin with samples: ``bin``, ``centre_c``, ``samples``, ``reversals_scored``, ``z``, ``distance_rad``
        (fitted), ``rms_static_nm``, ``rms_dynamic_nm`` (in sample, at the fitted distance), ``applied``,
        ``held_back`` (why not, empty when applied)."""
        self._check(joint)
        s = self.settings
        fitted = self.fitted_rad(joint)
        idx = self._candidate_index(joint)
        out = []
        for b in np.flatnonzero(self._samples[joint] > 0).tolist():
            n_rev, sg, sgg, sd = (float(x) for x in self._guard[joint][b])
            z = _z(n_rev, sg, sgg)
            n = float(self._samples[joint][b])
            if n_rev < s.min_reversals:
                reason = f'scored by {n_rev:.0f} of {s.min_reversals} reversals'
            elif not z >= s.guard_z:
                reason = f'its gain over reversals is {z:.1f} standard errors, needs {s.guard_z:g}'
            elif not sd > 0.0:
                reason = 'it adds to the squared error summed over the reversals scored'
            else:
                reason = ''
            out.append({'bin': b, 'centre_c': s.temperature_min_c + (b + 0.5) * s.temperature_bin_c,
                        'samples': int(n), 'reversals_scored': int(n_rev), 'z': z,
                        'mean_gain': sg / n_rev if n_rev > 0 else math.nan,
                        'cut_nm2': sd,
                        'distance_rad': float(fitted[b]),
                        'rms_static_nm': math.sqrt(self._sse_static[joint][b] / n),
                        'rms_dynamic_nm': math.sqrt(self._sse[joint][b, idx[b]] / n),
                        'applied': not reason, 'held_back': reason})
        return out

    def apply(self, joint: str) -> None:
        """Apply the fitted distance in the bins the guard lets through; the others off."""
        d = np.full(self.settings.n_temperature, np.nan)
        fitted = self.fitted_rad(joint)
        for v in self.verdicts(joint):
            if v['applied']:
                d[v['bin']] = fitted[v['bin']]
        self.distances[joint] = d

    def unguarded(self) -> PreslidingTerm:
        """A copy with the fitted distance applied in every bin with samples, whatever the guard says (to measure
        what the guard holds back; not for service)."""
        out = copy.deepcopy(self)
        for j in out.joints:
            out.distances[j] = out.fitted_rad(j)
        return out

    def summary(self) -> dict[str, Any]:
        """Per joint: bins with samples, applied, held back, and the verdicts."""
        joints = {}
        for j in self.joints:
            ver = self.verdicts(j)
            joints[j] = {'bins_with_data': len(ver), 'bins_applied': sum(v['applied'] for v in ver),
                         'bins_held_back': sum(not v['applied'] for v in ver), 'bins': ver}
        return {'bins_applied': sum(d['bins_applied'] for d in joints.values()),
                'bins_held_back': sum(d['bins_held_back'] for d in joints.values()), 'joints': joints}


def _z(n: float, sd: float, sdd: float) -> float:
    """Mean of per-reversal gains over its standard error [-] (0 with fewer than two)."""
    if n < 2.0:
        return 0.0
    mean = sd / n
    var = max((sdd - n * mean * mean) / (n - 1.0), 0.0)
    if var <= 0.0:
        return math.inf if mean > 0.0 else 0.0
    return mean / math.sqrt(var / n)


def _parabola_min(x: Array, y: Array) -> float:
    """Where a parabola through the least ``y`` and its two neighbours on ``x`` is least (the end points held)."""
    k = int(np.argmin(y))
    if k == 0 or k == x.size - 1:
        return float(x[k])
    y0, y1, y2 = float(y[k - 1]), float(y[k]), float(y[k + 1])
    den = y0 - 2.0 * y1 + y2
    if den <= 0.0:
        return float(x[k])
    h = float(x[k + 1] - x[k])
    return float(x[k] + 0.5 * h * (y0 - y2) / den)


def _delayed(run: ReversalRun, delay_s: float) -> ReversalRun:
    """``run`` with each friction sample paired with the inputs ``delay_s`` [s] before it (the torque computed from
    them is applied that much later): the friction column moved back by the delay in whole ticks."""
    if delay_s <= 0.0 or run.time_s.size < 2:
        return run
    lag = int(round(delay_s / float(np.median(np.diff(run.time_s)))))
    if lag <= 0:
        return run
    friction = np.full(run.friction_nm.shape, np.nan)
    friction[:-lag] = run.friction_nm[lag:]
    return run._replace(friction_nm=friction)


def _dahl_states(run: ReversalRun, grid: Array, s: PreslidingSettings) -> Array:
    """The Dahl state of every candidate distance over a run, (ticks, candidates); starts (and restarts after a gap
    longer than ``max_step_s``) at the static sign."""
    u = np.asarray(run.velocity_rad_s, dtype=float)
    n = u.size
    out = np.empty((n, grid.size))
    if n == 0:
        return out
    dt = np.diff(run.time_s, prepend=run.time_s[0])
    static = np.tanh(u / s.velocity_threshold_rad_s)
    inv = 1.0 / grid
    state = np.full(grid.size, static[0])
    sign = np.sign(u)
    a = np.abs(u) * dt
    restart = (dt > s.max_step_s) | ~np.isfinite(u)
    for k in range(n):
        if restart[k]:
            state = np.full(grid.size, static[k] if math.isfinite(static[k]) else 0.0)
        else:
            sg = sign[k]
            state = sg + (state - sg) * np.exp(-a[k] * inv)
        out[k] = state
    return out


def _near_reversal(u: Array, static: Array, slowest: Array) -> NDArray[np.bool_]:
    """Ticks where the static sign or the slowest candidate has not settled at the sign of the motion."""
    sign = np.sign(u)
    return np.asarray((np.abs(static) < 0.999) | (np.abs(slowest - sign) > 1e-3))


def _events(near: NDArray[np.bool_], u: Array) -> list[tuple[int, int]]:
    """Runs of near-reversal ticks [start, stop), those less than :data:`MERGE_TICKS` apart merged (one per
    reversal: the sign dithering through a reversal is one event)."""
    if not near.any():
        return []
    x = np.concatenate([[False], near, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(x))
    out: list[tuple[int, int]] = []
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        if out and a - out[-1][1] < MERGE_TICKS:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out
