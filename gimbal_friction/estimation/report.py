"""The estimator's ``/diagnostics`` from its logic (no rclpy): one status per joint and one for the rest.

One job in one module: what ``friction_estimator`` says about itself, from
:class:`~gimbal_friction.estimation.estimator.EstimatorLogic` and what the node knows of its inputs, testable
without a node (the node publishes :meth:`EstimatorReport.statuses` as ``diagnostic_msgs``).

- ``gimbal_friction/estimator/<joint>`` (hardware_id = joint): ``accepted``, ``pending``,
  ``waiting_for_temperature``, the last sample (friction [N·m], stamp [s], method), the joint's K_T [N·m/A], I_0
  [A] and J [kg·m²], and ``rejected: <reason>`` per reason seen. WARN while no sample was accepted, and when bad
  inputs (:data:`~gimbal_friction.estimation.estimator.INPUT_REASONS`, not the steady-state/observer verdicts) were
  rejected since the last report.
- ``gimbal_friction/estimator`` (inputs of no configured joint, the temperature, the inputs' delivery):
  ``temperature_c``, ``rejected_temperature: <reason>``, the inputs' values, the callback errors; WARN for
  temperatures rejected, messages lost or an input that delivers nothing since the last report, ERROR for a
  callback that failed since then.

A cause keeps its status at WARN for one report: back to OK once it has gone for a report period.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.estimation.estimator import INPUT_REASONS, UNKNOWN_JOINT, EstimatorLogic
from gimbal_friction.streams.diagnostics import ERROR, OK, WARN, Status, status
from gimbal_friction.streams.measurement import METHOD_NAMES


def _new(counts: Mapping[str, int], previous: Mapping[str, int]) -> dict[str, int]:
    """The counts that grew since ``previous``, by how much."""
    return {r: c - previous.get(r, 0) for r, c in counts.items() if c > previous.get(r, 0)}


class EstimatorReport:
    """The statuses of one estimator, report after report (it remembers the counts of the last report)."""

    def __init__(self) -> None:
        self._last_counts: dict[str, dict[str, int]] = {}

    def statuses(self, logic: EstimatorLogic, *, lost: Mapping[str, int] | None = None,
                 input_problems: Sequence[str] = (), input_values: Mapping[str, Any] | None = None,
                 errors: Mapping[str, int] | None = None) -> list[Status]:
        """This report's statuses: one per configured joint, then ``gimbal_friction/estimator``.

        ``lost``: messages lost on the way since the last report, per topic; ``input_problems``: the inputs that
        deliver nothing (topic and cause); ``input_values``: the inputs' counts; ``errors``: callback errors
        (``callback error: <kind>`` -> count, in all)."""
        counters = logic.counters
        out = []
        failed = False
        for axis in [*logic.order, UNKNOWN_JOINT]:
            rejected = counters.rejected.get(axis, {})
            new_bad = {r: c for r, c in _new(rejected, self._last_counts.get(axis, {})).items() if r in INPUT_REASONS}
            self._last_counts[axis] = dict(rejected)
            problems = []
            if new_bad:  # only what happened since the last report keeps the status at WARN
                problems.append('bad inputs rejected: ' + ', '.join(f'{r} {c}x' for r, c in sorted(new_bad.items())))
            if axis == UNKNOWN_JOINT:
                values: dict[str, Any] = {
                    'temperature_c': logic.last_temperature_c if math.isfinite(logic.last_temperature_c) else 'none'}
                for reason, count in sorted(counters.temperature_rejected.items()):
                    values[f'rejected_temperature: {reason}'] = count
                new_t = _new(counters.temperature_rejected, self._last_counts.get('temperature', {}))
                self._last_counts['temperature'] = dict(counters.temperature_rejected)
                if new_t:
                    problems.append('temperatures rejected: '
                                    + ', '.join(f'{r} {c}x' for r, c in sorted(new_t.items())))
                new_lost = {t: n for t, n in (lost or {}).items() if n}
                if new_lost:
                    problems.append('messages lost on the way: '
                                    + ', '.join(f'{t} {n}' for t, n in sorted(new_lost.items())))
                problems += list(input_problems)   # an input that delivers nothing: topic and cause
                values.update(input_values or {})
                errors = dict(errors or {})
                values.update(errors)
                previous_e = self._last_counts.get('errors', {})
                self._last_counts['errors'] = dict(errors)
                if any(n > previous_e.get(k, 0) for k, n in errors.items()):
                    problems.append('a callback failed (see values)')
                    failed = True
                name, hw = 'gimbal_friction/estimator', ''
            else:
                accepted = counters.accepted.get(axis, 0)
                last = logic.last.get(axis)
                params = logic.axes[axis]
                values = {
                    'accepted': accepted,
                    'pending': logic.pending(axis),
                    'waiting_for_temperature': logic.held(axis),
                    'last_friction_nm': float(last.friction_nm[0]) if last is not None else 'none',
                    'last_stamp_s': f'{int(last.stamp_ns[0]) / NS_PER_S:.9f}' if last is not None else 'none',
                    'last_method': METHOD_NAMES[int(last.method[0])] if last is not None else 'none',
                    'torque_constant_nm_per_a': float(params.torque_constant_nm_per_a),
                    'no_load_current_a': float(params.no_load_current_a),
                    'inertia_kg_m2': float(params.inertia_kg_m2),
                }
                if not accepted:
                    problems.insert(0, 'no sample accepted yet')
                name, hw = f'gimbal_friction/estimator/{axis}', axis
            for reason, count in sorted(rejected.items()):
                values[f'rejected: {reason}'] = count
            level = (ERROR if failed else WARN) if problems else OK
            out.append(status(name, level, '; '.join(problems) or 'ok', hw, values))
        return out
