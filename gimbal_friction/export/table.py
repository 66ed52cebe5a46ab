"""The model as an interpolation table with a stated error bound, for a controller or drive firmware.

One job in one module: building the table and proving its error bound (the grid and its check share the model
evaluations).

Pure: builds the table from :func:`~gimbal_friction.physics.model.friction_torque` (the full model) and checks it
against the full model. :mod:`gimbal_friction.export.formats` renders it as text (CSV, a C99 header, a ROS parameter
YAML); ``gimbal-friction export`` (:mod:`gimbal_friction.cli.export_cmd`) writes the files.

The axis friction magnitude is ``M(t, n) = M_R(t) + M_S(t) + M_L(t, n)``: the contact torques depend on temperature
only, and Palmgren's viscous torque, Eq. (9) (Palmgren 1959), depends on speed only through the product ``ν(t) n``:

    M_L = 1e-7 s0 (ν n)^(2/3) d_m³   if ν n ≥ 2000,   else   160e-7 s0 d_m³   (per bearing, [N·mm], n [rpm]).

Two features make a plain (temperature, speed) grid a poor fit: a slope discontinuity in temperature (the loose-fit
temperature, 43.1 °C with the defaults) and a *jump* of Eq. (9) on the curve ``ν(t) n = 2000`` (its two branches
differ by 0.79 % there), which crosses the whole (t, n) plane. Linear interpolation across a jump cannot meet
1e-4, however fine the grid. So the table is laid out in the coordinates of Eq. (9):

* **temperature breakpoints** ``t_i`` (non-uniform): start every 5 °C plus the loose-fit kink as a breakpoint, then
  split every interval whose midpoint check fails, until all pass (see below);
* **switch speed** ``v*(t) = 2000/ν(t)`` [rpm → rad/s], the speed above which Eq. (9) takes its speed-dependent
  branch, stored as ``ln v*`` at each breakpoint and interpolated linearly in temperature (ln ν is much closer to
  linear in t than ν);
* **speed coordinate** ``η = (|v| / v*(t))^(2/3) = (ν n / 2000)^(2/3)``: Eq. (9) switches branch at η = 1 at every
  temperature, is constant in speed below (``torque_lower``, a table over temperature only: speed does not matter
  there) and linear in η above (``torque_upper``, breakpoints η = 1 and η_top, η_top = η at the largest speed and the
  coldest breakpoint). Linear interpolation in η is therefore exact along speed; all interpolation error comes from
  temperature, which is what the refinement controls.

Evaluation (the C function and :meth:`ExportTable.evaluate_nm` do exactly this)::

    t ← clamp(t, t_0, t_N-1);  s ← min(|v|, v_max)
    i: t_i ≤ t ≤ t_i+1;  w = (t − t_i)/(t_i+1 − t_i);  lerp(a) = a_i + w (a_i+1 − a_i)
    ξ = s · exp(−lerp(ln v*))
    M = lerp(torque_lower)                                        if ξ < 1 (or row i+1 has no upper values)
    M = lerp(torque_upper[:, 0]) + u (lerp(torque_upper[:, 1]) − lerp(torque_upper[:, 0])),
        u = (min(ξ^(2/3), η_top) − 1)/(η_top − 1)                 otherwise

The upper table has rows only up to the first breakpoint whose switch speed exceeds ``v_max``: above that
temperature the lubricant is thin enough that ν n < 2000 at every speed the table covers.

**Error check.** The relative error ``|table − model| / model`` against the full model is evaluated at the midpoint
of every temperature interval (speed 0; and, where the upper branch is reachable, just above the switch, at
``v_max`` and at the η-midpoint between), at the η-midpoint of every upper row, and at ``random_points`` seeded
random points (t uniform, |v| half uniform, half log-uniform over six decades, both signs). An interval whose
midpoint error, or whose switch-speed deviation ``|lerp(ln v*) − ln v*|`` at its midpoint, exceeds half the bound
is split into ``ceil(1.1 √(error / (bound/2)))`` equal parts (the error of linear interpolation scales with the
step squared); an interval holding a random point above the bound is split too. The grid is capped at
``max_breakpoints``; a bound that would need more is refused. Defaults: −40…60 °C (the model's validity range,
:mod:`gimbal_friction.physics.validity`: a table never reaches past it, and ``gimbal-friction export`` takes the
feedforward node's table range within it), |v| ≤ 10 rad/s (573 °/s, above the slew rates of seeker gimbals; faster is
clamped), bound 1e-4.

**Learned correction.** With a correction file (``export --correction``; :class:`TableCorrection`), every table also
carries the correction of its axis as the feedforward looks it up without a joint position: per temperature bin
centre and speed octave, its part along the motion ``odd = ½(S_cw + S_ccw)`` and its part independent of the
direction ``even = ½(S_cw − S_ccw)`` of the learned speed profiles S_d (after the lookup's hold rule), linear in
temperature between bin centres and in ``u = log2(|v|/min_speed)`` between octave centres, held beyond. The
feedforward adds it exactly as the node does: ``odd`` clamped to ±(max_relative |k_dir M| + floor), ``even`` to
±max(that, max_independent), ``τ = clamp(tanh(v/v_th) (k_dir M + odd) + even, ±τ_max)`` (:func:`correction_nm`, the
C function ``gf_<axis>_correction_split_nm``). Each cell (direction × bin) carries its samples and its error bound
(the standard error of its mean, shrunk like its value). The correction's terms in the joint angle (a ripple, a
trend) are not exported, and the files say so.

**Switch band.** The table decides the Palmgren branch with the interpolated switch speed, the model with the exact
one; they differ by at most ``switch_band`` (relative, ≤ half the bound by construction). Inside that band, i.e.
``|ν n/2000 − 1| ≲ switch_band``, the table may sit on the other branch of Eq. (9) and differ from the model by the
model's own jump (0.79 % of M_L). The report counts the random points that fell into it and their largest error;
everywhere else the bound holds.

>>> table = build_table('elevation', AxisParams(), FeedforwardSettings(), ExportOptions(random_points=2000))
>>> table.report.random_max_relative_error < 1e-4, table.report.midpoint_max_relative_error < 1e-4
(True, True)
>>> round(float(table.evaluate_nm(-40.0, rad_s_from_rpm(1.0 / 3.0))) * 1e3, 3)   # N*mm, paper: 3.14
3.143
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.errors import GimbalFrictionError, ModelDomainError, check_rules
from gimbal_friction.common.units import nm_from_nmm, rad_s_from_rpm, rpm_from_rad_s
from gimbal_friction.feedforward.correction import Correction, CorrectionSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.physics.friction import PALMGREN_THRESHOLD_CST_RPM
from gimbal_friction.physics.model import FrictionResult, friction_torque, palmgren_threshold_temperature, viscosity_cst
from gimbal_friction.physics.params import MODEL_T_MAX_C, MODEL_T_MIN_C, AxisParams
from gimbal_friction.physics.thermal import loose_fit_temperature
from gimbal_friction.physics.validity import VALID_T_MAX_C, VALID_T_MIN_C, validity_range

Array = NDArray[np.float64]

#: ν n at which Palmgren's Eq. (9) switches branch, [cSt·rpm] (:func:`~gimbal_friction.physics.friction.
#: viscous_torque_Palmgren_1959`; ``test_export.py`` checks the model switches exactly here)
PALMGREN_SWITCH_CST_RPM = PALMGREN_THRESHOLD_CST_RPM
#: relative jump of M_L where Eq. (9) switches branch: 160 / 2000^(2/3) − 1, [-]
PALMGREN_JUMP = 160.0 / PALMGREN_SWITCH_CST_RPM ** (2.0 / 3.0) - 1.0
#: default largest |velocity| of the table, [rad/s] (573 °/s: above the slew rates of seeker gimbals)
DEFAULT_MAX_SPEED_RAD_S = 10.0
#: default relative interpolation error bound, [-]
DEFAULT_RELATIVE_ERROR = 1e-4
#: the model's own numerical resolution is about 1e-12 (relative); a bound below this is not checkable
MIN_RELATIVE_ERROR = 1e-10
#: initial temperature step of the refinement, [°C]
INITIAL_STEP_C = 5.0
#: temperature breakpoints never closer than this, [°C]
MIN_STEP_C = 1e-6
#: refinement passes before giving up
MAX_PASSES = 60

Progress = Callable[[str], None]


@dataclasses.dataclass(frozen=True)
class ExportOptions:
    """What the table spans and how accurate it must be (options of ``gimbal-friction export``)."""

    temperature_min_c: float = VALID_T_MIN_C         #: lowest table temperature [°C] (within the validity range)
    temperature_max_c: float = VALID_T_MAX_C         #: highest table temperature [°C] (within the validity range)
    max_speed_rad_s: float = DEFAULT_MAX_SPEED_RAD_S  #: largest |velocity| of the table [rad/s]
    relative_error: float = DEFAULT_RELATIVE_ERROR   #: bound on |table − model| / model [-]
    random_points: int = 20000                       #: random check points [-]
    seed: int = 0                                    #: seed of the random check points
    max_breakpoints: int = 5000                      #: cap on the temperature breakpoints [-]

    def validate(self) -> None:
        """Raises ConfigError naming the option and the rule it breaks."""
        checks: list[tuple[str, bool, str]] = [
            ('temperature_min_c', self.temperature_min_c >= MODEL_T_MIN_C, f'must be >= {MODEL_T_MIN_C:g} [degC]'),
            ('temperature_max_c', self.temperature_max_c <= MODEL_T_MAX_C, f'must be <= {MODEL_T_MAX_C:g} [degC]'),
            ('temperature_max_c', self.temperature_max_c > self.temperature_min_c,
             'must exceed temperature_min_c [degC]'),
            ('max_speed_rad_s', 0.0 < self.max_speed_rad_s <= 1e4, 'must lie in (0, 1e4] [rad/s]'),
            ('relative_error', MIN_RELATIVE_ERROR <= self.relative_error <= 0.1,
             f'must lie in [{MIN_RELATIVE_ERROR:g}, 0.1] (the model resolves about 1e-12)'),
            ('random_points', 100 <= self.random_points <= 1_000_000, 'must lie in [100, 1000000]'),
            ('max_breakpoints', 3 <= self.max_breakpoints <= 100_000, 'must lie in [3, 100000]'),
        ]
        check_rules(self, checks)


class Provenance(NamedTuple):
    """Where a table came from, recorded in every file."""

    generator: str                          #: e.g. ``gimbal-friction export 0.1.0``
    created: str                            #: ISO 8601 date and time
    sources: tuple[tuple[str, str], ...]    #: (parameter file or ``packaged defaults``, SHA-256 of its bytes)


class ErrorReport(NamedTuple):
    """What the table achieved against the full model (relative errors ``|table − model| / model``)."""

    relative_error_bound: float            #: requested bound [-]
    temperatures: int                      #: temperature breakpoints [-]
    upper_rows: int                        #: breakpoints with upper-branch values (speed matters) [-]
    values: int                            #: numbers stored (all arrays) [-]
    passes: int                            #: refinement passes [-]
    midpoint_checks: int                   #: midpoint evaluations in the final check [-]
    midpoint_max_relative_error: float     #: largest error at the midpoints [-]
    midpoint_worst_temperature_c: float    #: where [°C]
    midpoint_worst_speed_rad_s: float      #: where [rad/s]
    random_points: int                     #: random points outside the switch band [-]
    random_max_relative_error: float       #: largest error at those [-]
    random_worst_temperature_c: float      #: where [°C]
    random_worst_speed_rad_s: float        #: where [rad/s]
    switch_band: float                     #: relative half-width of the Palmgren switch band [-]
    switch_band_points: int                #: random points inside it (other branch than the model) [-]
    switch_band_max_relative_error: float  #: largest error there (the model's own jump, ≤ 0.79 % of M_L) [-]
    speed_matters_below_c: float | None    #: ν n ≥ 2000 is reachable (|v| ≤ v_max) only below this [°C]
    loose_fit_c: float | None              #: loose-fit kink inside the range (a breakpoint) [°C]

    def as_dict(self) -> dict[str, float | int | None]:
        """Plain mapping (for JSON)."""
        return dict(self._asdict())


class TableGrid(NamedTuple):
    """The table's arrays (what the C header and the ROS file hold) and the model results at its nodes."""

    t: Array              #: breakpoints [°C], (N,)
    ln_vs: Array          #: ln of the switch speed v* [ln(rad/s)], (N,)
    lower_nm: Array       #: M on the speed-independent branch [N·m], (N,)
    eta: Array            #: η breakpoints of the upper table [-], (2,)
    upper_nm: Array       #: M on the speed-dependent branch [N·m], (K, 2)
    lower: FrictionResult     #: model at the breakpoints, speed 0
    upper: FrictionResult     #: model at the upper nodes, (K, 2)
    upper_speed_rad_s: Array  #: speeds of the upper nodes [rad/s], (K, 2)


class TableCorrection(NamedTuple):
    """The learned correction of one axis as exported: its lookup without a position, split as the feedforward
    applies it (odd: along the motion, even: independent of the direction), per temperature bin and speed octave."""

    source: str                 #: the correction file and the SHA-256 of its bytes
    centres_c: Array            #: temperature bin centres [°C], (B,)
    inv_bin_per_c: float        #: 1 / bin width [1/°C] (the lookup's x = (t − centres_c[0]) · inv_bin_per_c)
    min_speed_rad_s: float      #: the octaves start here: u = log2(|v| / min_speed_rad_s) [rad/s]
    odd_nm: Array               #: part along the motion ½(S_cw + S_ccw) per (bin, octave) [N·m], (B, K)
    even_nm: Array              #: part independent of the direction ½(S_cw − S_ccw) per (bin, octave) [N·m], (B, K)
    error_nm: Array             #: error bound per (direction cw/ccw, bin): std. error of the cell mean × n/(n + n0);
    #: 0 without data, NaN with one sample (unknown); a bin holding its neighbour's profile holds its error [N·m],
    #: (2, B)
    samples: NDArray[np.int64]  #: samples per (direction, bin) [-], (2, B)
    applied: NDArray[np.bool_]  #: cells the guard applies (with samples; the others are held back to 0) (2, B)
    max_relative: float         #: bound: |odd| <= max_relative × |k_dir M| + floor_nm [-]
    floor_nm: float             #: [N·m]
    max_independent_nm: float   #: |even| <= max(max_relative × |k_dir M| + floor_nm, this) [N·m]
    ripple_periods_rad: tuple[float, ...]   #: periods of the applied ripple, left out of the export [rad]
    ripple_max_relative: float  #: its largest amplitude per period, relative to the model friction (0: none) [-]
    trend_max_nm: float         #: largest |coefficient| of the applied trend with the angle, left out (0: none) [N·m]
    settings: CorrectionSettings  #: the file's settings

    @property
    def octaves(self) -> int:
        """Speed octaves K of the profile [-] (node k at u = k + ½; 1: no speed dependence)."""
        return int(self.odd_nm.shape[1])

    @property
    def octave_speeds_rad_s(self) -> Array:
        """Speeds of the profile's nodes, the centres of the octaves: min_speed · 2^(k + ½) [rad/s], (K,)."""
        return np.asarray(self.min_speed_rad_s * 2.0 ** (np.arange(self.octaves) + 0.5), dtype=float)

    @property
    def empty(self) -> bool:
        """Nothing is added without a position (the correction applies nothing to this axis): exactly the model."""
        return not (np.any(self.odd_nm) or np.any(self.even_nm))

    @property
    def position_terms(self) -> bool:
        """The correction has terms in the joint angle the export leaves out (a ripple, a trend)."""
        return bool(self.ripple_periods_rad) or self.trend_max_nm > 0.0


def _held_error(error: Array, has: NDArray[np.bool_]) -> Array:
    """``error`` (bins,) with every bin without samples next to one with samples holding its neighbour's error (the
    mean of both neighbours' when both have samples): the hold rule of the lookup's profiles."""
    out = error.copy()
    n = error.shape[0]
    for b in range(n):
        if has[b]:
            continue
        left = b > 0 and bool(has[b - 1])
        right = b + 1 < n and bool(has[b + 1])
        if left and right:
            out[b] = 0.5 * (error[b - 1] + error[b + 1])
        elif left:
            out[b] = error[b - 1]
        elif right:
            out[b] = error[b + 1]
    return out


def table_correction(correction: Correction, axis: str, source: str) -> TableCorrection:
    """The exported form of ``correction``'s terms of ``axis`` (see :class:`TableCorrection`): the tables its lookup
    reads (after the hold rule; zeros where nothing is applied), its constants and per cell the samples and the error
    bound. The position terms (ripple, trend) are left out: the export is the lookup without a position."""
    s = correction.settings
    nt, ns = s.n_temperature, s.n_speed
    lut = correction.lookups[axis]
    if lut is None:   # nothing applied: exactly the model
        odd, even = np.zeros((nt, ns)), np.zeros((nt, ns))
        t0, inv_bin, vmin = s.temperature_min_c + 0.5 * s.temperature_bin_c, 1.0 / s.temperature_bin_c, \
            s.min_speed_rad_s
        rel, floor, independent = s.max_relative, s.floor_nm, s.max_independent_nm
    else:
        odd, even = np.array(lut.odd, dtype=float), np.array(lut.even, dtype=float)
        t0, inv_bin, vmin = lut.t0, lut.inv_bin, lut.vmin
        rel, floor, independent = lut.rel, lut.floor, lut.independent
    error = np.zeros((2, nt))
    samples = np.zeros((2, nt), dtype=np.int64)
    applied = np.zeros((2, nt), dtype=bool)
    for cell in correction.cells(axis):
        d = 0 if cell['direction'] == 'cw' else 1
        b, n = int(cell['bin']), int(cell['samples'])
        samples[d, b] = n
        applied[d, b] = bool(cell['applied'])
        se = cell['std_error_nm']
        error[d, b] = math.nan if se is None else se * n / (n + s.prior_samples)
    error = np.stack([_held_error(error[d], samples[d] > 0) for d in range(2)])
    centres = np.asarray(s.temperature_min_c + (np.arange(nt) + 0.5) * s.temperature_bin_c, dtype=np.float64)
    centres[0] = t0   # (the lookup's origin, to the bit)
    p = correction.applied(axis)
    amplitude = np.hypot(p.ripple[..., 0], p.ripple[..., 1])        # (bins, periods)
    rippling = np.any(amplitude > 0.0, axis=0)
    periods = tuple(float(x) for x in p.periods_rad[rippling])
    return TableCorrection(source, centres, float(inv_bin), float(vmin), odd, even, error, samples, applied,
                           float(rel), float(floor), float(independent), periods,
                           float(amplitude.max()) if amplitude.size else 0.0,
                           float(np.abs(p.trend_nm).max()) if p.trend_nm.size else 0.0, s)


def correction_nm(tc: TableCorrection, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                  model_nm: ArrayLike) -> tuple[Array, Array, Array]:
    """The exported correction at temperatures [°C] and velocities [rad/s] (``>= 0``: cw) for the model friction
    ``model_nm`` = k_dir M [N·m]: its part along the motion (odd) and its part independent of the direction (even),
    each bounded [N·m], applied as ``τ = clamp(tanh(v/v_th) (model + odd) + even, ±τ_max)``; and the error bound
    [N·m] of the direction of ``velocity_rad_s`` (its cells' bounds interpolated over temperature; NaN where one is
    unknown). The rule and the operations of the correction's lookup without a position
    (:meth:`~gimbal_friction.feedforward.correction.Correction.split_nm_array` with NaN positions) and of the C
    function ``gf_<axis>_correction_split_nm``."""
    t, v, m = (np.asarray(a, dtype=float) for a in np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (temperature_c, velocity_rad_s, model_nm))))
    nt, hi = tc.centres_c.shape[0], tc.octaves - 1
    # temperature: bin i and weight w, held at the ends (NaN: the first bin)
    x = (t - float(tc.centres_c[0])) * tc.inv_bin_per_c
    inside = (x > 0.0) & (x < nt - 1)
    i = np.where(inside, np.trunc(np.where(inside, x, 0.0)), np.where(x > 0.0, nt - 2, 0)).astype(np.int64)
    w = np.where(inside, x - i, np.where(x > 0.0, 1.0, 0.0))
    w0 = 1.0 - w
    # speed: octave coordinate u − ½ = log2(|v| / min speed) − ½, node k and weight f, held beyond the end nodes
    a = np.abs(v)
    faster = a > tc.min_speed_rad_s
    with np.errstate(divide='ignore', invalid='ignore'):
        xs = np.where(faster, np.log2(np.where(faster, a, 1.0) / tc.min_speed_rad_s) - 0.5, -1.0)
    low, high = ~(xs > 0.0), xs >= hi
    inner = ~low & ~high
    k = np.where(inner, np.trunc(np.where(inner, xs, 0.0)), np.where(high, hi, 0)).astype(np.int64)
    f = np.where(inner, xs - k, 0.0)
    k1 = np.minimum(k + 1, hi)
    parts = []
    for table in (tc.odd_nm, tc.even_nm):
        r0 = w0 * table[i, k] + w * table[i + 1, k]
        r1 = w0 * table[i, k1] + w * table[i + 1, k1]
        parts.append(np.where(inner, r0 + f * (r1 - r0), r0))
    odd, even = parts
    # below the slowest speed learned the part along the motion fades linearly to 0 at zero speed
    odd = np.where(a < tc.min_speed_rad_s, odd * (a / tc.min_speed_rad_s), odd)
    bound = tc.max_relative * np.abs(m) + tc.floor_nm
    clipped = ~((-bound <= odd) & (odd <= bound))
    odd = np.where(clipped, np.where(odd > 0.0, bound, -bound), odd)
    bound = np.maximum(bound, tc.max_independent_nm)
    clipped = ~((-bound <= even) & (even <= bound))
    even = np.where(clipped, np.where(even > 0.0, bound, -bound), even)
    finite = np.isfinite(m)   # an infinite model (an absurd speed): no correction
    odd, even = np.where(finite, odd, 0.0), np.where(finite, even, 0.0)
    d = np.where(v >= 0.0, 0, 1)
    e = tc.error_nm[d, i] + w * (tc.error_nm[d, i + 1] - tc.error_nm[d, i])
    return np.asarray(odd, dtype=float), np.asarray(even, dtype=float), np.asarray(e, dtype=float)


def correction_along_nm(tc: TableCorrection, temperature_c: ArrayLike, velocity_rad_s: ArrayLike,
                        model_nm: ArrayLike) -> tuple[Array, Array]:
    """What the exported correction adds to the model friction along the motion away from zero speed,
    odd + sign(v) even [N·m] (:meth:`~gimbal_friction.feedforward.correction.Correction.along_nm_array` without a
    position; the C function ``gf_<axis>_correction_nm``), and its error bound [N·m] (see :func:`correction_nm`)."""
    odd, even, error = correction_nm(tc, temperature_c, velocity_rad_s, model_nm)
    v = np.broadcast_to(np.asarray(velocity_rad_s, dtype=float), odd.shape)
    return np.asarray(np.where(v >= 0.0, odd + even, odd - even), dtype=float), error


class ExportTable(NamedTuple):
    """The exported table of one axis, its settings and its error report."""

    axis: str
    params: AxisParams
    settings: FeedforwardSettings
    options: ExportOptions
    grid: TableGrid
    report: ErrorReport
    correction: TableCorrection | None = None   #: the learned correction carried (None: the model alone)

    @property
    def temperatures_c(self) -> Array:
        """Temperature breakpoints [°C]."""
        return self.grid.t

    @property
    def switch_speed_rad_s(self) -> Array:
        """Switch speed v* = 2000/ν [rpm] at each breakpoint, [rad/s]."""
        return np.exp(self.grid.ln_vs)

    def evaluate_nm(self, temperature_c: ArrayLike, speed_rad_s: ArrayLike) -> Array:
        """Friction magnitude from the table (clamped at its edges), [N·m]; what the exported C function returns.

        Parameters
        ----------
        temperature_c : array_like
            Bearing temperature, [°C]; clamped to the table range.
        speed_rad_s : array_like
            Angular velocity, [rad/s]; its magnitude is used, clamped to ``max_speed_rad_s``.
        """
        return _interpolate(self.grid, self.options.max_speed_rad_s, temperature_c, speed_rad_s)[0]

    def model_nm(self, temperature_c: ArrayLike, speed_rad_s: ArrayLike) -> Array:
        """The full model at the same points (no clamping), [N·m]."""
        return _model_nm(self.params, temperature_c, speed_rad_s)


# ---------------------------------------------------------------------------------------------- building
def c_identifier(axis: str) -> str:
    """The axis name as a C identifier fragment and file-name part (anything but ``[A-Za-z0-9_]`` becomes ``_``).

    >>> c_identifier('elevation'), c_identifier('gimbal/az-1')
    ('elevation', 'gimbal_az_1')
    """
    return re.sub(r'[^0-9A-Za-z_]', '_', axis)


def _model_nm(params: AxisParams, t: ArrayLike, v: ArrayLike) -> Array:
    """Full model friction magnitude at temperature [°C] and angular velocity [rad/s], [N·m]."""
    rpm = rpm_from_rad_s(np.abs(np.asarray(v, dtype=float)))
    return nm_from_nmm(friction_torque(params, t, rpm).m_total_nmm)


def _ln_switch_speed(params: AxisParams, t: ArrayLike) -> Array:
    """ln of the switch speed v* = 2000/ν(t) [rpm] in [rad/s]; refuses a non-positive viscosity."""
    t_arr = np.asarray(t, dtype=float)
    nu = viscosity_cst(params, t_arr)
    if np.any(~(nu > 0.0)):
        bad = float(np.atleast_1d(t_arr)[np.argmax(np.atleast_1d(~(nu > 0.0)))])
        msg = f'the lubricant parameters give a viscosity <= 0 cSt at {bad:g} degC; no table can be built'
        raise ModelDomainError(msg)
    return np.asarray(np.log(rad_s_from_rpm(PALMGREN_SWITCH_CST_RPM / nu)), dtype=float)


def _upper_branch_rpm(params: AxisParams, t: Array, rpm: Array) -> Array:
    """``rpm`` raised by a few ulp where needed so that ν(t)·rpm ≥ 2000 exactly as the model computes it."""
    nu = viscosity_cst(params, t)
    out = rpm.copy()
    for _ in range(64):
        low = nu * out < PALMGREN_SWITCH_CST_RPM
        if not low.any():
            return out
        out = np.where(low, np.nextafter(out, np.inf), out)
    msg = 'cannot place the switch-speed nodes on the upper branch of Eq. (9)'   # not seen: a few ulp suffice
    raise ModelDomainError(msg)


def _grid(params: AxisParams, t: Array, max_speed: float) -> TableGrid:
    """Model values at the breakpoints ``t``: the lower branch at speed 0, the upper at η = 1 and η_top."""
    ln_vs = _ln_switch_speed(params, t)
    lower = friction_torque(params, t, 0.0)
    reachable = np.flatnonzero(ln_vs <= math.log(max_speed) + 1e-9)
    # rows 0..k: every breakpoint where the switch is reachable, plus the next one (interpolation partner)
    k = int(reachable.max()) + 1 if reachable.size else 1
    k = min(max(k, 1), len(t) - 1)
    rows = slice(0, k + 1)
    eta_top = max(float(np.max((max_speed * np.exp(-ln_vs[rows])) ** (2.0 / 3.0))), 2.0)
    eta = np.array([1.0, eta_top])
    # node speeds from ν directly (exp(ln v*) loses |ln v*| ulp), the η = 1 node nudged onto the upper branch
    rpm_switch = PALMGREN_SWITCH_CST_RPM / viscosity_cst(params, t[rows])
    rpm = np.stack([_upper_branch_rpm(params, t[rows], rpm_switch), rpm_switch * eta_top ** 1.5], axis=1)
    t_rows = np.broadcast_to(t[rows, None], rpm.shape)
    upper = friction_torque(params, t_rows, rpm)
    return TableGrid(t, ln_vs, nm_from_nmm(lower.m_total_nmm), eta, nm_from_nmm(upper.m_total_nmm), lower, upper,
                     rad_s_from_rpm(rpm))


def _interpolate(g: TableGrid, max_speed: float, t_c: ArrayLike, v: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
    """The table's friction magnitude [N·m] and whether it took the upper branch (the C code, vectorised)."""
    t_in, v_in = np.broadcast_arrays(np.asarray(t_c, dtype=float), np.asarray(v, dtype=float))
    T = g.t
    n = len(T)
    t = np.clip(t_in, T[0], T[-1])
    s = np.minimum(np.abs(v_in), max_speed)
    i = np.clip(np.searchsorted(T, t, side='right') - 1, 0, n - 2)
    w = (t - T[i]) / (T[i + 1] - T[i])

    def lerp(a: Array, j: NDArray[np.intp]) -> Array:
        return np.asarray(a[j] + w * (a[j + 1] - a[j]), dtype=float)

    xi = s * np.exp(-lerp(g.ln_vs, i))
    lower = lerp(g.lower_nm, i)
    k = g.upper_nm.shape[0]
    upper_ok = (xi >= 1.0) & (i + 1 < k)
    iu = np.minimum(i, k - 2)
    a = g.upper_nm[iu, 0] + w * (g.upper_nm[iu + 1, 0] - g.upper_nm[iu, 0])
    b = g.upper_nm[iu, 1] + w * (g.upper_nm[iu + 1, 1] - g.upper_nm[iu, 1])
    c = np.cbrt(xi)
    eta = np.minimum(c * c, g.eta[1])
    u = (eta - g.eta[0]) / (g.eta[1] - g.eta[0])
    upper = a + u * (b - a)
    return np.where(upper_ok, upper, lower), upper_ok


def _initial_breakpoints(params: AxisParams, o: ExportOptions) -> tuple[Array, float | None]:
    """Uniform breakpoints every ≤ INITIAL_STEP_C plus the loose-fit kink (if inside the range)."""
    n = max(int(math.ceil((o.temperature_max_c - o.temperature_min_c) / INITIAL_STEP_C)), 2)
    t = np.linspace(o.temperature_min_c, o.temperature_max_c, n + 1)
    kink = loose_fit_temperature(params)
    margin = 1e-3
    inside = math.isfinite(kink) and o.temperature_min_c + margin < kink < o.temperature_max_c - margin
    if inside:
        t = np.union1d(t[np.abs(t - kink) > margin], [kink])
    return t, (kink if inside else None)


def _midpoint_points(params: AxisParams, g: TableGrid, max_speed: float) -> tuple[Array, Array, NDArray[np.intp],
                                                                             Array]:
    """Check points of the refinement and the final check (module docstring): (t [°C], v [rad/s], interval index,
    switch-band deviation |Δ ln v*| per interval)."""
    T = g.t
    n = len(T)
    idx = np.arange(n - 1)
    tm = 0.5 * (T[:-1] + T[1:])
    ln_interp = 0.5 * (g.ln_vs[:-1] + g.ln_vs[1:])
    ln_true = _ln_switch_speed(params, tm)
    k = g.upper_nm.shape[0]
    ln_max = math.log(max_speed)
    has_upper = idx + 1 < k
    band = np.where(has_upper, np.abs(ln_interp - ln_true), 0.0)
    ts: list[Array] = [tm]
    vs: list[Array] = [np.zeros(n - 1)]
    ids: list[NDArray[np.intp]] = [idx]
    # upper branch: just above the switch (on the upper branch for both table and model), at v_max, and half way
    # in η between them
    ln_lo = np.maximum(ln_interp, ln_true) + 1e-9
    sel = has_upper & (ln_lo < ln_max)
    if sel.any():
        eta1 = np.exp((2.0 / 3.0) * (ln_lo[sel] - ln_interp[sel]))
        eta2 = np.exp((2.0 / 3.0) * (ln_max - ln_interp[sel]))
        v_mid = np.exp(ln_interp[sel]) * (0.5 * (eta1 + eta2)) ** 1.5
        for vv in (np.exp(ln_lo[sel]), np.full(int(sel.sum()), max_speed), v_mid):
            ts.append(tm[sel])
            vs.append(vv)
            ids.append(idx[sel])
    # η-midpoints of the upper rows at the breakpoints themselves (pure speed-direction error)
    rows = np.flatnonzero((np.arange(n) < k) & (g.ln_vs < ln_max))
    if rows.size:
        eta2 = np.exp((2.0 / 3.0) * (ln_max - g.ln_vs[rows]))
        ts.append(T[rows])
        vs.append(np.exp(g.ln_vs[rows]) * (0.5 * (1.0 + eta2)) ** 1.5)
        ids.append(np.minimum(rows, n - 2))
    return np.concatenate(ts), np.concatenate(vs), np.concatenate(ids), band


def _random_points(rng: np.random.Generator, o: ExportOptions) -> tuple[Array, Array]:
    """Seeded check points: t uniform; |v| uniform for half, log-uniform over six decades for the other half."""
    n = o.random_points
    t = rng.uniform(o.temperature_min_c, o.temperature_max_c, n)
    half = n // 2
    v_uniform = rng.uniform(-o.max_speed_rad_s, o.max_speed_rad_s, half)
    sign = np.where(rng.uniform(size=n - half) < 0.5, -1.0, 1.0)
    v_log = sign * o.max_speed_rad_s * 10.0 ** rng.uniform(-6.0, 0.0, n - half)
    return t, np.concatenate([v_uniform, v_log])


def _split(t: Array, ratio: Array, o: ExportOptions) -> Array:
    """Split every interval whose error ratio (error / target) exceeds 1 into ``ceil(1.1 sqrt(ratio))`` equal parts
    (linear-interpolation error scales with the step squared); refuses when the cap or the smallest step would be
    passed."""
    bad = ratio > 1.0
    parts = np.clip(np.ceil(1.1 * np.sqrt(ratio[bad])), 2, 64).astype(int)
    lo, hi = t[:-1][bad], t[1:][bad]
    if np.any((hi - lo) / parts < MIN_STEP_C):
        where = float(lo[np.argmin((hi - lo) / parts)])
        msg = (f'relative error bound {o.relative_error:g} needs breakpoints closer than {MIN_STEP_C:g} degC near '
               f'{where:.4g} degC; choose a larger bound')
        raise GimbalFrictionError(msg)
    new = [lo[j] + (hi[j] - lo[j]) * np.arange(1, parts[j]) / parts[j] for j in range(len(lo))]
    count = len(t) + int(np.sum(parts - 1))
    if count > o.max_breakpoints:
        msg = (f'relative error bound {o.relative_error:g} needs more than {o.max_breakpoints} temperature '
               f'breakpoints (had {len(t)}, {int(bad.sum())} intervals still above it); choose a larger bound')
        raise GimbalFrictionError(msg)
    return np.union1d(t, np.concatenate(new)) if new else t


def _switch_band(params: AxisParams, g: TableGrid, band_midpoints: Array, t: Array) -> float:
    """Largest relative deviation of the interpolated switch speed from the exact one, at the interval midpoints
    and at the temperatures ``t`` where the table has speed-dependent values, [-]."""
    top = g.t[g.upper_nm.shape[0] - 1]
    t_in = t[t <= top]
    dev = np.abs(np.interp(t_in, g.t, g.ln_vs) - _ln_switch_speed(params, t_in)) if t_in.size else np.zeros(1)
    return float(np.expm1(max(float(np.max(band_midpoints, initial=0.0)), float(np.max(dev, initial=0.0)))))


def _speed_matters_below(params: AxisParams, o: ExportOptions) -> float | None:
    """Temperature below which ν n ≥ 2000 is reachable at |v| ≤ v_max, [°C] (None: nowhere in the range)."""
    ln_max = math.log(o.max_speed_rad_s)
    lo, hi = o.temperature_min_c, o.temperature_max_c
    f_lo, f_hi = (float(x) - ln_max for x in _ln_switch_speed(params, np.array([lo, hi])))
    if f_lo > 0.0:
        return None
    if f_hi <= 0.0:
        return hi
    return min(max(palmgren_threshold_temperature(params, rpm_from_rad_s(o.max_speed_rad_s)), lo), hi)


def _relative_error(table: Array, model: Array) -> Array:
    return np.asarray(np.abs(table - model) / np.abs(model), dtype=float)


def check_in_validity(params: AxisParams, options: ExportOptions) -> None:
    """Raise ConfigError unless the table range of ``options`` lies within the model's validity range for
    ``params`` (a table for a controller never extrapolates the model; outside its range the table clamps)."""
    r = validity_range(params)
    why = (f' for these parameters: {r.note}' if r.note else
           ', where the paper computed and measured the friction (docs/model.md, "Validity range")')
    check_rules(options, [
        ('temperature_min_c', options.temperature_min_c >= r.low_c,
         f"must be >= {r.low_c:g} [degC]: the model's validity range is {r.text}{why}"),
        ('temperature_max_c', options.temperature_max_c <= r.high_c,
         f"must be <= {r.high_c:g} [degC]: the model's validity range is {r.text}{why}"),
    ])


def build_table(axis: str, params: AxisParams, settings: FeedforwardSettings,
                options: ExportOptions | None = None, *, progress: Progress | None = None,
                extrapolate: bool = False) -> ExportTable:
    """Build the table of one axis so that linear interpolation stays within ``options.relative_error``.

    Parameters
    ----------
    axis : str
        Axis (joint) name.
    params : AxisParams
        Model parameters of the axis.
    settings : FeedforwardSettings
        Feedforward settings (smooth-sign threshold, clamp) recorded with the table and used by the C feedforward.
    options : ExportOptions, optional
        Range, speed limit, error bound, check points.
    progress : callable, optional
        Called with a one-line status after each refinement pass.
    extrapolate : bool
        Allow a range past the model's validity range (:func:`~gimbal_friction.physics.validity.validity_range`;
        for checks of the table's numerics: a table for a controller never extrapolates the model).

    Returns
    -------
    ExportTable
        The table and its :class:`ErrorReport`.

    Raises
    ------
    ConfigError
        An option or setting breaks its rule, or the range reaches past the model's validity range.
    GimbalFrictionError
        The bound needs more than ``max_breakpoints`` breakpoints (or breakpoints closer than 1e-6 °C).
    ModelDomainError
        The model cannot be evaluated over the range.
    """
    o = options if options is not None else ExportOptions()
    o.validate()
    settings.validate()
    if not extrapolate:
        check_in_validity(params, o)
    target = 0.5 * o.relative_error
    t, kink = _initial_breakpoints(params, o)
    rt, rv = _random_points(np.random.default_rng(o.seed), o)
    r_model: Array | None = None      # evaluated once, when the midpoints first pass
    passes = 0
    while True:
        passes += 1
        if passes > MAX_PASSES:
            msg = f'relative error bound {o.relative_error:g} not reached after {MAX_PASSES} refinement passes'
            raise GimbalFrictionError(msg)
        g = _grid(params, t, o.max_speed_rad_s)
        pt, pv, pi, band = _midpoint_points(params, g, o.max_speed_rad_s)
        err = _relative_error(_interpolate(g, o.max_speed_rad_s, pt, pv)[0], _model_nm(params, pt, pv))
        worst = np.zeros(len(t) - 1)
        np.maximum.at(worst, pi, err)
        ratio = np.maximum(worst, band) / target
        if not (ratio > 1.0).any():
            if r_model is None:
                r_model = _model_nm(params, rt, rv)
                r_branch = viscosity_cst(params, rt) * rpm_from_rad_s(np.abs(rv)) >= PALMGREN_SWITCH_CST_RPM
            table_r, branch = _interpolate(g, o.max_speed_rad_s, rt, rv)
            r_err = _relative_error(table_r, r_model)
            in_band = branch != r_branch
            over = (r_err > o.relative_error) & ~in_band
            if not over.any():
                break
            ri = np.clip(np.searchsorted(t, rt[over], side='right') - 1, 0, len(t) - 2)
            np.maximum.at(ratio, ri, 4.0)
        if progress is not None:
            progress(f'{axis}: pass {passes}: {len(t)} breakpoints, {int((ratio > 1.0).sum())} intervals above '
                     'the bound')
        t = _split(t, ratio, o)
    i_mid = int(np.argmax(err))
    out = ~in_band
    i_rand = int(np.argmax(np.where(out, r_err, -1.0)))
    report = ErrorReport(
        relative_error_bound=o.relative_error, temperatures=len(t), upper_rows=int(g.upper_nm.shape[0]),
        values=int(3 * len(t) + g.upper_nm.size + g.eta.size), passes=passes, midpoint_checks=int(err.size),
        midpoint_max_relative_error=float(err[i_mid]), midpoint_worst_temperature_c=float(pt[i_mid]),
        midpoint_worst_speed_rad_s=float(pv[i_mid]), random_points=int(out.sum()),
        random_max_relative_error=float(r_err[i_rand]) if out.any() else 0.0,
        random_worst_temperature_c=float(rt[i_rand]), random_worst_speed_rad_s=float(rv[i_rand]),
        switch_band=_switch_band(params, g, band, rt),
        switch_band_points=int(in_band.sum()),
        switch_band_max_relative_error=float(r_err[in_band].max()) if in_band.any() else 0.0,
        speed_matters_below_c=_speed_matters_below(params, o), loose_fit_c=kink)
    if progress is not None:
        progress(f'{axis}: {len(t)} breakpoints, max relative error {report.midpoint_max_relative_error:.2e} '
                 f'(midpoints), {report.random_max_relative_error:.2e} (random points)')
    return ExportTable(axis, params, settings, o, g, report)
