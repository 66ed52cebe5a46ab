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
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import ConfigError, ModelDomainError
from gimbal_friction.common.files import ReadError, file_exists, read_text_bounded, write_bytes_atomic
from gimbal_friction.common.settings import settings_from
from gimbal_friction.common.xp import ARRAY
from gimbal_friction.feedforward.correction.core import GUARD_COLUMNS, Correction, applied_bound_nm
from gimbal_friction.feedforward.correction.fit import Params, empty_params
from gimbal_friction.feedforward.correction.periods import Period
from gimbal_friction.feedforward.correction.settings import (
    DIRECTIONS,
    RETIRED,
    CorrectionError,
    CorrectionSettings,
    ModelIdentity,
    model_identity,
)
from gimbal_friction.feedforward.correction.stats import SUMS
from gimbal_friction.physics.direction import direction_factors
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import FrictionTable
from gimbal_friction.physics.thermal import loose_fit_temperature
from gimbal_friction.physics.validity import validity_range

__all__ = ['FORMAT', 'MAX_BYTES', 'MAX_DEPTH', 'MAX_JOINTS', 'UNITS', 'VERSION', 'Loaded', 'check',
           'check_against_model', 'exists', 'load', 'load_file', 'remove_stale_temporaries', 'save', 'to_mapping']

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
            rec = {'bin': bb, 'centre_c': s.centre_c(bb), 'speed_cw_nm': p.speed_nm[0, bb].tolist(),
                   'speed_ccw_nm': p.speed_nm[1, bb].tolist(), 'ripple': p.ripple[bb].tolist(),
                   'trend_nm': p.trend_nm[bb].tolist()}
            if st.bin_ranges is not None:
                rng = st.bin_ranges[bb]
                rec['angle_range_rad'] = rng.tolist() if bool(np.all(np.isfinite(rng))) else None
            applied.append(rec)
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
    checking it reads back (:func:`check`, and at most :data:`MAX_BYTES`: a state the reader would refuse is never
    written).

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
    data = (HEADER + body + f'sha256: {digest}\n').encode('utf-8')
    if len(data) > MAX_BYTES:   # (the reader would refuse it: keep the file there is)
        raise CorrectionError(f'correction file {path}: not written, {len(data)} bytes is more than the {MAX_BYTES} '
                              'a correction file may have (rows over too many positions and temperatures); '
                              'coarsen correction_position_resolution_rad or start a new file')
    write_bytes_atomic(Path(path), data, fsync=True, what='correction file', error=CorrectionError)


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
#: most joints a correction file names [-]
MAX_JOINTS = 64
#: longest scalar read [characters] (the writer's longest is a held-back reason, far shorter)
MAX_SCALAR_CHARS = 1024
#: most entries of a mapping or list whose length the format does not set otherwise [-]
MAX_ENTRIES = 64
#: events between two looks at a reader's ``cancelled`` [-]
_CANCEL_EVERY = 4096
_READ_FIXES = {'not_regular': 'name a correction file', 'too_big': 'name another file or relearn it',
               'not_utf8': 'delete it', 'loop': 'point the link at a file or remove it',
               'missing': 'name an existing file', 'unreadable': 'check its permissions'}


def _read_bounded(path: str | os.PathLike[str]) -> str:
    """The text of ``path`` within the bounds of a correction file (:func:`~gimbal_friction.common.files.
    read_text_bounded`: a regular file opened without blocking, at most :data:`MAX_BYTES`, UTF-8)."""
    try:
        return read_text_bounded(path, MAX_BYTES, 'a correction file')
    except ReadError as err:
        raise CorrectionError(f'{err}; {_READ_FIXES[err.kind]}') from None


def exists(path: str | os.PathLike[str]) -> bool:
    """Whether a correction file is at ``path`` (False: none yet, so learning starts empty). A symbolic link loop, or
    a folder that cannot be searched, is not "no file yet": it is refused.

    Raises:
        CorrectionError: one line naming the file, the cause and the fix.
    """
    try:
        return file_exists(path)
    except ReadError as err:
        raise CorrectionError(f'correction file {path}: {err}; {_READ_FIXES[err.kind]}') from None


class _Limits:
    """How many entries each mapping and list of a correction file may hold: the shape the writer produces, from the
    settings read so far (the writer writes them before the joints; a file without them there gets the largest any
    settings allow)."""

    def __init__(self) -> None:
        self._settings: CorrectionSettings | None = None
        self._looked = False

    def settings(self, root: dict[Any, Any]) -> CorrectionSettings | None:
        """The settings of ``root`` (read whole by the time the joints come), None if absent or invalid."""
        if not self._looked:
            self._looked = True
            given = root.get('settings')
            if isinstance(given, dict):
                names = {f.name for f in fields(CorrectionSettings)}
                try:
                    self._settings = settings_from(CorrectionSettings,
                                                   {k: v for k, v in given.items() if k in names and k not in RETIRED})
                except (ConfigError, TypeError, ValueError):
                    self._settings = None   # (refused with its reason once the file is read)
        return self._settings

    def __call__(self, path: tuple[Any, ...], root: dict[Any, Any]) -> tuple[int, str]:
        """(most entries, the rule in words) of the mapping or list at ``path`` of the document ``root``."""
        n = len(path)
        head = path[0] if path else None
        if (head == 'model' and path[1:] == ('joints',)) or (head in ('joints', 'samples_total') and n == 1):
            return MAX_JOINTS, f'a correction file names at most {MAX_JOINTS} joints'
        if head == 'temperature_edges_c' and n == 1:
            s = self.settings(root)
            return (10001, 'at most 10001 edges') if s is None else (
                s.n_temperature + 1, "the settings' temperature bins + 1")
        if head != 'joints' or n < 2:
            return MAX_ENTRIES, 'no field of a correction file is longer'
        s = self.settings(root)
        nt = s.n_temperature if s is not None else 10000
        if root.get('version') in (1, 2):   # joints.<j>: a list of cells
            return (2 * nt, 'one cell per direction and temperature bin') if n == 2 else (
                MAX_ENTRIES if n == 3 else 10000, 'no field of a version-1/2 cell is longer')
        if n == 2:
            return MAX_ENTRIES, 'no field of a joint is longer'
        field = path[2]
        ns = s.n_speed if s is not None else 40
        if n == 3:
            return self._joint_field(field, s, nt)
        name = path[4] if n >= 5 else None
        if n == 5 and field == 'applied' and name == 'angle_range_rad':
            return 2, '[low, high]'
        if n == 5 and field == 'applied' and name in ('speed_cw_nm', 'speed_ccw_nm'):
            return ns, "one value per speed octave (the settings' speed_bins)"
        if n == 5 and field == 'applied' and name in ('ripple', 'trend_nm'):
            return (16, 'one [cos, sin] per ripple period') if name == 'ripple' else (4, 'four trend coefficients')
        if n == 6 and field == 'applied' and name == 'ripple':
            return 2, '[cos, sin]'
        if n == 5 and field == 'cells' and name in ('octave', 'position_bin', *SUMS):
            rows = ns * (s.n_position + 1) if s is not None else MAX_BYTES // 2
            return rows, 'a row per speed octave and position bin (+ 1) of the settings'
        if n == 5 and field == 'cells' and name == 'guard':
            return len(GUARD_COLUMNS), f'{len(GUARD_COLUMNS)} guard columns'
        return MAX_ENTRIES, 'no field of a joint is longer'

    @staticmethod
    def _joint_field(field: Any, s: CorrectionSettings | None, nt: int) -> tuple[int, str]:
        if field == 'periods':
            k = s.ripple_periods_max if s is not None else 16
            return k, f'the ripple periods found: at most ripple_periods_max = {k}'
        if field == 'ripple_periods_rad':
            return 16, 'at most 16 ripple periods'
        if field == 'angle_range_rad':
            return 2, '[low, high]'
        if field == 'applied':
            return nt, 'one per temperature bin'
        if field == 'cells':
            return 2 * nt, 'one per direction and temperature bin'
        return MAX_ENTRIES, 'no field of a joint is longer'


def _yaml() -> tuple[Any, Any, dict[str, list[tuple[str, Any]]], list[tuple[str, Any]]]:
    """PyYAML (imported when a file is read), its safe loader (libyaml's where present), and the resolver's rules of
    plain scalars per first character plus those for any character (the YAML 1.1 types its safe loader gives)."""
    import yaml
    rules: dict[Any, list[tuple[str, Any]]] = yaml.resolver.Resolver.yaml_implicit_resolvers
    wildcard = list(rules.get(None, []))
    return yaml, getattr(yaml, 'CSafeLoader', yaml.SafeLoader), {
        c: list(r) + wildcard for c, r in rules.items() if c is not None}, wildcard


#: a mapping's frame before its next key
_NO_KEY = object()
#: plain scalars that are a float or an integer by YAML 1.1's rules and mean the same to ``float`` / ``int``
_PLAIN_FLOAT = re.compile(r'[-+]?[0-9]+\.[0-9]*(?:[eE][-+][0-9]+)?\Z')
_PLAIN_INT = re.compile(r'[-+]?(?:0|[1-9][0-9]*)\Z')


def _parse(text: str, cancelled: Callable[[], bool] | None = None) -> Any:
    """The YAML document of ``text``, built from the parser's events with its bounds checked as it goes, so a hostile
    file is refused at its first entry too many, before anything large is built: nesting at most :data:`MAX_DEPTH`, a
    scalar at most :data:`MAX_SCALAR_CHARS` characters, every mapping and list within the length the writer gives it
    (:class:`_Limits`), no anchors, aliases or explicit tags (the writer writes none; an alias could multiply what is
    built), one document, no repeated key. Plain scalars get the types PyYAML's safe loader gives them. Interruptible:
    a signal is handled between two events, and ``cancelled`` (polled every few thousand events) returning True
    stops it."""
    yaml, loader, by_char, wildcard = _yaml()
    constructor = yaml.constructor.SafeConstructor()
    makers = constructor.yaml_constructors
    limits = _Limits()
    root: dict[Any, Any] = {}
    document: list[Any] = []
    # per open collection: [container, path, key awaiting its value (or _NO_KEY), entries, most entries, the rule]
    stack: list[list[Any]] = []

    def where(path: tuple[Any, ...]) -> str:
        return '.'.join(map(str, path)) or 'the document'

    def scalar(event: Any) -> Any:
        value: str = event.value
        if len(value) > MAX_SCALAR_CHARS:
            raise CorrectionError(f'a value of {len(value)} characters (at most {MAX_SCALAR_CHARS}); not a correction '
                                  'file, delete it')
        if not event.implicit[0]:
            return value    # quoted, or a block: a string
        if _PLAIN_FLOAT.match(value):   # the writer's numbers (what the rules below give them, faster)
            return float(value)
        if _PLAIN_INT.match(value):
            return int(value)
        tag = None
        for rule_tag, regexp in by_char.get(value[:1], wildcard):
            if regexp.match(value):
                tag = rule_tag
                break
        if tag is None or tag not in makers:
            return value
        if tag.endswith(':float'):
            try:
                return float(value)
            except ValueError:
                pass    # .inf, 1_0.5, sexagesimal: below
        elif tag.endswith(':int') and value.isdigit() and (value[0] != '0' or len(value) == 1):
            return int(value)
        return makers[tag](constructor, yaml.ScalarNode(tag, value))

    def add(value: Any, collection: bool) -> None:
        if not stack:
            if document:
                raise CorrectionError('more than one YAML document; not a correction file, delete it')
            document.append(value)
            if not collection:
                return
            path: tuple[Any, ...] = ()
        else:
            frame = stack[-1]
            container, parent, key = frame[0], frame[1], frame[2]
            if type(container) is dict:
                if key is _NO_KEY:    # this is a key
                    if collection:
                        raise CorrectionError(f'{where(parent)}: a key that is a mapping or a list; not a correction '
                                              'file, delete it')
                    if value in container:
                        raise CorrectionError(f'{where(parent)}: key {value!r} repeated; restore it or relearn it')
                    frame[2] = value
                    return
                frame[2] = _NO_KEY
                container[key] = value
            else:
                key = len(container)
                container.append(value)
            frame[3] += 1
            if frame[3] > frame[4]:
                raise CorrectionError(f'{where(parent)} holds more than {frame[4]} entries ({frame[5]}); not what the '
                                      'writer writes: delete it or relearn it')
            if not collection:
                return
            path = (*parent, key)
        if len(stack) >= MAX_DEPTH:
            raise CorrectionError(f'YAML nested more than {MAX_DEPTH} deep; not a correction file, delete it')
        most, rule = limits(path, document[0] if type(document[0]) is dict else root)
        stack.append([value, path, _NO_KEY, 0, most, rule])

    count = 0
    parser = loader(text)
    try:
        while True:
            event = parser.get_event()
            if event is None:
                break
            kind = type(event)
            if kind is yaml.ScalarEvent:
                if event.anchor is not None or event.tag not in (None, '!'):
                    raise CorrectionError(_special(event))
                top = stack[-1] if stack else None
                if top is not None and type(top[0]) is list:   # (most scalars: an entry of a list)
                    top[0].append(scalar(event))
                    top[3] += 1
                    if top[3] > top[4]:
                        raise CorrectionError(f'{where(top[1])} holds more than {top[4]} entries ({top[5]}); not '
                                              'what the writer writes: delete it or relearn it')
                else:
                    add(scalar(event), False)
            elif kind is yaml.MappingStartEvent or kind is yaml.SequenceStartEvent:
                if event.anchor is not None or event.tag not in (None, '!'):
                    raise CorrectionError(_special(event))
                add({} if kind is yaml.MappingStartEvent else [], True)
            elif kind is yaml.MappingEndEvent or kind is yaml.SequenceEndEvent:
                stack.pop()
            elif kind is yaml.AliasEvent:
                raise CorrectionError('a YAML alias (*...); the writer writes none, delete it or relearn it')
            count += 1
            if cancelled is not None and count % _CANCEL_EVERY == 0 and cancelled():
                raise CorrectionError('reading it was cancelled')
    except yaml.YAMLError as err:
        raise CorrectionError(f'not valid YAML ({" ".join(str(err).split())}); delete it') from None
    finally:
        dispose = getattr(parser, 'dispose', None)
        if dispose is not None:
            dispose()
    return document[0] if document else None


def _special(event: Any) -> str:
    what = f'an anchor (&{event.anchor})' if event.anchor is not None else f'an explicit tag ({event.tag})'
    return f'a YAML {what}; the writer writes none, delete it or relearn it'


def load_file(path: str | os.PathLike[str], expected: ModelIdentity | None = None, *,
              model: Mapping[str, AxisParams] | None = None,
              cancelled: Callable[[], bool] | None = None) -> Loaded:
    """The correction in ``path`` and a note for the reader; with ``expected``, one learned against that model only.

    ``model`` (joint -> the parameters the reader runs): every figure the file stores is checked against that model
    (:func:`check_against_model`: the mean |model| of every row within what the model gives over its temperature
    bin and speed octave, so the bound on applied values the file's own sums set is the one learning against this
    model keeps to); its identity must be the file's (``expected`` defaults to it). Reading has no shared state: it
    may run in a thread while the correction in use keeps serving; ``cancelled`` (polled every few thousand YAML
    events) returning True stops it with a CorrectionError.

    Raises:
        CorrectionError: one line naming the file, the cause and the fix: missing, unreadable, a symbolic link loop,
            not a regular file, too big, not UTF-8, not YAML, nested too deep, a list or mapping longer than the
            writer writes, not a correction file, another version, a field missing or out of range (named), a
            figure the model cannot give, edited (sha256), or another model.
    """
    name = f'correction file {path}'
    if model is not None and expected is None:
        expected = model_identity(model)
    try:
        text = _read_bounded(path)
        body, digest = _split_digest(text)
        doc = _parse(body, cancelled)
        note = None
        if isinstance(doc, dict) and doc.get('version') == VERSION:
            if digest is None:
                note = _no_digest_note(body)
            elif hashlib.sha256(_strip_header(body).encode('utf-8')).hexdigest() != digest:
                raise CorrectionError('sha256 does not match its content: edited after it was written or damaged; '
                                      'restore it, relearn it, or delete the sha256 line to use a deliberate edit')
        c, converted = _from_mapping(doc)
        if expected is not None:
            c.check_identity(expected, name)
        if model is not None:   # (versions 1 and 2 kept a cell's rows at one speed: over every speed)
            check_against_model(c, model, speed_octaves=converted is None)
    except (CorrectionError, ConfigError) as err:
        message = err.args[0]
        raise CorrectionError(message if message.startswith(name) else f'{name}: {message}') from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as err:
        if isinstance(err, KeyError):
            reason = f'field {err.args[0]!r} is missing (a file cut short or edited); restore it or relearn it'
        else:
            reason = (f'a field has a value of the wrong kind ({" ".join(str(err).split())}; a file cut short or '
                      'edited); restore it or relearn it')
        raise CorrectionError(f'{name}: {reason}') from None
    return Loaded(c, converted or note)


def _no_digest_note(body: str) -> str:
    """What a version-3 file without its ``sha256`` line may be: with the writer's header intact it may equally be
    a file cut short just before that last line (a copy or a save interrupted) or a deliberate edit; without the
    header it was rewritten by hand or by a tool."""
    if body.startswith(HEADER):
        return ('no sha256 line: either deleted by hand to make an edit deliberate, or the file was cut short just '
                'before that last line (an interrupted copy or save; everything before it is whole and checked); read '
                'as a deliberate edit: if nobody edited it, restore it from a copy')
    return 'edited by hand (no sha256 line, and the header the writer writes is gone): read as a deliberate edit'


def load(path: str | os.PathLike[str], expected: ModelIdentity | None = None, *,
         model: Mapping[str, AxisParams] | None = None) -> Correction:
    """:func:`load_file`'s correction."""
    return load_file(path, expected, model=model).correction


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


# ---------------------------------------------------------------------------------------------------- the model
#: relative slack of :func:`check_against_model` [-]: the model's jump where Palmgren's Eq. 9 switches branch (0.8 %),
#: its table's interpolation (2e-7) and a temperature grid inside a bin; a figure off by more was not learned
#: against this model
MODEL_SLACK = 0.02
#: temperatures per bin and speeds per octave :func:`check_against_model` evaluates the model at [-], and the step of
#: its table [°C] (the contact torques interpolated to ~1e-6, far inside the slack)
_BIN_POINTS, _OCTAVE_POINTS, _TABLE_STEP_C = 11, 5, 0.25


def _model_span_nm(params: AxisParams, s: CorrectionSettings, bins: NDArray[np.int64], lo_v: NDArray[np.float64],
                   hi_v: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The least and the largest model friction along the motion, k_d M [N·m] (rows: cw, ccw), over each
    temperature bin of ``bins`` and speeds ``lo_v…hi_v`` [rad/s] (one per bin): as the feedforward's table gives it
    (over the credible range, once its default; now the model's validity range, where a temperature outside is used
    at the edge: either may have learned the file)."""
    edges = np.asarray(s.edges_c())
    frac = np.linspace(0.0, 1.0, _BIN_POINTS)
    t = edges[bins, None] + frac[None, :] * s.temperature_bin_c                              # (rows, points)
    kink = loose_fit_temperature(params)
    t = np.concatenate([t, np.clip(np.full((len(bins), 1), kink if math.isfinite(kink) else edges[0]),
                                   edges[bins, None], edges[bins + 1, None])], axis=1)
    r = validity_range(params)
    lows, highs = [], []
    for temps in (np.clip(t, r.low_c, r.high_c), t):
        try:
            with np.errstate(all='ignore'):
                table = FrictionTable(params, float(temps.min()), max(float(temps.max()), float(temps.min()) + 1.0),
                                      _TABLE_STEP_C)
        except (ModelDomainError, ConfigError):
            continue   # the equations do not reach there: no feedforward evaluated them
        u = np.linspace(0.0, 1.0, _OCTAVE_POINTS)
        v = np.exp(np.log(lo_v)[:, None] + u[None, :] * np.log(hi_v / lo_v)[:, None])        # (rows, speeds)
        tt = np.broadcast_to(temps[:, :, None], (*temps.shape, v.shape[1]))
        vv = np.broadcast_to(v[:, None, :], tt.shape)
        with np.errstate(all='ignore'):
            m = table.magnitude_nm(tt.ravel(), vv.ravel(), ARRAY).reshape(tt.shape)
            k_pos, k_neg = direction_factors(params, tt, ARRAY)
        for k in (k_pos, k_neg):
            along = np.where(np.isfinite(k * m), k * m, np.nan)
            lows.append(np.nanmin(along, axis=(1, 2)))
            highs.append(np.nanmax(along, axis=(1, 2)))
    if not lows:
        nan = np.full(len(bins), np.nan)
        return np.stack([nan, nan]), np.stack([nan, nan])
    low = np.stack([np.fmin.reduce(lows[0::2]), np.fmin.reduce(lows[1::2])])
    high = np.stack([np.fmax.reduce(highs[0::2]), np.fmax.reduce(highs[1::2])])
    return low, high


def check_against_model(c: Correction, model: Mapping[str, AxisParams], *, speed_octaves: bool = True) -> None:
    """Check every figure of ``c`` that depends on the model against ``model`` (joint -> the parameters it was
    learned against, as the node runs them): each row's mean |model| (Σ model / n) must lie within what the model
    gives over the row's temperature bin and speed octave (``speed_octaves`` False: over every speed, for rows
    converted from versions 1 and 2), :data:`MODEL_SLACK` either way. The bound on applied values (``max_relative``
    × the largest mean |model| of a bin + ``floor_nm``), checked when the file was read, then is the one learning
    against this model keeps to: a file moves the feedforward no further than the node could have learned to.

    Raises:
        CorrectionError: one line naming the joint, the cell and the figure (no file name: the caller adds it).
    """
    s = c.settings
    ns = s.n_speed
    top = max(s.min_speed_rad_s * 2.0 ** ns, s.max_speed_rad_s)   # the last octave holds every faster sample learned
    for joint in c.identity.joints:
        params = model.get(joint)
        if params is None:
            raise CorrectionError(f'joint {joint}: not in the model given to check it against')
        st = c.joint(joint)
        keys, sums = st.stats.rows()
        if not keys.size:
            continue
        d, b, k, _, _ = st.stats.decode(keys)
        mean = sums[:, 2] / sums[:, 0]
        octave = k if speed_octaves else np.zeros_like(k)
        lo_v = s.min_speed_rad_s * 2.0 ** octave.astype(float)
        hi_v = np.where(octave < ns - 1, 2.0 * lo_v, top)
        if not speed_octaves:   # (a version-1/2 cell's row: its samples at any speed)
            lo_v, hi_v = np.full(k.shape, s.min_speed_rad_s), np.full(k.shape, top)
        combos, first, inverse = np.unique(np.stack([b, octave]), axis=1, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
        low, high = _model_span_nm(params, s, combos[0], lo_v[first], hi_v[first])
        row_low, row_high = low[d, inverse], high[d, inverse]
        bad = ~((mean >= row_low * (1.0 - MODEL_SLACK) - 1e-15) & (mean <= row_high * (1.0 + MODEL_SLACK) + 1e-15))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            dd, bb = int(d[i]), int(b[i])
            span = (f'{row_low[i]:.4g}..{row_high[i]:.4g} N*m' if np.isfinite(row_low[i]) else
                    'nothing (the model does not reach there)')
            raise CorrectionError(f'joint {joint}: cell {DIRECTIONS[dd]} bin {bb} ({s.centre_c(bb):g} degC) claims a '
                                  f'mean |model| of {mean[i]:.4g} N*m where the model it names gives {span} over the '
                                  'bin and speed octave: not learned against this model (a hand edit or damage); '
                                  'restore it or relearn it')


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
    levels: dict[tuple[int, int], tuple[float, str]] = {}
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
        # what the cell says, as the writer derived it from these sums
        _centre(rec['centre_c'], s.centre_c(b), f'{f}.centre_c')
        mean = _number(rec['mean_nm'], f'{f}.mean_nm')
        if abs(mean - sum(sr) / samples) > 1e-9 * (abs(mean) + sum(map(abs, sr)) / samples) + 1e-300:
            raise CorrectionError(f'{f}.mean_nm = {mean!r} is not the mean of its sums ({sum(sr) / samples!r}); '
                                  'restore it or relearn it')
        levels[(d, b)] = (_number(rec['value_nm'], f'{f}.value_nm'), f'{f}.value_nm')
        if not isinstance(rec['applied'], bool) or not isinstance(rec['held_back'], str):
            raise CorrectionError(f'{f}: applied must be true or false and held_back a text')
        g = _numbers(rec['guard'], f'{f}.guard', len(GUARD_COLUMNS))
        if any(g[c_] < 0.0 for c_, name in enumerate(GUARD_COLUMNS)
               if not name.startswith('d_') and (name == 'open_n' or not name.startswith('open_'))):
            raise CorrectionError(f'{f}.guard: a count or sum of squares is negative')
        # (the scores are of samples the cell then learned, forgetting: no more of them, no larger squares)
        if g[0] > samples * (1.0 + 1e-9) or g[1] > sq * (1.0 + 1e-9) + 1e-300:
            raise CorrectionError(f'{f}.guard: it scores more samples or larger squared residuals than the cell '
                                  'holds (a hand edit or damage); restore it or relearn it')
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
    for (_, b), (level, f) in levels.items():
        if abs(level) > float(bounds[b]) * (1 + 1e-9) + 1e-300:
            raise CorrectionError(f'{f} = {level!r} lies beyond the bound learning keeps to ({float(bounds[b]):.4g} '
                                  'N*m); restore it or relearn it')
    p = empty_params(s, np.asarray(slots))
    have_rows = np.zeros(nt, dtype=bool)
    for _, b in seen:
        have_rows[b] = True
    travel: dict[int, Any] = {}
    for i, rec in enumerate(jd['applied'] or []):
        f = f'{where}: applied[{i}]'
        b = _count(rec['bin'], f'{f}.bin')
        if b >= nt or not have_rows[b]:
            raise CorrectionError(f'{f}.bin = {b} has no samples (or is out of range); an applied value needs them')
        _centre(rec['centre_c'], s.centre_c(b), f'{f}.centre_c')
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
        travel[b] = _bin_travel(rec, f, angle)
    st.applied = p
    st.angle_range = angle
    st.bin_ranges = _bin_ranges(travel, nt, where)
    c.rebuild(j)


_NO_TRAVEL = object()


def _bin_travel(rec: Any, f: str, angle: tuple[float, float] | None) -> Any:
    """The travel of an applied bin ``rec`` ([low, high] within the joint's ``angle``, None: no positions), or
    :data:`_NO_TRAVEL` where the record has none (a file written before the travel was kept per bin)."""
    if not isinstance(rec, dict) or 'angle_range_rad' not in rec:
        return _NO_TRAVEL
    rng = rec['angle_range_rad']
    if rng is None:
        return None
    lo, hi = _numbers(rng, f'{f}.angle_range_rad', 2, -math.pi - 1.0, math.pi + 1.0)
    tol = 1e-9
    if not lo <= hi or angle is None or lo < angle[0] - tol or hi > angle[1] + tol:
        raise CorrectionError(f"{f}.angle_range_rad must be [low, high] with low <= high within the joint's "
                              'angle_range_rad; restore it or relearn it')
    return lo, hi


def _bin_ranges(travel: dict[int, Any], nt: int, where: str) -> NDArray[np.float64] | None:
    """The per-bin travel of a joint's applied bins (bins, 2; NaN: none), None when no record gives one (an older
    file: the joint's travel holds for every bin); a file that gives it for some applied bins only is refused."""
    given = [b for b, r in travel.items() if r is not _NO_TRAVEL]
    if not given:
        return None
    if len(given) != len(travel):
        raise CorrectionError(f'{where}: angle_range_rad is given for some applied bins and not for others; restore '
                              'it or relearn it')
    out = np.full((nt, 2), np.nan)
    for b, r in travel.items():
        if r is not None:
            out[b] = r
    return out


def _centre(value: Any, centre_c: float, field: str) -> None:
    if abs(_number(value, field) - centre_c) > 1e-9 * (1.0 + abs(centre_c)):
        raise CorrectionError(f'{field} = {value!r} is not the centre of its bin ({centre_c:g} degC); restore it or '
                              'relearn it')


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
        if abs(value) > bound * (1 + 1e-9) + 1e-300:
            raise CorrectionError(f'{f}.value_nm = {value!r} lies beyond the bound learning keeps to '
                                  f'(max_relative x its mean |model| + floor_nm = {bound:.4g} N*m); restore it or '
                                  'relearn it')
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
