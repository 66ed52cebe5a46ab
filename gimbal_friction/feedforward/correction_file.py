"""The correction file: a :class:`~gimbal_friction.feedforward.correction.Correction` as YAML a user can read, diff
and version (no rclpy; YAML is imported when a file is read or written).

Content: ``format: gimbal_friction/correction``, ``version: 1``, the units (``torque_unit: N*m``,
``temperature_unit: degC``, ``position_unit: rad``), ``model`` (the joints and the SHA-256 of their parameters,
:func:`~gimbal_friction.feedforward.correction.model_identity`: a file learned against other parameters is refused),
``settings`` (:class:`~gimbal_friction.feedforward.correction.CorrectionSettings`: bins, shrinkage ``prior_samples``,
bound, gate), ``temperature_edges_c`` and, per joint, one record per cell with data: ``direction`` (cw/ccw), ``bin``,
``centre_c`` [°C], ``value_nm`` (applied), ``samples``, ``sum_nm``, ``mean_nm``, ``std_error_nm`` [N·m],
``saturated``, and the sums learning resumes from (``sum_sq_nm2``, ``sum_abs_model_nm``). With a position map a cell
also holds the applied ``values_nm`` at the position-bin centres, ``position_samples``, ``position_sums_nm`` and the
map's harmonics ``harmonics_cos_nm`` / ``harmonics_sin_nm`` [N·m] (for reading: map(θ) ≈ value_nm + Σ_k a_k
cos(2πkθ/period) + b_k sin(2πkθ/period)). One field per line; lists of numbers on one line.

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
VERSION = 1
UNITS = {'torque_unit': 'N*m', 'temperature_unit': 'degC', 'position_unit': 'rad'}


def to_mapping(c: Correction) -> dict[str, Any]:
    """The file's content (plain Python values)."""
    return {'format': FORMAT, 'version': VERSION, **UNITS,
            'model': {'joints': list(c.identity.joints), 'params_sha256': c.identity.params_sha256},
            'settings': asdict(c.settings), 'temperature_edges_c': c.settings.edges_c(),
            'joints': {j: c.cells(j) for j in c.identity.joints}}


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
    text = yaml.dump(to_mapping(c), Dumper=dumper, sort_keys=False, width=1 << 16)
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
        reason = err.args[0] if isinstance(err, (CorrectionError, ConfigError)) else \
            f'{type(err).__name__} {" ".join(str(err).split())}'
        raise CorrectionError(f'{name}: {reason}') from None
    if expected is not None:
        c.check_identity(expected, name)
    return c


def _from_mapping(doc: Any) -> Correction:
    if not isinstance(doc, dict) or doc.get('format') != FORMAT:
        raise CorrectionError(f'not a correction file (format is not {FORMAT}); delete it or name another')
    if doc.get('version') != VERSION:
        raise CorrectionError(f'version {doc.get("version")!r} is not supported (this version reads {VERSION}); '
                              'relearn it')
    for key, unit in UNITS.items():
        if doc.get(key) != unit:
            raise CorrectionError(f'{key} must be {unit}, not {doc.get(key)!r}')
    names = {f.name for f in fields(CorrectionSettings)}
    if set(doc['settings']) != names:
        raise CorrectionError(f'settings must name exactly {", ".join(sorted(names))}')
    s = settings_from(CorrectionSettings, doc['settings'])
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
            if s.position_bins:
                counts, sums, vals = rec['position_samples'], rec['position_sums_nm'], rec['values_nm']
                if not len(counts) == len(sums) == len(vals) == npos or sum(counts) != rec['samples']:
                    raise CorrectionError(f"joint {j}: a cell's position lists do not match position_bins/samples")
            else:
                counts, sums, vals = [rec['samples']], [rec['sum_nm']], [rec['value_nm']]
            c.count[j][nodes] = [int(k) for k in counts]
            c.sum_nm[j][nodes] = [float(x) for x in sums]
            c.values_nm[j][nodes] = [float(x) for x in vals]
            c.sum_sq_nm2[j][cell] = float(rec['sum_sq_nm2'])
            c.sum_model_nm[j][cell] = float(rec['sum_abs_model_nm'])
        numbers = (c.count[j], c.sum_nm[j], c.values_nm[j], c.sum_sq_nm2[j], c.sum_model_nm[j])
        if not all(np.all(np.isfinite(a)) for a in numbers) or np.any(c.count[j] < 0):
            raise CorrectionError(f'joint {j}: non-finite values or negative sample counts; delete it')
    c.rebuild()
    return c
