"""Reading residual logs for a refit: per-joint sufficient statistics, streamed chunk by chunk with bounded memory.

Used by ``gimbal-friction refit`` and by ``fleet`` (one unit per worker).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from gimbal_friction.recording.residual_read import ReadReport, iter_residual_rows
from gimbal_friction.refit.sufficient import SufficientStats, accumulate_rows

#: rows per chunk read from the logs (bounds the memory of a refit or a fleet worker)
CHUNK_ROWS = 1 << 18


class AxisData(NamedTuple):
    """What the logs held for one axis: the statistics, and what was skipped."""

    stats: SufficientStats
    rows: int
    skipped_nonfinite: int
    skipped_standstill: int


def read_stats(logs: Sequence[Path], *, joints: list[str] | None = None, direction: str = 'both',
               report: ReadReport | None = None, label: str = 'refit: reading') -> dict[str, AxisData]:
    """Per-joint sufficient statistics of the logs, streamed chunk by chunk with bounded memory
    (:func:`~gimbal_friction.recording.residual_read.iter_residual_rows`; progress on a terminal's stderr)."""
    stats: dict[str, SufficientStats] = {}
    done = 0
    for chunk in iter_residual_rows(list(logs), chunk_rows=CHUNK_ROWS, report=report):
        accumulate_rows(chunk, stats, joints=joints, direction=direction)
        done += len(chunk)
        if sys.stderr.isatty():
            sys.stderr.write(f'\r{label}: {done} rows')
            sys.stderr.flush()
    if done and sys.stderr.isatty():
        sys.stderr.write('\n')
    return {j: AxisData(s, s.tally.rows, s.tally.skipped_nonfinite, s.tally.skipped_standstill)
            for j, s in stats.items()}
