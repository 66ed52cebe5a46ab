"""The correction file: a :class:`~gimbal_friction.feedforward.correction.Correction` as YAML a user can read, diff
and version (no rclpy; YAML is imported when a file is read or written).

Content: ``format: gimbal_friction/correction``, ``version: 2``, the units (``torque_unit: N*m``,
``temperature_unit: degC``, ``position_unit: rad``), ``model`` (the joints and the SHA-256 of their parameters,
:func:`~gimbal_friction.feedforward.correction.model_identity`: a file learned against other parameters is refused),
``settings`` (:class:`~gimbal_friction.feedforward.correction.CorrectionSettings`: bins, shrinkage ``prior_samples``,
bound, gate), ``temperature_edges_c`` and, per joint, one record per cell with data: ``direction`` (cw/ccw), ``bin``,
``centre_c`` [°C], ``value_nm`` [N·m] (applied, at the speed term ``speed_ref``), ``speed_nm`` [N·m] (applied: the
correction is ``value_nm + speed_nm · (x − speed_ref)`` with the speed term x = (clip(|v|, min_speed_rad_s,
100 rad/s) / speed_reference_rad_s)^(2/3)), ``samples``, ``sum_nm``, ``mean_nm``, ``std_error_nm`` [N·m],
``saturated``, and the sums learning resumes from (``sum_sq_nm2``, ``sum_abs_model_nm``, ``sum_speed``,
``sum_speed_sq``, ``sum_speed_residual_nm``). With a position map a cell also holds the applied relative ripple
``ripple_relative`` [-] at the position-bin centres (the correction adds ripple(θ) × |model|), the same sums per
position bin
(``position_samples``, ``position_sums_nm``, ``position_speed_sums``, ``position_speed_sq_sums``,
``position_speed_residual_sums_nm``, ``position_model_sums_nm``) and the ripple's harmonics ``harmonics_cos`` /
``harmonics_sin`` [-] (for reading: ripple(θ) ≈ Σ_k a_k cos(2πkθ/period) + b_k sin(2πkθ/period)). One field per
line; lists of numbers on one line. Last, ``samples_total`` per joint (a file cut short is refused).

Version 1 files (no speed term, an additive position map) are still read: ``speed_term: false``, ``speed_nm`` 0,
their position map turned into a relative ripple at the cell's mean |model| (equal there); their samples count as
taken at ``speed_reference_rad_s`` (the chamber test's 1/3 rpm), so learning on from them with ``speed_term`` learns
the speed term from the new samples.

:func:`save` writes through a temporary file renamed over the target (a crash leaves the old file or the new one,
never half of one); :func:`load` refuses a missing, corrupt, unknown-version or mismatched file with one line naming
the file, the cause and the fix (:class:`~gimbal_friction.feedforward.correction.CorrectionError`). Numbers are
written with Python's ``repr``, so a round trip is exact.
"""

from __future__ import annotations

import os
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.files import write_bytes_atomic
from gimbal_friction.common.settings import settings_from
from gimbal_friction.feedforward.correction import (
    DIRECTIONS,
    Correction,
    CorrectionError,
    CorrectionSettings,
    ModelIdentity,
)

__all__ = ['FORMAT', 'UNITS', 'VERSION', 'load', 'save', 'to_mapping']

FORMAT = 'gimbal_friction/correction'
VERSION = 2
#: the comment a saved file starts with: how to read it
HEADER = """\
# A learned friction correction (gimbal_friction). Per joint, per cell (direction cw: v >= 0 / ccw: v < 0, and a
# 5 degC temperature bin by default), the correction added to the model friction along the motion [N*m] is
#   c = value_nm + speed_nm * (x - speed_ref) + ripple(theta) * |model|,
#   x = (clip(|v|, min_speed_rad_s, 100 rad/s) / speed_reference_rad_s)^(2/3)   [-], ripple [-] (position map only),
# bounded by max_relative * |model| + floor_nm. samples = how much data a cell has; the sum_* fields are what
# learning resumes from. Written by gimbal-friction refit/fleet --correction-out or friction_feedforward's learning.
"""
#: versions :func:`load` reads (1: before the slope on the model friction)
READS = (1, 2)
#: settings a version-1 file does not hold, and what it meant
#: a version-2 cell's per-position-bin lists (with a position map) and sums (without one): state name -> key
_POSITION_LISTS = {'count': 'position_samples', 'sum_nm': 'position_sums_nm', 'sum_speed': 'position_speed_sums',
                   'sum_speed_sq': 'position_speed_sq_sums', 'sum_speed_res_nm': 'position_speed_residual_sums_nm',
                   'sum_model_nm': 'position_model_sums_nm', 'ripple': 'ripple_relative'}
_CELL_SUMS = {'count': 'samples', 'sum_nm': 'sum_nm', 'sum_speed': 'sum_speed', 'sum_speed_sq': 'sum_speed_sq',
              'sum_speed_res_nm': 'sum_speed_residual_nm', 'sum_model_nm': 'sum_abs_model_nm'}
V1_SETTINGS = {'speed_term': False, 'speed_reference_rad_s': CorrectionSettings().speed_reference_rad_s,
               'speed_prior_spread': CorrectionSettings().speed_prior_spread}
UNITS = {'torque_unit': 'N*m', 'temperature_unit': 'degC', 'position_unit': 'rad'}


def to_mapping(c: Correction) -> dict[str, Any]:
    """The file's content (plain Python values)."""
    return {'format': FORMAT, 'version': VERSION, **UNITS,
            'model': {'joints': list(c.identity.joints), 'params_sha256': c.identity.params_sha256},
            'settings': asdict(c.settings), 'temperature_edges_c': c.settings.edges_c(),
            'joints': {j: c.cells(j) for j in c.identity.joints},
            # last: a file cut short (a full disk, a copy interrupted) misses it and is refused
            'samples_total': {j: int(c.count[j].sum()) for j in c.identity.joints}}


def save(c: Correction, path: str | os.PathLike[str]) -> None:
    """Write ``c`` to ``path`` atomically (a temporary file in the same folder, renamed over ``path``).

    Raises:
        CorrectionError: the file cannot be written (one line).
    """
    import yaml
    # one field per line (diffable), lists of numbers on one line each
    dumper: Any = type('Dumper', (getattr(yaml, 'CSafeDumper', yaml.SafeDumper),), {})
    dumper.add_representer(list, lambda d, x: d.represent_sequence(
        'tag:yaml.org,2002:seq', x, flow_style=not any(isinstance(v, dict) for v in x)))
    text = HEADER + yaml.dump(to_mapping(c), Dumper=dumper, sort_keys=False, width=1 << 16)
    out = Path(path)
    write_bytes_atomic(out, text.encode('utf-8'), fsync=True, what='correction file', error=CorrectionError)


def load(path: str | os.PathLike[str], expected: ModelIdentity | None = None) -> Correction:
    """The correction in ``path``; with ``expected``, one learned against that model only.

    Raises:
        CorrectionError: one line naming the file, the cause and the fix: missing or unreadable, not YAML, not a
            correction file, another version, a field missing or out of range, or another model.
    """
    import yaml
    name = f'correction file {path}'
    try:
        with open(path, encoding='utf-8') as f:
            doc = yaml.load(f, Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))  # noqa: S506  # a safe loader
    except OSError as err:
        raise CorrectionError(f'{name}: cannot read it ({err.strerror or err})') from None
    except yaml.YAMLError as err:
        raise CorrectionError(f'{name}: not valid YAML ({" ".join(str(err).split())}); delete it') from None
    try:
        c = _from_mapping(doc)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, ConfigError) as err:
        if isinstance(err, (CorrectionError, ConfigError)):
            reason = str(err.args[0])
        elif isinstance(err, KeyError):
            reason = f'field {err.args[0]!r} is missing (a file cut short or edited); restore it or relearn it'
        else:
            reason = (f'a field has a value of the wrong kind ({" ".join(str(err).split())}; a file cut short or '
                      'edited); restore it or relearn it')
        raise CorrectionError(f'{name}: {reason}') from None
    if expected is not None:
        c.check_identity(expected, name)
    return c


def _from_mapping(doc: Any) -> Correction:
    if not isinstance(doc, dict) or doc.get('format') != FORMAT:
        raise CorrectionError(f'not a correction file (format is not {FORMAT}); delete it or name another')
    version = doc.get('version')
    if version not in READS:
        raise CorrectionError(f'version {version!r} is not supported (this version reads '
                              f'{", ".join(map(str, READS))}); relearn it')
    for key, unit in UNITS.items():
        if doc.get(key) != unit:
            raise CorrectionError(f'{key} must be {unit}, not {doc.get(key)!r}')
    names = {f.name for f in fields(CorrectionSettings)}
    given = dict(doc['settings'])
    if version == 1:
        names -= set(V1_SETTINGS)
    if set(given) != names:
        raise CorrectionError(f'settings must name exactly {", ".join(sorted(names))}')
    if version == 1:
        given |= V1_SETTINGS
    s = settings_from(CorrectionSettings, given)
    if doc['temperature_edges_c'] != s.edges_c():
        raise CorrectionError('temperature_edges_c do not match the settings; delete it')
    model = doc['model']
    c = Correction(s, ModelIdentity(tuple(str(j) for j in model['joints']), str(model['params_sha256'])))
    if set(doc['joints']) != set(c.identity.joints):
        raise CorrectionError('joints do not match model.joints')
    nt, npos = s.n_temperature, s.n_position
    for j, cells in doc['joints'].items():
        for rec in cells or ():
            b = int(rec['bin'])
            if not (0 <= b < nt) or rec['direction'] not in DIRECTIONS:
                raise CorrectionError(f'joint {j}: a cell has bin {b} or direction {rec["direction"]!r}, out of range')
            cell = DIRECTIONS.index(rec['direction']) * nt + b
            nodes = slice(cell * npos, (cell + 1) * npos)
            n = int(rec['samples'])
            value = float(rec['value_nm'])
            if version == 1:   # no speed sums: its samples count as taken at speed_reference_rad_s (x = 1)
                m_bar = float(rec['sum_abs_model_nm']) / n if n else 0.0
                if s.position_bins:
                    counts, sums = rec['position_samples'], rec['position_sums_nm']
                    ripple = [(float(x) - value) / m_bar if m_bar > 0.0 else 0.0 for x in rec['values_nm']]
                else:
                    counts, sums, ripple = [n], [rec['sum_nm']], [0.0]
                node = {'count': counts, 'sum_nm': sums, 'sum_speed': counts, 'sum_speed_sq': counts,
                        'sum_speed_res_nm': sums, 'sum_model_nm': [k * m_bar for k in counts], 'ripple': ripple}
                speed_nm, speed_ref = 0.0, 1.0
            else:
                if s.position_bins:
                    node = {name: rec[key] for name, key in _POSITION_LISTS.items()}
                else:
                    node = {name: [rec[key]] for name, key in _CELL_SUMS.items()} | {'ripple': [0.0]}
                speed_nm, speed_ref = float(rec['speed_nm']), float(rec['speed_ref'])
            if any(len(x) != npos for x in node.values()) or sum(int(k) for k in node['count']) != n:
                raise CorrectionError(f"joint {j}: a cell's position lists do not match position_bins/samples")
            for name, values in node.items():
                getattr(c, name)[j][nodes] = [int(k) for k in values] if name == 'count' else \
                    [float(x) for x in values]
            c.sum_sq_nm2[j][cell] = float(rec['sum_sq_nm2'])
            c.values_nm[j][cell], c.speed_nm[j][cell], c.speed_ref[j][cell] = value, speed_nm, speed_ref
        numbers = [getattr(c, name)[j] for name in Correction.STATE]
        if not all(np.all(np.isfinite(a)) for a in numbers) or np.any(c.count[j] < 0):
            raise CorrectionError(f'joint {j}: non-finite values or negative sample counts; delete it')
    if version > 1:
        totals = doc['samples_total']
        if not isinstance(totals, dict) or {j: int(c.count[j].sum()) for j in c.identity.joints} != totals:
            raise CorrectionError('samples_total does not match the cells (a file cut short or edited); delete it')
    c.rebuild()
    return c
