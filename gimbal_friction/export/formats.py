"""Text forms of the exported model table (for a controller or drive firmware):
CSV with units, a C99 header, a ROS parameter YAML.

The table, its grid and its error check are :mod:`gimbal_friction.export.table` (pure); this module only renders
them, each with the provenance (parameters, parameter-file hashes, error bound) and the lookup rule.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence

import numpy as np
import yaml
from numpy.typing import NDArray

from gimbal_friction.common.units import nm_from_nmm, rpm_from_rad_s
from gimbal_friction.common.xp import ARRAY
from gimbal_friction.export.table import (
    PALMGREN_JUMP,
    ExportTable,
    Provenance,
    TableCorrection,
    c_identifier,
    correction_along_nm,
)
from gimbal_friction.physics.direction import direction_factor
from gimbal_friction.physics.model import FrictionResult
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.validity import LUBRICANT_DATA_C, validity_range

Array = NDArray[np.float64]


# ---------------------------------------------------------------------------------------------- rendering
#: CSV columns, in order (units in the names)
CSV_FIELDS = ('temperature_c', 'speed_rpm', 'speed_rad_s', 'eta', 'm_total_nmm', 'm_total_nm', 'm_rolling_nmm',
              'm_sliding_nmm', 'm_viscous_nmm', 'viscosity_cst', 'switch_speed_rad_s')
#: CSV columns added with a learned correction: what the feedforward adds to the model friction along the motion
#: (odd + sign(v) even, away from zero speed) at the row's temperature and speed, per direction, and its error bound
#: [N*m]
CSV_CORRECTION_FIELDS = ('correction_cw_nm', 'correction_cw_error_nm', 'correction_ccw_nm', 'correction_ccw_error_nm')

#: the lookup rule, as written into every file
LOOKUP_RULE = (
    'Lookup (what gf_<axis>_friction_nm does): clamp t to [first, last temperature], s = min(|v|, max speed);',
    'find i with t_i <= t <= t_i+1, w = (t - t_i)/(t_i+1 - t_i), lerp(a) = a_i + w (a_i+1 - a_i);',
    'xi = s * exp(-lerp(ln_switch_speed))   (xi = nu*n/2000: Palmgren Eq. 9 switches branch at xi = 1);',
    'if xi < 1 or i+1 >= upper rows: M = lerp(torque_lower)   (speed-independent branch);',
    'else eta = min(xi^(2/3), eta_top), u = (eta - 1)/(eta_top - 1),',
    '     M = lerp(torque_upper[:,0]) + u (lerp(torque_upper[:,1]) - lerp(torque_upper[:,0]))',
    '     (Eq. 9 is linear in eta above the switch, so this is exact along speed).',
)


def _clean(text: str) -> str:
    """One line, safe inside a C comment, a YAML comment and a CSV comment."""
    return re.sub(r'[\x00-\x1f\x7f]', ' ', text).replace('*/', '*\\/')


def _fmt(x: float) -> str:
    """Shortest text that reads back to the same double (a valid C, YAML and CSV number)."""
    return repr(float(x))


def _validity_line(p: AxisParams) -> str:
    r = validity_range(p)
    why = r.note or ('where the paper computed and measured the friction; the lubricant data reach '
                     f'{LUBRICANT_DATA_C[0]:g} .. {LUBRICANT_DATA_C[1]:g} degC')
    return (f"The model's validity range is {r.low_c:g} .. {r.high_c:g} degC ({why}); the table never reaches past "
            'it (a temperature outside is used at the edge).')


def provenance_lines(table: ExportTable, prov: Provenance) -> list[str]:
    """The comment block every file carries: generator, date, axis, parameters, hashes, bound and its check."""
    r, o, p, s = table.report, table.options, table.params, table.settings
    lines = [
        f'{prov.generator}, created {prov.created}',
        f'axis: {table.axis}',
        (f'Friction torque magnitude M of the whole axis ({p.bearings_per_axis} bearings), model of Yu & Shang '
         '(2017), JAMDSM 11(5), DOI 10.1299/jamdsm.2017jamdsm0052.'),
        'Parameter files, layered in this order (SHA-256 of the bytes read):',
        *[f'  {label}: {digest}' for label, digest in prov.sources],
        (f'Range: temperature {o.temperature_min_c:g} .. {o.temperature_max_c:g} degC, |velocity| <= '
         f'{o.max_speed_rad_s:g} rad/s; outside, inputs are clamped to these edges.'),
        _validity_line(p),
        (f'Relative interpolation error bound |table - model|/model: requested {r.relative_error_bound:.3g}; '
         f'achieved {r.midpoint_max_relative_error:.3g} (max at {r.midpoint_checks} midpoints), '
         f'{r.random_max_relative_error:.3g} (max at {r.random_points} seeded random points; seed {o.seed}).'),
        (f'Palmgren switch band: within +-{r.switch_band:.2g} (relative) of nu*n = 2000 the table may take the '
         f'other branch of Eq. 9 (the model itself jumps {100 * PALMGREN_JUMP:.2f} % of M_L there); '
         f'{r.switch_band_points} random points fell inside.'),
        (f'Grid: {r.temperatures} temperature breakpoints (non-uniform), {r.upper_rows} with speed-dependent '
         f'values at eta = 1 and {table.grid.eta[1]:.6g}; {r.values} numbers.'),
        ('Speed matters (nu*n >= 2000 reachable) below '
         f'{r.speed_matters_below_c:.2f} degC.' if r.speed_matters_below_c is not None else
         'Speed never matters in this range (nu*n < 2000 at every tabulated speed).'),
    ]
    if r.loose_fit_c is not None:
        lines.append(f'Loose-fit kink at {r.loose_fit_c:.4f} degC (a breakpoint).')
    lines.append('Model parameters (AxisParams):')
    for f in dataclasses.fields(p):
        unit = f.metadata.get('unit', '')
        value = getattr(p, f.name)
        shown = f' [{unit}]' if unit and not isinstance(value, (bool, str)) else ''
        lines.append(f'  {f.name} = {value!r}{shown}')
    lines.append('Feedforward settings (friction_feedforward):')
    for name in ('velocity_threshold_rad_s', 'max_torque_nm'):
        unit = next(f.metadata['unit'] for f in dataclasses.fields(s) if f.name == name)
        lines.append(f'  {name} = {getattr(s, name)!r} [{unit}]')
    lines.append(f'  direction factor k_dir = s_d (1 + d a(T)): scale_positive = {p.scale_positive!r} (v >= 0), '
                 f'scale_negative = {p.scale_negative!r} (v < 0), a(T) from {p.direction_asymmetry_cold!r} at '
                 f'{p.direction_asymmetry_cold_c!r} degC to {p.direction_asymmetry_warm!r} at '
                 f'{p.direction_asymmetry_warm_c!r} degC (linear, held outside)')
    c = table.correction
    if c is None:
        lines.append('Feedforward: tau = clamp(tanh(v/velocity_threshold) * k_dir * M(t, |v|), +-max_torque) [N*m].')
    else:
        lines += correction_lines(c)
    return [_clean(line) for line in lines]


def correction_lines(c: TableCorrection) -> list[str]:
    """The comment lines of a learned correction: where from, what it holds, how it is looked up and added, its
    error bound and what is left out."""
    bins, k = c.centres_c.shape[0], c.octaves
    speeds = c.octave_speeds_rad_s
    lines = [
        (f'Learned correction: {c.source}; {int(c.samples.sum())} samples in {int((c.samples > 0).sum())} cells '
         f'({int(c.applied.sum())} applied, the others held back to the model); {bins} temperature bins of '
         f'{1.0 / c.inv_bin_per_c:g} degC centred {c.centres_c[0]:g} .. {c.centres_c[-1]:g} degC x {k} speed '
         f'octaves from {c.min_speed_rad_s!r} rad/s (nodes at {speeds[0]:.6g} .. {speeds[-1]:.6g} rad/s); '
         'cw: v >= 0, ccw: v < 0.'),
        ('Feedforward: tau = clamp(tanh(v/velocity_threshold) * (k_dir * M(t, |v|) + odd) + even, +-max_torque) '
         '[N*m]; odd = (S_cw + S_ccw)/2 is the part along the motion and even = (S_cw - S_ccw)/2 the part '
         'independent of the direction of the learned speed profiles S_cw, S_ccw (per bin centre and octave centre; '
         "a bin without samples next to one with samples holds its neighbour's, the mean of both when both have)."),
        ('Correction lookup (t0 = the first bin centre, inv_bin = 1 / bin width): x = (t - t0) * inv_bin; inside '
         '0 < x < bins - 1: i = floor(x), w = x - i; else the first (x <= 0 or NaN: i = 0, w = 0) or last '
         '(i = bins - 2, w = 1) bin; '
         'row(k) = (1 - w) * table[i][k] + w * table[i+1][k];'),
        ('  y = log2(|v| / min_speed) - 0.5 (y = -1 if |v| <= min_speed); y <= 0: row(0); y >= octaves - 1: '
         'row(octaves - 1); else k = floor(y), f = y - k, row(k) + f * (row(k+1) - row(k));'),
        ('  below min_speed odd *= |v| / min_speed (the part along the motion fades to 0 at zero speed: through a '
         "reversal the feedforward is the model's);"),
        (f'  odd clamped to +-B, B = {c.max_relative!r} * |k_dir M| + {c.floor_nm!r} N*m; even clamped to '
         f'+-max(B, {c.max_independent_nm!r} N*m).'),
        ('Error bound per cell (direction x bin): standard error of the cell mean x n/(n + n0) (0: no data; unknown '
         "with one sample: nan, -1 in C and ROS); a bin holding its neighbour's profile holds its error."),
    ]
    if c.position_terms:
        left = []
        if c.ripple_periods_rad:
            left.append('a ripple at periods ' + ', '.join(f'{x:.6g}' for x in c.ripple_periods_rad) + ' rad (up to '
                        f'{100.0 * c.ripple_max_relative:.3g} % of the model friction)')
        if c.trend_max_nm > 0.0:
            left.append(f'a trend with the joint angle (coefficients up to {c.trend_max_nm:.3g} N*m)')
        lines.append(f'Not exported: the correction\'s position terms ({" and ".join(left)}); these tables are its '
                     'lookup without a joint position, as the node without one (its profile over speed only).')
    return lines


def csv_rows(table: ExportTable) -> list[dict[str, float]]:
    """The grid as records (``CSV_FIELDS``): per breakpoint the speed-independent value at η = 0, and where the
    upper table has the breakpoint, the values at η = 1 and η_top."""
    g = table.grid
    out: list[dict[str, float]] = []
    vs = np.exp(g.ln_vs)
    k = g.upper_nm.shape[0]

    def record(res: FrictionResult, idx: tuple[int, ...], speed: float, eta: float, i: int) -> dict[str, float]:
        m = float(res.m_total_nmm[idx])
        return {'temperature_c': float(g.t[i]), 'speed_rpm': float(rpm_from_rad_s(speed)), 'speed_rad_s': speed,
                'eta': eta, 'm_total_nmm': m, 'm_total_nm': float(nm_from_nmm(m)),
                'm_rolling_nmm': float(res.m_rolling_nmm[idx]), 'm_sliding_nmm': float(res.m_sliding_nmm[idx]),
                'm_viscous_nmm': float(res.m_viscous_nmm[idx]), 'viscosity_cst': float(res.viscosity_cst[idx]),
                'switch_speed_rad_s': float(vs[i])}

    for i in range(len(g.t)):
        out.append(record(g.lower, (i,), 0.0, 0.0, i))
        if i < k:
            for j in range(2):
                out.append(record(g.upper, (i, j), float(g.upper_speed_rad_s[i, j]), float(g.eta[j]), i))
    if table.correction is not None and out:
        t = np.array([r['temperature_c'] for r in out])
        m = np.array([r['m_total_nm'] for r in out])
        speed = np.array([r['speed_rad_s'] for r in out])
        for sign, name in ((1.0, 'cw'), (-1.0, 'ccw')):
            model = direction_factor(table.params, t, sign, ARRAY) * m
            # at the row's speed (the profile is held below min_speed_rad_s, so the sign can pick the direction)
            v = sign * np.maximum(speed, table.correction.min_speed_rad_s)
            value, error = correction_along_nm(table.correction, t, v, model)
            for r, cv, ce in zip(out, value.tolist(), error.tolist(), strict=True):
                r[f'correction_{name}_nm'], r[f'correction_{name}_error_nm'] = cv, ce
    return out


def csv_fields(table: ExportTable) -> tuple[str, ...]:
    """The CSV columns of ``table`` (with a learned correction: :data:`CSV_CORRECTION_FIELDS` too)."""
    return CSV_FIELDS if table.correction is None else CSV_FIELDS + CSV_CORRECTION_FIELDS


def render_csv(table: ExportTable, prov: Provenance) -> str:
    """CSV text: ``#`` comment lines (provenance, error bound, lookup rule), a header row with units, the rows."""
    head = [
        *provenance_lines(table, prov),
        'Rows: per temperature, eta = 0 is the speed-independent branch (valid for every eta < 1, i.e. nu*n < 2000:',
        'do NOT interpolate between eta = 0 and eta = 1, Eq. 9 jumps there); eta = 1 and eta = eta_top are the',
        'speed-dependent branch (interpolate linearly in eta = (|v|/switch_speed)^(2/3)).',
        *LOOKUP_RULE,
        'Columns: torques of the whole axis in N*mm (paper) and N*m (SI); speed in rpm and rad/s; viscosity in cSt.',
    ]
    if table.correction is not None:
        head.append("Correction columns: what the feedforward adds to k_dir * M along the motion (odd + even cw, odd "
                    "- even ccw, away from zero speed) at the row's temperature and speed, cw and ccw, and its error "
                    'bound [N*m].')
    fields = csv_fields(table)
    lines = [f'# {line}' for line in head]
    lines.append(','.join(fields))
    for rec in csv_rows(table):
        lines.append(','.join(_fmt(rec[f]) for f in fields))
    return '\n'.join(lines) + '\n'


def _c_array(values: Sequence[float] | Array, per_line: int = 4, indent: str = '    ') -> str:
    items = [_fmt(float(v)) for v in values]
    rows = [', '.join(items[k:k + per_line]) for k in range(0, len(items), per_line)]
    return ',\n'.join(indent + r for r in rows)


def render_c_header(table: ExportTable, prov: Provenance) -> str:
    """A self-contained C99 header: the table as ``static const double`` arrays, ``gf_<axis>_friction_nm``,
    ``gf_<axis>_direction_factor`` and ``gf_<axis>_feedforward_nm``. Needs only ``<math.h>`` (link with -lm)."""
    g, o, s, p = table.grid, table.options, table.settings, table.params
    a = c_identifier(table.axis)
    A = a.upper()
    n, k = len(g.t), g.upper_nm.shape[0]
    comment = '\n'.join(f' * {line}'.rstrip() for line in [
        f'gimbal_friction_{a}.h: friction table and feedforward of axis "{_clean(table.axis)}".',
        'Generated by gimbal-friction export; do not edit.',
        '', *provenance_lines(table, prov), '', *LOOKUP_RULE, '',
        f'double gf_{a}_friction_nm(double temperature_c, double speed_rad_s): friction magnitude M [N*m] at the',
        '  bearing temperature [degC] and angular velocity [rad/s] (magnitude used). Temperature is clamped to the',
        '  table range and |velocity| to the max speed (documented edges). NaN in, NaN out.',
        f'double gf_{a}_direction_factor(double temperature_c, double velocity_rad_s): k_dir [-] (a function of',
        '  temperature so that it can become a table over temperature).',
        f"double gf_{a}_feedforward_nm(double temperature_c, double velocity_rad_s): the friction_feedforward node's",
        ('  torque [N*m], clamp(tanh(v/v_th) * k_dir * M, +-max_torque)' if table.correction is None else
         '  torque [N*m], clamp(tanh(v/v_th) * (k_dir * M + odd) + even, +-max_torque) with the learned correction')
        + '; 0 for a non-finite input (the node outputs 0',
        '  for a non-finite velocity; it rejects a bad temperature and applies its stale policy: do that in your',
        '  code if you need it).',
        *([] if table.correction is None else [
            f'void gf_{a}_correction_split_nm(double temperature_c, double velocity_rad_s, double model_nm, double',
            '  *odd_nm, double *even_nm): the learned correction [N*m] for the model friction model_nm = k_dir * M',
            '  [N*m], its part along the motion and its part independent of the direction, each bounded;',
            f'double gf_{a}_correction_nm(double temperature_c, double velocity_rad_s, double model_nm): what it adds',
            '  along the motion away from zero speed, odd + even (v >= 0) or odd - even (v < 0) [N*m];',
            f'double gf_{a}_correction_error_nm(double temperature_c, double velocity_rad_s): its error bound in the',
            '  direction of velocity_rad_s [N*m] (negative: unknown).']),
        'No pre-sliding (dynamic) term: the sign of motion here is the static tanh(v/v_th); a pre-sliding term the',
        '  suite learned (a Dahl state per joint, docs/model.md) is not carried by this header.',
        'C99, only <math.h>; link with -lm.',
    ])
    upper_rows = ',\n'.join(f'    {{{_fmt(g.upper_nm[i, 0])}, {_fmt(g.upper_nm[i, 1])}}}' for i in range(k))
    return f"""/*
{comment}
 */
#ifndef GIMBAL_FRICTION_{A}_H
#define GIMBAL_FRICTION_{A}_H

#include <math.h>

#define GF_{A}_N {n}  /* temperature breakpoints */
#define GF_{A}_N_UPPER {k}  /* leading breakpoints that carry speed-dependent (upper-branch) values */
#define GF_{A}_MAX_SPEED_RAD_S {_fmt(o.max_speed_rad_s)}  /* |velocity| is clamped to this [rad/s] */
#define GF_{A}_ETA_TOP {_fmt(g.eta[1])}  /* second eta breakpoint of the upper table [-] */
#define GF_{A}_RELATIVE_ERROR_BOUND {_fmt(table.report.relative_error_bound)}  /* [-] */
#define GF_{A}_VELOCITY_THRESHOLD_RAD_S {_fmt(s.velocity_threshold_rad_s)}  /* v_th of tanh(v/v_th) [rad/s] */
#define GF_{A}_MAX_TORQUE_NM {_fmt(s.max_torque_nm)}  /* feedforward clamp [N*m] */
#define GF_{A}_SCALE_POSITIVE {_fmt(p.scale_positive)}  /* s_+, factor for v >= 0 [-] */
#define GF_{A}_SCALE_NEGATIVE {_fmt(p.scale_negative)}  /* s_-, factor for v < 0 [-] */
#define GF_{A}_ASYMMETRY_COLD {_fmt(p.direction_asymmetry_cold)}  /* a_c, CW/CCW asymmetry at the cold anchor [-] */
#define GF_{A}_ASYMMETRY_WARM {_fmt(p.direction_asymmetry_warm)}  /* a_w, at the warm anchor [-] */
#define GF_{A}_ASYMMETRY_COLD_C {_fmt(p.direction_asymmetry_cold_c)}  /* cold anchor [degC] */
#define GF_{A}_ASYMMETRY_WARM_C {_fmt(p.direction_asymmetry_warm_c)}  /* warm anchor [degC] */

/* temperature breakpoints [degC], increasing */
static const double gf_{a}_temperature_c[GF_{A}_N] = {{
{_c_array(g.t)}
}};

/* ln of the switch speed v* = 2000/nu(t) rpm, in rad/s [ln(rad/s)]: nu*n >= 2000 <=> |v| >= v* */
static const double gf_{a}_ln_switch_speed[GF_{A}_N] = {{
{_c_array(g.ln_vs)}
}};

/* M on the speed-independent branch (nu*n < 2000) [N*m] */
static const double gf_{a}_torque_lower_nm[GF_{A}_N] = {{
{_c_array(g.lower_nm)}
}};

/* M on the speed-dependent branch at eta = 1 and eta = GF_{A}_ETA_TOP [N*m] */
static const double gf_{a}_torque_upper_nm[GF_{A}_N_UPPER][2] = {{
{upper_rows}
}};

static inline double gf_{a}_friction_nm(double temperature_c, double speed_rad_s)
{{
    const double *T = gf_{a}_temperature_c;
    const double *L = gf_{a}_ln_switch_speed;
    const double *M = gf_{a}_torque_lower_nm;
    double t = temperature_c, s = fabs(speed_rad_s), w, xi;
    int lo = 0, hi = GF_{A}_N - 1;
    if (isnan(t) || isnan(s)) {{
        return NAN;
    }}
    if (t < T[0]) {{
        t = T[0];
    }}
    if (t > T[GF_{A}_N - 1]) {{
        t = T[GF_{A}_N - 1];
    }}
    if (s > GF_{A}_MAX_SPEED_RAD_S) {{
        s = GF_{A}_MAX_SPEED_RAD_S;
    }}
    while (hi - lo > 1) {{  /* T[lo] <= t <= T[hi] */
        int mid = lo + (hi - lo) / 2;
        if (T[mid] <= t) {{
            lo = mid;
        }} else {{
            hi = mid;
        }}
    }}
    w = (t - T[lo]) / (T[hi] - T[lo]);
    xi = s * exp(-(L[lo] + w * (L[hi] - L[lo])));
    if (xi >= 1.0 && hi < GF_{A}_N_UPPER) {{
        const double *a = gf_{a}_torque_upper_nm[lo];
        const double *b = gf_{a}_torque_upper_nm[hi];
        double c = cbrt(xi), eta = c * c, m1, m2, u;
        if (eta > GF_{A}_ETA_TOP) {{
            eta = GF_{A}_ETA_TOP;
        }}
        u = (eta - 1.0) / (GF_{A}_ETA_TOP - 1.0);
        m1 = a[0] + w * (b[0] - a[0]);
        m2 = a[1] + w * (b[1] - a[1]);
        return m1 + u * (m2 - m1);
    }}
    return M[lo] + w * (M[hi] - M[lo]);
}}

/* k_dir = s_d (1 + d a(T)), a(T) linear between the anchors and held outside (gimbal_friction.physics.direction) */
static inline double gf_{a}_direction_factor(double temperature_c, double velocity_rad_s)
{{
    double w = (temperature_c - GF_{A}_ASYMMETRY_COLD_C) / (GF_{A}_ASYMMETRY_WARM_C - GF_{A}_ASYMMETRY_COLD_C);
    double a;
    w = w < 0.0 ? 0.0 : (w > 1.0 ? 1.0 : w);
    a = GF_{A}_ASYMMETRY_COLD + (GF_{A}_ASYMMETRY_WARM - GF_{A}_ASYMMETRY_COLD) * w;
    return velocity_rad_s >= 0.0 ? GF_{A}_SCALE_POSITIVE * (1.0 + a) : GF_{A}_SCALE_NEGATIVE * (1.0 - a);
}}

{_c_correction(table)}static inline double gf_{a}_feedforward_nm(double temperature_c, double velocity_rad_s)
{{
    double tau;
    if (!isfinite(temperature_c) || !isfinite(velocity_rad_s)) {{
        return 0.0;
    }}
{_c_torque(table)}
    if (tau > GF_{A}_MAX_TORQUE_NM) {{
        tau = GF_{A}_MAX_TORQUE_NM;
    }} else if (tau < -GF_{A}_MAX_TORQUE_NM) {{
        tau = -GF_{A}_MAX_TORQUE_NM;
    }}
    return tau;
}}

#endif /* GIMBAL_FRICTION_{A}_H */
"""


def _c_torque(table: ExportTable) -> str:
    """The feedforward's torque statement of the C header (with the learned correction if the table has one)."""
    a = c_identifier(table.axis)
    A = a.upper()
    if table.correction is None or table.correction.empty:   # (exactly the model, as the node)
        return f"""    tau = tanh(velocity_rad_s / GF_{A}_VELOCITY_THRESHOLD_RAD_S)
          * gf_{a}_direction_factor(temperature_c, velocity_rad_s)
          * gf_{a}_friction_nm(temperature_c, velocity_rad_s);"""
    return f"""    {{
        double model = gf_{a}_direction_factor(temperature_c, velocity_rad_s)
                       * gf_{a}_friction_nm(temperature_c, velocity_rad_s);
        double odd, even;
        gf_{a}_correction_split_nm(temperature_c, velocity_rad_s, model, &odd, &even);
        tau = tanh(velocity_rad_s / GF_{A}_VELOCITY_THRESHOLD_RAD_S) * (model + odd) + even;
    }}"""


def _c_rows(table: Array) -> str:
    """A (rows, columns) array as the initialiser rows of a C 2-D array."""
    return ',\n'.join(f'    {{\n{_c_array(row, indent="        ")}\n    }}' for row in table)


def _c_correction(table: ExportTable) -> str:
    """The learned correction's arrays and lookup in the C header (:func:`~gimbal_friction.export.table.
    correction_nm`; empty without one)."""
    c = table.correction
    if c is None:
        return ''
    a = c_identifier(table.axis)
    A = a.upper()
    err = np.where(np.isnan(c.error_nm), -1.0, c.error_nm)
    cells = []
    for d, name in ((0, 'cw'), (1, 'ccw')):
        sense = 'v >= 0' if d == 0 else 'v < 0'
        cells.append(f"""/* error bound of the {name} cells ({sense}) per bin [N*m] (-1: unknown, one sample) */
static const double gf_{a}_correction_{name}_error_nm[GF_{A}_CORRECTION_N] = {{
{_c_array(err[d])}
}};

/* samples of the {name} cells per bin [-] */
static const double gf_{a}_correction_{name}_samples[GF_{A}_CORRECTION_N] = {{
{_c_array(c.samples[d].astype(float))}
}};
""")
    body = '\n'.join(cells)
    return f"""#define GF_{A}_CORRECTION_N {c.centres_c.shape[0]}  /* temperature bins of the learned correction */
#define GF_{A}_CORRECTION_OCTAVES {c.octaves}  /* speed octaves of its profile */
#define GF_{A}_CORRECTION_T0_C {_fmt(c.centres_c[0])}  /* centre of the first bin [degC] */
#define GF_{A}_CORRECTION_INV_BIN_PER_C {_fmt(c.inv_bin_per_c)}  /* 1 / bin width [1/degC] */
#define GF_{A}_CORRECTION_MIN_SPEED_RAD_S {_fmt(c.min_speed_rad_s)}  /* octave k centre: this * 2^(k+0.5) [rad/s] */
#define GF_{A}_CORRECTION_MAX_RELATIVE {_fmt(c.max_relative)}  /* |odd| <= this * |k_dir M| + floor [-] */
#define GF_{A}_CORRECTION_FLOOR_NM {_fmt(c.floor_nm)}  /* [N*m] */
#define GF_{A}_CORRECTION_MAX_INDEPENDENT_NM {_fmt(c.max_independent_nm)}  /* |even| <= max(that, this) [N*m] */

/* learned correction along the motion, odd = (S_cw + S_ccw)/2, per bin centre and octave centre [N*m] */
static const double gf_{a}_correction_odd_nm[GF_{A}_CORRECTION_N][GF_{A}_CORRECTION_OCTAVES] = {{
{_c_rows(c.odd_nm)}
}};

/* learned correction independent of the direction of motion, even = (S_cw - S_ccw)/2, per bin and octave [N*m] */
static const double gf_{a}_correction_even_nm[GF_{A}_CORRECTION_N][GF_{A}_CORRECTION_OCTAVES] = {{
{_c_rows(c.even_nm)}
}};

{body}
/* temperature bin i and weight w: linear between bin centres, held beyond the first and last (NaN: the first) */
static inline int gf_{a}_correction_bin(double temperature_c, double *w)
{{
    double x = (temperature_c - GF_{A}_CORRECTION_T0_C) * GF_{A}_CORRECTION_INV_BIN_PER_C;
    int i;
    if (x > 0.0 && x < GF_{A}_CORRECTION_N - 1) {{
        i = (int)x;
        *w = x - i;
    }} else if (x > 0.0) {{
        i = GF_{A}_CORRECTION_N - 2;
        *w = 1.0;
    }} else {{
        i = 0;
        *w = 0.0;
    }}
    return i;
}}

static inline void gf_{a}_correction_split_nm(double temperature_c, double velocity_rad_s, double model_nm,
                                              double *odd_nm, double *even_nm)
{{
    const double (*O)[GF_{A}_CORRECTION_OCTAVES] = gf_{a}_correction_odd_nm;
    const double (*E)[GF_{A}_CORRECTION_OCTAVES] = gf_{a}_correction_even_nm;
    double w, s = fabs(velocity_rad_s), y, f = 0.0, odd, even, m = fabs(model_nm), bound;
    int i = gf_{a}_correction_bin(temperature_c, &w), k = 0, hi = GF_{A}_CORRECTION_OCTAVES - 1;
    /* speed: y = log2(|v| / min speed) - 0.5, linear between octave centres, held beyond the first and last */
    y = s > GF_{A}_CORRECTION_MIN_SPEED_RAD_S ? log2(s / GF_{A}_CORRECTION_MIN_SPEED_RAD_S) - 0.5 : -1.0;
    if (y >= hi) {{
        k = hi;
    }} else if (y > 0.0) {{
        k = (int)y;
        f = y - k;
    }}
    odd = (1.0 - w) * O[i][k] + w * O[i + 1][k];
    even = (1.0 - w) * E[i][k] + w * E[i + 1][k];
    if (f > 0.0) {{
        double o1 = (1.0 - w) * O[i][k + 1] + w * O[i + 1][k + 1];
        double e1 = (1.0 - w) * E[i][k + 1] + w * E[i + 1][k + 1];
        odd = odd + f * (o1 - odd);
        even = even + f * (e1 - even);
    }}
    if (s < GF_{A}_CORRECTION_MIN_SPEED_RAD_S) {{  /* below the slowest speed learned: fades to 0 at zero speed */
        odd *= s / GF_{A}_CORRECTION_MIN_SPEED_RAD_S;
    }}
    if (!(m - m == 0.0)) {{  /* an infinite model (an absurd speed): no correction */
        *odd_nm = 0.0;
        *even_nm = 0.0;
        return;
    }}
    bound = GF_{A}_CORRECTION_MAX_RELATIVE * m + GF_{A}_CORRECTION_FLOOR_NM;
    if (!(-bound <= odd && odd <= bound)) {{
        odd = odd > 0.0 ? bound : -bound;
    }}
    if (bound < GF_{A}_CORRECTION_MAX_INDEPENDENT_NM) {{
        bound = GF_{A}_CORRECTION_MAX_INDEPENDENT_NM;
    }}
    if (!(-bound <= even && even <= bound)) {{
        even = even > 0.0 ? bound : -bound;
    }}
    *odd_nm = odd;
    *even_nm = even;
}}

static inline double gf_{a}_correction_nm(double temperature_c, double velocity_rad_s, double model_nm)
{{
    double odd, even;
    gf_{a}_correction_split_nm(temperature_c, velocity_rad_s, model_nm, &odd, &even);
    return velocity_rad_s >= 0.0 ? odd + even : odd - even;
}}

static inline double gf_{a}_correction_error_nm(double temperature_c, double velocity_rad_s)
{{
    const double *e = velocity_rad_s >= 0.0 ? gf_{a}_correction_cw_error_nm : gf_{a}_correction_ccw_error_nm;
    double w;
    int i = gf_{a}_correction_bin(temperature_c, &w);
    if (e[i] < 0.0 || e[i + 1] < 0.0) {{
        return -1.0;
    }}
    return e[i] + w * (e[i + 1] - e[i]);
}}

/* samples of the cell of velocity_rad_s's direction nearest to temperature_c [-] */
static inline double gf_{a}_correction_samples(double temperature_c, double velocity_rad_s)
{{
    double w;
    int i = gf_{a}_correction_bin(temperature_c, &w);
    return (velocity_rad_s >= 0.0 ? gf_{a}_correction_cw_samples : gf_{a}_correction_ccw_samples)[w < 0.5 ? i : i + 1];
}}

"""


#: node section of the exported ROS parameter file
ROS_NODE = 'friction_compensation'


def ros_parameters(table: ExportTable) -> dict[str, object]:
    """The ``<node>.ros__parameters.<axis>`` mapping of the ROS parameter file (SI; flat lists)."""
    g, o, s, p, r = table.grid, table.options, table.settings, table.params, table.report
    return {
        'joint': table.axis,
        'temperatures_c': [float(x) for x in g.t],
        'ln_switch_speed': [float(x) for x in g.ln_vs],
        'torque_lower_nm': [float(x) for x in g.lower_nm],
        'eta_breakpoints': [float(x) for x in g.eta],
        'torque_upper_nm': [float(x) for x in g.upper_nm.ravel()],
        'torque_upper_shape': [int(g.upper_nm.shape[0]), int(g.upper_nm.shape[1])],
        'max_speed_rad_s': float(o.max_speed_rad_s),
        'relative_error_bound': float(r.relative_error_bound),
        'max_relative_error': float(max(r.midpoint_max_relative_error, r.random_max_relative_error)),
        'velocity_threshold_rad_s': float(s.velocity_threshold_rad_s),
        'max_torque_nm': float(s.max_torque_nm),
        'direction_factor_positive': float(p.scale_positive),
        'direction_factor_negative': float(p.scale_negative),
        'direction_asymmetry_cold': float(p.direction_asymmetry_cold),
        'direction_asymmetry_warm': float(p.direction_asymmetry_warm),
        'direction_asymmetry_cold_c': float(p.direction_asymmetry_cold_c),
        'direction_asymmetry_warm_c': float(p.direction_asymmetry_warm_c),
        **_ros_correction(table),
    }


def _ros_correction(table: ExportTable) -> dict[str, object]:
    """The learned correction's entries of the ROS parameter file (none without one)."""
    c = table.correction
    if c is None:
        return {}
    err = np.where(np.isnan(c.error_nm), -1.0, c.error_nm)
    return {
        'correction_temperatures_c': [float(x) for x in c.centres_c],
        'correction_inv_bin_per_c': float(c.inv_bin_per_c),
        'correction_min_speed_rad_s': float(c.min_speed_rad_s),
        'correction_speeds_rad_s': [float(x) for x in c.octave_speeds_rad_s],
        'correction_shape': [int(c.odd_nm.shape[0]), int(c.odd_nm.shape[1])],
        'correction_odd_nm': [float(x) for x in c.odd_nm.ravel()],
        'correction_even_nm': [float(x) for x in c.even_nm.ravel()],
        'correction_max_relative': float(c.max_relative),
        'correction_floor_nm': float(c.floor_nm),
        'correction_max_independent_nm': float(c.max_independent_nm),
        'correction_cw_error_nm': [float(x) for x in err[0]],
        'correction_ccw_error_nm': [float(x) for x in err[1]],
        'correction_cw_samples': [int(x) for x in c.samples[0]],
        'correction_ccw_samples': [int(x) for x in c.samples[1]],
        'correction_cw_applied': [bool(x) for x in c.applied[0]],
        'correction_ccw_applied': [bool(x) for x in c.applied[1]],
    }


def render_ros_yaml(table: ExportTable, prov: Provenance) -> str:
    """ROS 2 parameter file (``friction_compensation: ros__parameters: <axis>: ...``) with provenance comments."""
    head = [
        *provenance_lines(table, prov),
        f'ROS parameters for an effort controller: {ROS_NODE}.<axis>.* (SI units).',
        'temperatures_c [degC]; ln_switch_speed [ln(rad/s)]; torque_lower_nm [N*m] per temperature;',
        'torque_upper_nm [N*m] row-major with shape torque_upper_shape = [rows, eta_breakpoints] (the first rows',
        'of temperatures_c); eta_breakpoints [-]; the feedforward settings and direction factors.',
        *LOOKUP_RULE,
        *([] if table.correction is None else [
            'correction_*: the learned correction, correction_odd_nm and correction_even_nm [N*m] row-major with shape',
            'correction_shape = [temperature bins, speed octaves] at the bin centres correction_temperatures_c [degC]',
            'and the octave centres correction_speeds_rad_s [rad/s] (see the correction lookup above); per cell (cw,',
            'ccw per bin) its error bound [N*m] (-1: unknown), samples and whether the guard applies it.']),
    ]
    doc = {ROS_NODE: {'ros__parameters': {c_identifier(table.axis): ros_parameters(table)}}}
    body: str = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=116)
    return ''.join(f'# {line}\n' for line in head) + body
