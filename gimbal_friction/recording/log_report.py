"""The residual logger's ``/diagnostics`` from what it logged (no rclpy): its own status and one per joint.

One job in one module: what ``residual_logger`` says about itself, testable without a node (the node publishes
:meth:`LoggerReport.statuses` as ``diagnostic_msgs``).

- ``gimbal_friction/residual_logger`` (hardware_id ``residual_logger``): ``logging`` / ``not logging``; ERROR with
  the write error while the log cannot be written; WARN for inputs refused, messages lost or an input that delivers
  nothing since the last report; ERROR (message prefixed) while a callback has failed. Values: the folder, the
  current file, files, messages, bytes, the residual counts, what waits for its feedforward, what was dropped, the
  temperature input's QoS, ``refused: <reason>`` per reason, the inputs' values and the callback errors.
- ``gimbal_friction/residual_logger/<joint>``: the residual RMS [N·m] and sample count per temperature bin
  (``rms_nm_at_<+20C|unknown>``, ``samples_at_...``), bins in order, unknown last.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from gimbal_friction.recording.residual_log import ResidualLogStats
from gimbal_friction.streams.diagnostics import ERROR, OK, WARN, Status, status


def rms_statuses(rms: Mapping[tuple[str, float | None], tuple[int, float]]) -> list[Status]:
    """One status per joint of ``ResidualStats.rms()`` ((joint, bin [°C] or None) -> (count, RMS [N·m])).

    >>> [(s.name, s.values) for s in rms_statuses({('el', None): (3, 0.5), ('el', -40.0): (2, 0.001)})]
    [('gimbal_friction/residual_logger/el', (('rms_nm_at_-40C', '0.001'), ('samples_at_-40C', '2'), \
('rms_nm_at_unknown', '0.5'), ('samples_at_unknown', '3')))]
    """
    by_axis: dict[str, dict[str, Any]] = {}
    for (joint, b), (n, value) in sorted(rms.items(), key=lambda kv: (kv[0][0], math.inf if kv[0][1] is None
                                                                      else kv[0][1])):
        tag = 'unknown' if b is None else f'{b:+g}C'
        by_axis.setdefault(joint, {})[f'rms_nm_at_{tag}'] = value
        by_axis[joint][f'samples_at_{tag}'] = n
    return [status(f'gimbal_friction/residual_logger/{joint}', OK, 'residual RMS per temperature bin', joint, vals)
            for joint, vals in by_axis.items()]


class LoggerReport:
    """The statuses of one residual logger, report after report (it remembers the counts of the last report)."""

    def __init__(self) -> None:
        self._reported: dict[str, int] = {}          # refusals per reason, as of the last report
        self._reported_errors: dict[str, int] = {}   # callback errors per kind, as of the last report

    def statuses(self, *, active: bool, error: str | None, folder: object | None, stats: ResidualLogStats | None,
                 counts: Mapping[str, int], temperature_reliable: bool, refused: Mapping[str, int],
                 lost: Mapping[str, int] | None = None, input_problems: Sequence[str] = (),
                 input_values: Mapping[str, Any] | None = None, errors: Mapping[str, int] | None = None,
                 rms: Mapping[tuple[str, float | None], tuple[int, float]] | None = None) -> list[Status]:
        """This report's statuses. ``counts``: ``residuals_logged``, ``paired_with_feedforward``,
        ``no_feedforward``, ``waiting_for_feedforward``, ``dropped``; ``refused``: refusals per reason in all;
        ``lost``: messages lost since the last report per topic; ``errors``: callback errors in all; ``rms``: the
        residual statistics (:func:`rms_statuses`)."""
        level = OK
        message = 'logging' if active else 'not logging'
        new_refused = {r: n - self._reported.get(r, 0) for r, n in refused.items() if n > self._reported.get(r, 0)}
        self._reported = dict(refused)
        new_lost = dict(lost or {})
        if error is not None:
            level, message = ERROR, f'not logging: {error}'
        elif new_refused or new_lost or input_problems:  # what happened since the previous report (totals: values)
            level, parts = WARN, list(input_problems)
            if new_refused:
                parts.append('inputs refused: ' + ', '.join(f'{r} {c}x' for r, c in sorted(new_refused.items())))
            if new_lost:
                parts.append('messages lost on the way: ' + ', '.join(f'{t} {n}' for t, n in sorted(new_lost.items())))
            message = '; '.join(parts)
        values: dict[str, Any] = {
            'folder': str(folder) if folder else 'none',
            'current_file': str(stats.current_file) if stats and stats.current_file else 'none',
            'files': len(stats.files) if stats else 0,
            'messages_logged': stats.messages if stats else 0,
            'bytes': stats.bytes if stats else 0,
            **{k: counts.get(k, 0) for k in ('residuals_logged', 'paired_with_feedforward', 'no_feedforward',
                                             'waiting_for_feedforward', 'dropped')},
            'temperature_qos': 'reliable' if temperature_reliable else 'best_effort',
        }
        for reason, count in sorted(refused.items()):
            values[f'refused: {reason}'] = count
        values.update(input_values or {})
        errors = dict(errors or {})
        values.update(errors)
        # ERROR only in the report after a callback failed (as the other nodes): the counts stay in the values
        new_errors = {k: n for k, n in errors.items() if n > self._reported_errors.get(k, 0)}
        self._reported_errors = errors
        if new_errors:
            level, message = ERROR, f'a callback failed (see values); {message}'
        return [status('gimbal_friction/residual_logger', level, message, 'residual_logger', values),
                *rms_statuses(rms or {})]
