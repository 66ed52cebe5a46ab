"""The correction file: a :class:`~gimbal_friction.feedforward.correction.core.Correction` as YAML a user can read,
diff and version, read as untrusted input (no rclpy; YAML is imported when a file is read or written).

One job in one module: :func:`save` and :func:`load` (the writer and the reader of one format share its field names
and its rules; :func:`check` is the rule both apply, so nothing is written that would not be read back).

Content (version 3): ``format: gimbal_friction/correction``, ``version``, the units (``torque_unit: N*m``,
``temperature_unit: degC``, ``position_unit: rad``), ``model`` (the joints and the SHA-256 of their parameters: a
file learned against other parameters is refused), ``settings``
(:class:`~gimbal_friction.feedforward.correction.settings.CorrectionSettings`), ``temperature_edges_c`` and, per
joint:

- ``periods``: the ripple periods found in its residuals and their evidence (``period_rad``, ``period_deg``,
  ``amplitude`` [-] relative to the model friction, ``z`` = amplitude / its standard error, ``power`` = share of the
  residual variance it explains, ``points`` = position bins behind it);
- ``angle_range_rad``: the positions the applied terms were fitted over [rad] (null: none);
- ``applied``: per temperature bin with an applied term: ``speed_cw_nm`` / ``speed_ccw_nm`` (the speed profile along
  the motion per speed octave from ``min_speed_rad_s`` [N·m]), ``ripple`` (per period of ``ripple_periods_rad``: the
  cos and sin coefficients relative to the model friction [-]) and ``trend_nm`` (along the motion sin θ, cos θ − 1,
  then independent of the direction sin θ, cos θ − 1 [N·m]);
- ``cells``: per cell with samples (``direction`` cw: v > 0 / ccw, ``bin``, ``centre_c`` [°C]): what the cell says
  (``samples``, ``mean_nm``, ``value_nm`` = the applied profile's level, ``applied``, ``held_back`` = the guard's
  reason) and what learning resumes from: its rows (``octave``, ``position_bin`` (−1: no position), ``n``,
  ``sum_nm``, ``sum_model_nm``, ``sum_octave``), ``sum_sq_nm2`` and the guard's sums ``guard`` (see
  :data:`~gimbal_friction.feedforward.correction.core.GUARD_COLUMNS`);
- ``searched_at``: the samples at the last search for periods.

Last come ``samples_total`` per joint and ``sha256``, the SHA-256 of everything before that line: a file cut short
misses them and is refused; a file edited by hand no longer matches its ``sha256`` and is refused, unless the line
is deleted: then it is read as a deliberate edit, and :attr:`Loaded.note` says so (the node reports it).

Every value is checked, with the field named, before anything is used: numbers finite and in range, counts whole and
not negative, sums consistent with their counts (a row's mean residual within the learning gate, Σr² ≥ (Σr)²/n),
applied values within the bound the learning applies (``max_relative`` × the cell's largest mean |model| +
``floor_nm``). What is read is bounded first: a regular file (a FIFO or a device is refused without blocking) of at
most :data:`MAX_BYTES`, UTF-8, YAML nested at most :data:`MAX_DEPTH` deep. Versions 1 and 2 (a value and a speed
term per cell, an optional position map over a given period) are still read: their cells become one row each
without a position at their mean speed, their applied values a speed profile, their position map ripple periods
(the map's period and its harmonics) over every angle.

:func:`save` writes through a temporary file renamed over the target (a crash leaves the old file or the new one,
never half of one); :func:`remove_stale_temporaries` removes the temporaries a crash left behind. Numbers are
written with Python's ``repr``, so a round trip is exact.
"""

from __future__ import annotations

import hashlib
import math
import os
import stat
import time
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.common.files import write_bytes_atomic
from gimbal_friction.common.settings import settings_from
from gimbal_friction.feedforward.correction.core import GUARD_COLUMNS, Correction, applied_bound_nm
from gimbal_friction.feedforward.correction.fit import Params, empty_params
from gimbal_friction.feedforward.correction.periods import Period
from gimbal_friction.feedforward.correction.settings import (
    DIRECTIONS,
    RETIRED,
    CorrectionError,
    CorrectionSettings,
    ModelIdentity,
)
from gimbal_friction.feedforward.correction.stats import SUMS

__all__ = ['FORMAT', 'MAX_BYTES', 'MAX_DEPTH', 'UNITS', 'VERSION', 'Loaded', 'check', 'load', 'load_file',
           'remove_stale_temporaries', 'save', 'to_mapping']

FORMAT = 'gimbal_friction/correction'
VERSION = 3
#: versions :func:`load` reads
READS = (1, 2, 3)
#: largest file read [bytes] (a correction of a long service life is a few MB)
MAX_BYTES = 32 * 1024 * 1024
#: deepest YAML nesting read (the format needs 6)
MAX_DEPTH = 16
UNITS = {'torque_unit': 'N*m', 'temperature_unit': 'degC', 'position_unit': 'rad'}
#: the comment a saved file starts with: how to read it
HEADER = """\
# A learned friction correction (gimbal_friction), version 3. Per joint and temperature bin (5 degC by default), the
# correction added to the model friction |model| along the motion [N*m] is, for direction d (cw: v > 0, ccw: v < 0)
#   c_d = S_d(u) + rho(theta) * |model| + h1 sin(theta) + h2 (cos(theta) - 1)
#         + s_d (g1 sin(theta) + g2 (cos(theta) - 1))
#   u = log2(|v| / min_speed_rad_s) [-]: S_d is linear between octave centres (speed_cw_nm / speed_ccw_nm),
#   rho = sum over periods P of a cos(2 pi theta / P) + b sin(2 pi theta / P) [-], s_d = +1 cw, -1 ccw;
# applied as tau = tanh(v / v_th) (model + odd) + even with odd = (c_cw + c_ccw) / 2, even = (c_cw - c_ccw) / 2, each
# bounded by max_relative * |model| + floor_nm. 'cells' hold the residual sums learning resumes from and the guard's
# out-of-sample scores ('held_back' says why a cell is not applied). The last line is the SHA-256 of the lines before
# it: delete it to make a hand edit deliberate. Written by refit/fleet --correction-out or friction_feedforward.
"""


class Loaded(NamedTuple):
    """A correction read from a file, and what a reader should know about it."""

    correction: Correction
    note: str | None     #: e.g. a deliberate hand edit (no sha256), an older version converted (None: nothing)


# ---------------------------------------------------------------------------------------------------- writing
def _joint_mapping(c: Correction, joint: str) -> dict[str, Any]:
    s = c.settings
    st = c.joint(joint)
    p = st.applied
    stats = st.stats
    keys, sums = stats.rows()
    d, b, k, j, known = stats.decode(keys)
    cell = d * s.n_temperature + b
    info = {(r['direction'], r['bin']): r for r in c.cells(joint)}
    cells = []
    for cc in np.unique(cell).tolist():
        sel = np.flatnonzero(cell == cc)
        dd, bb = divmod(cc, s.n_temperature)
        r = info[(DIRECTIONS[dd], bb)]
        cells.append({'direction': DIRECTIONS[dd], 'bin': bb, 'centre_c': s.centre_c(bb), 'samples': r['samples'],
                      'mean_nm': r['mean_nm'], 'value_nm': r['value_nm'], 'applied': r['applied'],
                      'held_back': r['held_back'],
                      'octave': k[sel].tolist(), 'position_bin': np.where(known[sel], j[sel], -1).tolist(),
                      **{name: sums[sel, i].tolist() for i, name in enumerate(SUMS)},
                      'sum_sq_nm2': float(stats.cell_sq[cc]), 'guard': st.guard[dd, bb].tolist()})
    applied = []
    for bb in range(s.n_temperature):
        if np.any(p.speed_nm[:, bb]) or np.any(p.ripple[bb]) or np.any(p.trend_nm[bb]):
            applied.append({'bin': bb, 'centre_c': s.centre_c(bb), 'speed_cw_nm': p.speed_nm[0, bb].tolist(),
                            'speed_ccw_nm': p.speed_nm[1, bb].tolist(), 'ripple': p.ripple[bb].tolist(),
                            'trend_nm': p.trend_nm[bb].tolist()})
    return {'periods': [{'period_rad': q.period_rad, 'period_deg': math.degrees(q.period_rad),
                         'amplitude': q.amplitude, 'z': q.z, 'power': q.power, 'points': q.samples,
                         'span_rad': q.span_rad} for q in c.periods[joint]],
            'angle_range_rad': None if st.angle_range is None else list(st.angle_range),
            'ripple_periods_rad': p.periods_rad.tolist(), 'applied': applied, 'cells': cells,
            'searched_at': st.searched_at}


def to_mapping(c: Correction) -> dict[str, Any]:
    """The file's content (plain Python values), without the trailing ``sha256``."""
    return {'format': FORMAT, 'version': VERSION, **UNITS,
            'model': {'joints': list(c.identity.joints), 'params_sha256': c.identity.params_sha256},
            'settings': asdict(c.settings), 'temperature_edges_c': c.settings.edges_c(),
            'joints': {j: _joint_mapping(c, j) for j in c.identity.joints},
            # last: a file cut short (a full disk, a copy interrupted) misses it and is refused
            'samples_total': {j: c.stats(j).samples() for j in c.identity.joints}}


def _dump(mapping: dict[str, Any]) -> str:
    import yaml
    # one field per line (diffable), lists of numbers on one line each
    dumper: Any = type('Dumper', (getattr(yaml, 'CSafeDumper', yaml.SafeDumper),), {})
    dumper.add_representer(list, lambda d, x: d.represent_sequence(
        'tag:yaml.org,2002:seq', x, flow_style=not any(isinstance(v, (dict, list)) for v in x)
        or all(isinstance(v, list) and not any(isinstance(w, (dict, list)) for w in v) for v in x)))
    return str(yaml.dump(mapping, Dumper=dumper, sort_keys=False, width=1 << 16))


def save(c: Correction, path: str | os.PathLike[str]) -> None:
    """Write ``c`` to ``path`` atomically (a temporary file in the same folder, renamed over ``path``), after
    checking it reads back (:func:`check`: a state the reader would refuse is never written).

    Raises:
        CorrectionError: the correction would not read back, or the file cannot be written (one line).
    """
    mapping = to_mapping(c)
    try:
        check(mapping)
    except CorrectionError as err:
        raise CorrectionError(f'correction file {path}: not written, it would not read back: {err}') from None
    body = _dump(mapping)
    digest = hashlib.sha256(body.encode('utf-8')).hexdigest()
    text = HEADER + body + f'sha256: {digest}\n'
    write_bytes_atomic(Path(path), text.encode('utf-8'), fsync=True, what='correction file', error=CorrectionError)


def remove_stale_temporaries(path: str | os.PathLike[str], older_than_s: float = 5.0) -> list[Path]:
    """Remove the temporary files an interrupted :func:`save` of ``path`` left in its folder (named
    ``.<name>.*.tmp``, older than ``older_than_s`` [s]); the files removed."""
    target = Path(path)
    out: list[Path] = []
    try:
        candidates = list(target.parent.glob(f'.{target.name}.*.tmp'))
    except OSError:
        return out
    now = time.time()
    for tmp in candidates:
        try:
            if tmp.is_file() and not tmp.is_symlink() and now - tmp.stat().st_mtime > older_than_s:
                tmp.unlink()
                out.append(tmp)
        except OSError:
            continue
    return out


# ---------------------------------------------------------------------------------------------------- reading
def _read_bounded(path: str | os.PathLike[str]) -> str:
    """The text of ``path``: a regular file (opened without blocking, so a FIFO cannot hang the reader) of at most
    :data:`MAX_BYTES`, UTF-8."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0) | getattr(os, 'O_NOCTTY', 0))
    except OSError as err:
        raise CorrectionError(f'cannot read it ({err.strerror or err})') from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise CorrectionError('not a regular file (a FIFO, a device or a folder); name a correction file')
        if info.st_size > MAX_BYTES:
            raise CorrectionError(f'{info.st_size} bytes, more than the {MAX_BYTES} a correction file may have; '
                                  'name another file or relearn it')
        chunks = []
        size = 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            size += len(chunk)
            if size > MAX_BYTES:
                raise CorrectionError(f'more than the {MAX_BYTES} bytes a correction file may have; relearn it')
            chunks.append(chunk)
    except OSError as err:
        raise CorrectionError(f'cannot read it ({err.strerror or err})') from None
    finally:
        os.close(fd)
    try:
        return b''.join(chunks).decode('utf-8')
    except UnicodeDecodeError as err:
        raise CorrectionError(f'not UTF-8 text (byte {err.start}; a binary or damaged file); delete it') from None


def _parse(text: str) -> Any:
    """The YAML document of ``text``, its nesting checked on the parser's events before anything is built (a
    deeply nested document would exhaust the stack of the builder)."""
    import yaml
    loader = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
    try:
        depth = 0
        for event in yaml.parse(text, Loader=loader):
            if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                depth += 1
                if depth > MAX_DEPTH:
                    raise CorrectionError(f'YAML nested more than {MAX_DEPTH} deep; not a correction file, delete it')
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                depth -= 1
        return yaml.load(text, Loader=loader)  # noqa: S506  # a safe loader
    except yaml.YAMLError as err:
        raise CorrectionError(f'not valid YAML ({" ".join(str(err).split())}); delete it') from None
    except RecursionError:
        raise CorrectionError('YAML nested too deep; not a correction file, delete it') from None


def load_file(path: str | os.PathLike[str], expected: ModelIdentity | None = None) -> Loaded:
    """The correction in ``path`` and a note for the reader; with ``expected``, one learned against that model only.

    Raises:
        CorrectionError: one line naming the file, the cause and the fix: missing, unreadable, not a regular file,
            too big, not UTF-8, not YAML, nested too deep, not a correction file, another version, a field missing
            or out of range (named), edited (sha256), or another model.
    """
    name = f'correction file {path}'
    try:
        text = _read_bounded(path)
        body, digest = _split_digest(text)
        doc = _parse(body)
        note = None
        if isinstance(doc, dict) and doc.get('version') == VERSION:
            if digest is None:
                note = 'edited by hand (no sha256 line): read as a deliberate edit'
            elif hashlib.sha256(_strip_header(body).encode('utf-8')).hexdigest() != digest:
                raise CorrectionError('sha256 does not match its content: edited after it was written or damaged; '
                                      'restore it, relearn it, or delete the sha256 line to use a deliberate edit')
        c, converted = _from_mapping(doc)
    except (CorrectionError, ConfigError) as err:
        raise CorrectionError(f'{name}: {err.args[0]}') from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as err:
        if isinstance(err, KeyError):
            reason = f'field {err.args[0]!r} is missing (a file cut short or edited); restore it or relearn it'
        else:
            reason = (f'a field has a value of the wrong kind ({" ".join(str(err).split())}; a file cut short or '
                      'edited); restore it or relearn it')
        raise CorrectionError(f'{name}: {reason}') from None
    if expected is not None:
        c.check_identity(expected, name)
    return Loaded(c, converted or note)


def load(path: str | os.PathLike[str], expected: ModelIdentity | None = None) -> Correction:
    """:func:`load_file`'s correction."""
    return load_file(path, expected).correction


def _split_digest(text: str) -> tuple[str, str | None]:
    """(text before the ``sha256`` line, the digest) — (text, None) without one."""
    stripped = text.rstrip('\n')
    last = stripped.rsplit('\n', 1)
    if len(last) == 2 and last[1].startswith('sha256: '):
        return last[0] + '\n', last[1][len('sha256: '):].strip()
    return text, None


def _strip_header(body: str) -> str:
    """``body`` without the leading comment lines (the digest covers the YAML that :func:`save` dumped)."""
    lines = body.split('\n')
    i = 0
    while i < len(lines) and lines[i].startswith('#'):
        i += 1
    return '\n'.join(lines[i:])


def check(doc: Any) -> None:
    """Raise CorrectionError (one line naming the field) unless ``doc`` is a correction file's content that
    :func:`load` accepts."""
    _from_mapping(doc)


def _number(value: Any, field: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CorrectionError(f'{field} must be a number, not {type(value).__name__}')
    x = float(value)
    if not math.isfinite(x):
        raise CorrectionError(f'{field} = {value!r} is not finite; restore it or relearn it')
    if not lo <= x <= hi:
        raise CorrectionError(f'{field} = {value!r} lies outside [{lo:g}, {hi:g}]; restore it or relearn it')
    return x


def _count(value: Any, field: str) -> int:
    x = _number(value, field, 0.0, 1e15)
    if x != int(x):
        raise CorrectionError(f'{field} = {value!r} is not a whole number; restore it or relearn it')
    return int(x)


def _numbers(values: Any, field: str, n: int | None = None, lo: float = -math.inf, hi: float = math.inf) -> list[float]:
    if not isinstance(values, list):
        raise CorrectionError(f'{field} must be a list of numbers')
    if n is not None and len(values) != n:
        raise CorrectionError(f'{field} must hold {n} numbers, not {len(values)}')
    return [_number(v, f'{field}[{i}]', lo, hi) for i, v in enumerate(values)]


def _settings(doc: dict[str, Any], version: int) -> CorrectionSettings:
    given = doc['settings']
    if not isinstance(given, dict):
        raise CorrectionError('settings must be a mapping')
    names = {f.name for f in fields(CorrectionSettings)}
    if version == 3:
        if set(given) != names:
            missing, extra = sorted(names - set(given)), sorted(set(given) - names)
            raise CorrectionError(f'settings must name exactly the settings of version 3 (missing: '
                                  f'{", ".join(missing) or "none"}; unknown: {", ".join(extra) or "none"})')
        return settings_from(CorrectionSettings, given)
    # versions 1 and 2: their layout, today's defaults for the rest
    kept = {k: v for k, v in given.items() if k in names and k not in RETIRED}
    return settings_from(CorrectionSettings, kept)


def _from_mapping(doc: Any) -> tuple[Correction, str | None]:
    if not isinstance(doc, dict) or doc.get('format') != FORMAT:
        raise CorrectionError(f'not a correction file (format is not {FORMAT}); delete it or name another')
    version = doc.get('version')
    if version not in READS:
        raise CorrectionError(f'version {version!r} is not supported (this version reads '
                              f'{", ".join(map(str, READS))}); relearn it')
    for key, unit in UNITS.items():
        if doc.get(key) != unit:
            raise CorrectionError(f'{key} must be {unit}, not {doc.get(key)!r}')
    s = _settings(doc, version)
    edges = doc['temperature_edges_c']
    if version == 3 and (not isinstance(edges, list) or len(edges) != s.n_temperature + 1
                         or _numbers(edges, 'temperature_edges_c') != s.edges_c()):
        raise CorrectionError('temperature_edges_c do not match the settings; delete it')
    model = doc['model']
    if not isinstance(model, dict) or not isinstance(model.get('joints'), list):
        raise CorrectionError('model must name its joints')
    c = Correction(s, ModelIdentity(tuple(str(j) for j in model['joints']), str(model['params_sha256'])))
    joints = doc['joints']
    if not isinstance(joints, dict) or set(joints) != set(c.identity.joints):
        raise CorrectionError('joints do not match model.joints')
    if version == 3:
        for j, jd in joints.items():
            _read_joint_v3(c, str(j), jd)
        totals = doc['samples_total']
        if not isinstance(totals, dict) or {j: c.stats(j).samples() for j in c.identity.joints} != totals:
            raise CorrectionError('samples_total does not match the cells (a file cut short or edited); delete it')
        return c, None
    for j, cells in joints.items():
        _read_joint_old(c, str(j), cells or [], doc['settings'], version)
    if version == 2:
        totals = doc['samples_total']
        if not isinstance(totals, dict) or {j: c.stats(j).samples() for j in c.identity.joints} != totals:
            raise CorrectionError('samples_total does not match the cells (a file cut short or edited); delete it')
    return c, (f'a version-{version} file, read into version 3: its cells as one row each without a position, its '
               'values as speed profiles; saved as version 3')


def _read_joint_v3(c: Correction, j: str, jd: Any) -> None:
    s = c.settings
    nt, ns, npos = s.n_temperature, s.n_speed, s.n_position
    if not isinstance(jd, dict):
        raise CorrectionError(f'joint {j}: must be a mapping')
    where = f'joint {j}'
    periods = []
    for i, q in enumerate(jd['periods'] or []):
        f = f'{where}: periods[{i}]'
        periods.append(Period(_number(q['period_rad'], f'{f}.period_rad', 1e-6, math.pi),
                              _number(q['amplitude'], f'{f}.amplitude', 0.0, 1e6),
                              _number(q['z'], f'{f}.z', 0.0, 1e300), _number(q['power'], f'{f}.power', 0.0, 1.0),
                              _number(q['points'], f'{f}.points', 0.0, 1e15),
                              _number(q['span_rad'], f'{f}.span_rad', 0.0, 2 * math.pi)))
    c.periods[j] = tuple(periods)
    rng = jd['angle_range_rad']
    angle = None
    if rng is not None:
        lo, hi = _numbers(rng, f'{where}: angle_range_rad', 2, -math.pi - 1.0, math.pi + 1.0)
        if not lo <= hi:
            raise CorrectionError(f'{where}: angle_range_rad must be [low, high] with low <= high')
        angle = (lo, hi)
    slots = _numbers(jd['ripple_periods_rad'], f'{where}: ripple_periods_rad', None, 4.0 * s.position_resolution_rad
                     * (1.0 - 1e-9), max(s.ripple_period_max_rad, math.pi) * (1.0 + 1e-9))
    if len(slots) > 16:
        raise CorrectionError(f'{where}: ripple_periods_rad holds {len(slots)} periods, at most 16')
    st = c.joint(j)
    st.searched_at = _number(jd['searched_at'], f'{where}: searched_at', 0.0, 1e15)
    # rows
    keys: list[int] = []
    sums: list[list[float]] = []
    cell_sq = np.zeros(2 * nt)
    guard = np.zeros((2, nt, len(GUARD_COLUMNS)))
    seen = set()
    for i, rec in enumerate(jd['cells'] or []):
        f = f'{where}: cells[{i}]'
        if not isinstance(rec, dict) or rec.get('direction') not in DIRECTIONS:
            raise CorrectionError(f'{f}.direction must be cw or ccw')
        d = DIRECTIONS.index(rec['direction'])
        b = _count(rec['bin'], f'{f}.bin')
        if b >= nt or (d, b) in seen:
            raise CorrectionError(f'{f}.bin = {b} is out of range or repeated')
        seen.add((d, b))
        octave = rec['octave']
        if not isinstance(octave, list) or not octave:
            raise CorrectionError(f'{f}.octave must be a list of at least one octave')
        k = len(octave)
        ks = [_count(x, f'{f}.octave[{n}]') for n, x in enumerate(octave)]
        pos = [_number(x, f'{f}.position_bin[{n}]', -1, npos - 1) for n, x in enumerate(_list(rec['position_bin'],
                                                                                             f'{f}.position_bin', k))]
        n_ = [_number(x, f'{f}.n[{m}]', 1.0, 1e15) for m, x in enumerate(_list(rec['n'], f'{f}.n', k))]
        if any(x != int(x) for x in n_) or any(x != int(x) for x in pos):
            raise CorrectionError(f'{f}: n and position_bin must be whole numbers')
        if any(x >= ns for x in ks):
            raise CorrectionError(f'{f}.octave: an octave is >= speed_bins')
        sr = _numbers(rec['sum_nm'], f'{f}.sum_nm', k)
        sm = _numbers(rec['sum_model_nm'], f'{f}.sum_model_nm', k, 0.0, 1e15)
        su = _numbers(rec['sum_octave'], f'{f}.sum_octave', k, 0.0, 1e15)
        for m in range(k):
            gate = s.max_residual_relative * sm[m] + n_[m] * s.max_residual_floor_nm
            if abs(sr[m]) > gate + 1e-12 * (1 + abs(sr[m])):
                raise CorrectionError(f'{f}.sum_nm[{m}] = {sr[m]!r} lies beyond the learning gate for its '
                                      f'{n_[m]:g} samples (a hand edit or damage); restore it or relearn it')
            if su[m] > n_[m] * s.speed_bins * (1.0 + 1e-9):
                raise CorrectionError(f'{f}.sum_octave[{m}] is larger than its samples allow')
        samples = _count(rec['samples'], f'{f}.samples')
        if samples != round(sum(n_)):
            raise CorrectionError(f'{f}.samples = {samples} does not match its rows ({sum(n_):g})')
        sq = _number(rec['sum_sq_nm2'], f'{f}.sum_sq_nm2', 0.0, 1e15)
        if sq < (sum(sr) ** 2 / samples) * (1.0 - 1e-9) - 1e-300:
            raise CorrectionError(f'{f}.sum_sq_nm2 = {sq!r} is smaller than its sums allow (a hand edit or damage)')
        cell_sq[d * nt + b] = sq
        g = _numbers(rec['guard'], f'{f}.guard', len(GUARD_COLUMNS))
        if any(g[c_] < 0.0 for c_, name in enumerate(GUARD_COLUMNS)
               if not name.startswith('d_') and (name == 'open_n' or not name.startswith('open_'))):
            raise CorrectionError(f'{f}.guard: a count or sum of squares is negative')
        guard[d, b] = g
        for m in range(k):
            jj = int(pos[m]) if pos[m] >= 0 else npos
            keys.append(((d * nt + b) * ns + ks[m]) * (npos + 1) + jj)
            sums.append([n_[m], sr[m], sm[m], su[m]])
    if len(set(keys)) != len(keys):
        raise CorrectionError(f'{where}: a row appears twice')
    st.stats.set_rows(np.asarray(keys, dtype=np.int64), np.asarray(sums, dtype=float).reshape(-1, len(SUMS)),
                      cell_sq)
    st.guard = guard
    # applied: within the bound learning keeps to
    bounds = applied_bound_nm(st.stats)
    p = empty_params(s, np.asarray(slots))
    have_rows = np.zeros(nt, dtype=bool)
    for _, b in seen:
        have_rows[b] = True
    for i, rec in enumerate(jd['applied'] or []):
        f = f'{where}: applied[{i}]'
        b = _count(rec['bin'], f'{f}.bin')
        if b >= nt or not have_rows[b]:
            raise CorrectionError(f'{f}.bin = {b} has no samples (or is out of range); an applied value needs them')
        bound = float(bounds[b])
        p.speed_nm[0, b] = _numbers(rec['speed_cw_nm'], f'{f}.speed_cw_nm', ns, -bound * (1 + 1e-9),
                                    bound * (1 + 1e-9))
        p.speed_nm[1, b] = _numbers(rec['speed_ccw_nm'], f'{f}.speed_ccw_nm', ns, -bound * (1 + 1e-9),
                                    bound * (1 + 1e-9))
        rip = rec['ripple']
        if not isinstance(rip, list) or len(rip) != len(slots):
            raise CorrectionError(f'{f}.ripple must hold one [cos, sin] per ripple period')
        for q, pair in enumerate(rip):
            a, bb = _numbers(pair, f'{f}.ripple[{q}]', 2, -s.max_relative, s.max_relative)
            if math.hypot(a, bb) > s.max_relative * (1 + 1e-9):
                raise CorrectionError(f'{f}.ripple[{q}]: amplitude above max_relative')
            p.ripple[b, q] = (a, bb)
        tb = 10.0 * bound * (1 + 1e-9)
        p.trend_nm[b] = _numbers(rec['trend_nm'], f'{f}.trend_nm', 4, -tb, tb)
    st.applied = p
    st.angle_range = angle
    c.rebuild(j)


def _list(values: Any, field: str, n: int) -> list[Any]:
    if not isinstance(values, list) or len(values) != n:
        raise CorrectionError(f'{field} must be a list of {n} numbers')
    return values


def _read_joint_old(c: Correction, j: str, cells: Any, old_settings: dict[str, Any], version: int) -> None:
    """A version-1/2 joint: each cell one row without a position at its mean speed, its applied value a profile."""
    s = c.settings
    nt, ns, npos = s.n_temperature, s.n_speed, s.n_position
    v_ref = float(old_settings.get('speed_reference_rad_s', 0.0349066)) if version == 2 else 0.0349066
    period = float(old_settings.get('position_period_rad', 2 * math.pi))
    bins = int(old_settings.get('position_bins', 0))
    if not isinstance(cells, list):
        raise CorrectionError(f'joint {j}: cells must be a list')
    keys, sums = [], []
    cell_sq = np.zeros(2 * nt)
    p = empty_params(s)
    harmonics: dict[int, list[tuple[list[float], list[float]]]] = {}
    octave_v = s.min_speed_rad_s * 2.0 ** (np.arange(ns) + 0.5)
    for i, rec in enumerate(cells):
        f = f'joint {j}: cells[{i}]'
        if rec['direction'] not in DIRECTIONS:
            raise CorrectionError(f'{f}.direction must be cw or ccw')
        d = DIRECTIONS.index(rec['direction'])
        b = _count(rec['bin'], f'{f}.bin')
        if b >= nt:
            raise CorrectionError(f'{f}.bin = {b} is out of range')
        n = _count(rec['samples'], f'{f}.samples')
        if n == 0:
            continue
        sr = _number(rec['sum_nm'], f'{f}.sum_nm')
        sm = _number(rec['sum_abs_model_nm'], f'{f}.sum_abs_model_nm', 0.0)
        x_bar = _number(rec.get('sum_speed', n), f'{f}.sum_speed', 0.0) / n if version == 2 else 1.0
        speed = v_ref * max(x_bar, 1e-9) ** 1.5
        u = min(max(math.log2(max(speed, s.min_speed_rad_s) / s.min_speed_rad_s), 0.0), float(ns))
        k = min(int(u), ns - 1)
        keys.append(((d * nt + b) * ns + k) * (npos + 1) + npos)
        sums.append([float(n), sr, sm, n * u])
        cell_sq[d * nt + b] = _number(rec['sum_sq_nm2'], f'{f}.sum_sq_nm2', 0.0)
        value = _number(rec['value_nm'], f'{f}.value_nm')
        slope = _number(rec.get('speed_nm', 0.0), f'{f}.speed_nm') if version == 2 else 0.0
        ref = _number(rec.get('speed_ref', 1.0), f'{f}.speed_ref') if version == 2 else 1.0
        x_nodes = (octave_v / v_ref) ** (2.0 / 3.0)
        bound = s.max_relative * sm / n + s.floor_nm
        p.speed_nm[d, b] = np.clip(value + slope * (x_nodes - ref) if s.speed_term else value, -bound, bound)
        if bins and 'harmonics_cos' in rec:
            harmonics.setdefault(b, []).append((_numbers(rec['harmonics_cos'], f'{f}.harmonics_cos'),
                                                _numbers(rec['harmonics_sin'], f'{f}.harmonics_sin')))
    st = c.joint(j)
    st.stats.set_rows(np.asarray(keys, dtype=np.int64), np.asarray(sums, dtype=float).reshape(-1, len(SUMS)), cell_sq)
    if harmonics:
        h = max(len(a) for pairs in harmonics.values() for a, _ in pairs)
        periods = np.array([period / (k + 1) for k in range(h)])
        keep = (periods >= 4.0 * s.position_resolution_rad)
        p = Params(p.speed_nm, periods[keep], np.zeros((nt, int(keep.sum()), 2)), p.trend_nm)
        for b, pairs in harmonics.items():
            a = np.mean([np.pad(x, (0, h - len(x))) for x, _ in pairs], axis=0)[keep]
            bb = np.mean([np.pad(y, (0, h - len(y))) for _, y in pairs], axis=0)[keep]
            p.ripple[b, :, 0], p.ripple[b, :, 1] = np.clip(a, -s.max_relative, s.max_relative), \
                np.clip(bb, -s.max_relative, s.max_relative)
        st.angle_range = (-math.pi, math.pi)
    st.applied = p
    c.rebuild(j)
