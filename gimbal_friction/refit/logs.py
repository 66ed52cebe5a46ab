"""Reading residual logs for a refit: per-joint sufficient statistics, streamed chunk by chunk with bounded memory;
and a learned correction against the refitted model (:func:`read_correction`, a second pass: the refitted model is
known only once the statistics of every row are in).

Used by ``gimbal-friction refit`` and by ``fleet`` (one unit per worker).
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator, Sequence, Sized
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from gimbal_friction.common.xp import ARRAY
from gimbal_friction.feedforward.correction import Correction, CorrectionSettings, model_identity
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.residual_read import ReadReport, iter_residual_rows
from gimbal_friction.refit.sufficient import SufficientStats, accumulate_rows
from gimbal_friction.streams.residual_row import ResidualRows

_Chunk = TypeVar('_Chunk', bound=Sized)

#: rows per chunk read from the logs (bounds the memory of a refit or a fleet worker)
CHUNK_ROWS = 1 << 18
#: rows of a joint scored by the candidate before they are learned and the candidate refitted (test, then train):
#: at least this many, and a twentieth of what the joint holds already (so the candidate is refitted about twenty
#: times per doubling of the data, whatever the log's length)
LEARN_ROWS = 250


class AxisData(NamedTuple):
    """What the logs held for one axis: the statistics, and what was skipped."""

    stats: SufficientStats
    rows: int
    skipped_nonfinite: int
    skipped_standstill: int
    held_out: SufficientStats | None = None   #: the direction left out by a direction filter (None: not read)


def _with_progress(chunks: Iterable[_Chunk], label: str) -> Iterator[_Chunk]:
    """``chunks`` as they come, with the running row count on a terminal's stderr (``<label>: <n> rows``)."""
    done = 0
    for chunk in chunks:
        yield chunk
        done += len(chunk)
        if sys.stderr.isatty():
            sys.stderr.write(f'\r{label}: {done} rows')
            sys.stderr.flush()
    if done and sys.stderr.isatty():
        sys.stderr.write('\n')


def read_stats(logs: Sequence[Path], *, joints: list[str] | None = None, direction: str = 'both',
               report: ReadReport | None = None, label: str = 'refit: reading',
               held_out: bool = False) -> dict[str, AxisData]:
    """Per-joint sufficient statistics of the logs, streamed chunk by chunk with bounded memory
    (:func:`~gimbal_friction.recording.residual_read.iter_residual_rows`; progress on a terminal's stderr);
    ``direction`` 'cw' or 'ccw' keeps one direction, and with ``held_out`` the other direction's statistics are
    kept beside it (:attr:`AxisData.held_out`: what a one-direction refit is then checked against)."""
    stats: dict[str, SufficientStats] = {}
    other: dict[str, SufficientStats] = {}
    opposite = {'cw': 'ccw', 'ccw': 'cw'}.get(direction) if held_out else None
    for chunk in _with_progress(iter_residual_rows(list(logs), chunk_rows=CHUNK_ROWS, report=report), label):
        accumulate_rows(chunk, stats, joints=joints, direction=direction)
        if opposite is not None:
            accumulate_rows(chunk, other, joints=joints, direction=opposite)
    return {j: AxisData(s, s.tally.rows, s.tally.skipped_nonfinite, s.tally.skipped_standstill,
                        other.get(j) if opposite is not None else None)
            for j, s in stats.items()}


class LearnedCorrection(NamedTuple):
    """A correction learned from residual logs, and what its gate refused."""

    correction: Correction
    rows: dict[str, int]                  #: rows read per configured joint [-]
    refused: dict[str, dict[str, int]]    #: samples refused per joint and reason [-]


def learn_rows(c: Correction, ff: Feedforward, rows: ResidualRows, refused: dict[str, dict[str, int]]) -> int:
    """Learn residual rows (in time order) into ``c``: test, then train, a block of a joint's rows at a time
    (:data:`LEARN_ROWS`; each block scored by the candidate fitted before it, then kept, then the candidate
    refitted), as the node's learner does between two steps. Each row's residual is its measured friction minus
    the model friction of ``ff`` at its temperature and velocity, both signed like the motion [N·m]
    (:meth:`Feedforward.model_nm`); refusals are
    added to ``refused`` (joint → reason → count); rows of joints not in ``c`` are ignored. Returns the rows of
    ``c``'s joints read."""
    n = 0
    for joint in np.unique(rows.joint).tolist():
        if joint not in c.identity.joints:
            continue
        k = np.flatnonzero(rows.joint == joint)
        t, v = rows.temperature_c[k], rows.velocity_rad_s[k]
        usable = np.isfinite(t) & np.isfinite(v)
        with np.errstate(invalid='ignore', over='ignore'):
            model = np.where(usable, np.sign(v) * ff.model_nm(joint, np.where(usable, v, 0.0),
                                                              np.where(usable, t, 20.0), ARRAY), np.nan)
            residual = rows.measured_nm[k] - model
        p = rows.position_rad[k]
        mine = refused.setdefault(joint, {})
        k0 = 0
        while k0 < k.size:
            step = max(LEARN_ROWS, c.stats(joint).samples() // 20)
            sl = slice(k0, k0 + step)
            for reason, m in c.learn_residuals(joint, t[sl], v[sl], p[sl], residual[sl], model[sl]).items():
                mine[reason] = mine.get(reason, 0) + m
            c.refit(joint)
            k0 += step
        n += int(k.size)
    return n


def read_correction(logs: Sequence[Path], axes: dict[str, AxisParams], *,
                    settings: CorrectionSettings | None = None,
                    feedforward_settings: FeedforwardSettings | None = None,
                    label: str = 'correction: reading') -> LearnedCorrection:
    """The learned correction of the residual logs against the model of ``axes`` (every configured joint, the
    refitted parameters layered in: the model the feedforward will run), streamed chunk by chunk.

    The rows are learned in the order the logs hold them (:func:`learn_rows`: each block scored out of sample
    before it is learned, the guard of the node's learner), then settled: every cell and term that earned its
    place on data it was not learned from is applied at once, the others hold back to the model.
    """
    ff = Feedforward(axes, feedforward_settings or FeedforwardSettings())
    c = Correction(settings or CorrectionSettings(), model_identity(axes))
    rows = dict.fromkeys(axes, 0)
    refused: dict[str, dict[str, int]] = {j: {} for j in axes}
    for chunk in _with_progress(iter_residual_rows(list(logs), chunk_rows=CHUNK_ROWS), label):
        for joint in np.unique(chunk.joint).tolist():
            if joint in axes:
                rows[joint] += int(np.count_nonzero(chunk.joint == joint))
        learn_rows(c, ff, chunk, refused)
    c.settle()
    return LearnedCorrection(c, rows, refused)


def correction_table(c: Correction) -> tuple[list[list[str]], list[dict[str, Any]]]:
    """The learned cells of ``c`` as table rows (joint, temperature bin [degC], direction, value [N*mm], std. error
    [N*mm], samples, applied or why held back by the guard, saturated) and as JSON records (values in N*mm and
    N*m)."""
    table: list[list[str]] = []
    records: list[dict[str, Any]] = []
    s = c.settings
    for joint in c.identity.joints:
        for cell in sorted(c.cells(joint), key=lambda r: (r['centre_c'], r['direction'])):
            lo, hi = cell['centre_c'] - 0.5 * s.temperature_bin_c, cell['centre_c'] + 0.5 * s.temperature_bin_c
            se = cell['std_error_nm']
            table.append([joint, f'{lo:g}..{hi:g}', cell['direction'], f'{1e3 * cell["value_nm"]:+.4f}',
                          '-' if se is None else f'{1e3 * se:.4f}', str(cell['samples']),
                          'yes' if cell['applied'] else f'held back: {cell["held_back"]}',
                          'yes' if cell['saturated'] else ''])
            records.append({'joint': joint, 'temperature_c': cell['centre_c'], 'temperature_bin_c': [lo, hi],
                            'direction': cell['direction'], 'value_nmm': 1e3 * cell['value_nm'],
                            'std_error_nmm': None if se is None else 1e3 * se, 'samples': cell['samples'],
                            'applied': cell['applied'], 'held_back': cell['held_back'], 'terms': cell['terms'],
                            'saturated': cell['saturated']})
    return table, records
