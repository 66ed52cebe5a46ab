"""The feedforward's ``/diagnostics`` per joint from its rule (no rclpy).

One job in one module: what ``friction_feedforward`` says about each joint, from
:class:`~gimbal_friction.feedforward.rule.Feedforward` and what the node knows of its inputs, testable without a
node (the node publishes :meth:`FeedforwardReport.joint_statuses` as ``diagnostic_msgs``, and adds its learning
status).

``gimbal_friction/feedforward/<joint>`` (hardware_id = joint): WARN names what happened since the previous report
(an input that delivers nothing, no fresh temperature, the output saturated, temperatures / joint states /
reference velocities rejected, messages lost); ERROR for the zero-temperature policy in force or a callback that
failed since then; OK once the cause has gone for a report period. The totals stay in the values: the temperature
used [°C], its source and age [s], the model range [°C], the saturations, ``max_torque_nm`` [N·m], the feedforwards
published and rate-limited, the rejections per reason, the velocity source, the inputs' values and the callback
errors.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from gimbal_friction.feedforward.rule import SOURCE_MEASURED, SOURCE_NAMES, SOURCE_ZERO, Feedforward
from gimbal_friction.streams.diagnostics import ERROR, OK, WARN, Status, status


class FeedforwardReport:
    """The per-joint statuses of one feedforward, report after report (it remembers the counts of the last one)."""

    def __init__(self) -> None:
        self._reported: dict[str, dict[str, int]] = {}

    def new_since_report(self, key: str, counts: Mapping[str, int]) -> dict[str, int]:
        """Counts that grew since the previous report under ``key`` (what keeps a status at WARN), by how much."""
        previous = self._reported.get(key, {})
        self._reported[key] = dict(counts)
        return {r: n - previous.get(r, 0) for r, n in counts.items() if n > previous.get(r, 0)}

    def joint_statuses(self, ff: Feedforward, now_s: float, *, lost: Mapping[str, int] | None = None,
                       input_problems: Sequence[str] = (), input_values: Mapping[str, Any] | None = None,
                       errors: Mapping[str, int] | None = None, rate_limited: int = 0) -> list[Status]:
        """One status per configured joint at ``now_s`` [s, the time of the last joint state]. ``lost``: messages
        lost since the last report per topic; ``input_problems``: the inputs that deliver nothing (topic and
        cause); ``errors``: callback errors in all; ``rate_limited``: feedforwards not published (rate limit)."""
        s, c = ff.settings, ff.counters
        age = ff.temperature_age_s(now_s)
        temperature, source = ff.temperature(now_s)
        new_t = self.new_since_report('temperature', c.temperature_rejected)
        new_j = self.new_since_report('joint_state', c.joint_state_rejected)
        new_r = self.new_since_report('reference', c.reference_rejected)
        new_sat = self.new_since_report('saturated', c.saturated)
        new_lost = dict(lost or {})
        errors = dict(errors or {})
        new_errors = self.new_since_report('errors', errors)
        out = []
        for axis in ff.order:
            level, problems = OK, []
            if input_problems:   # an input that delivers nothing (the topic and the cause)
                level = WARN
                problems += list(input_problems)
            if source != SOURCE_MEASURED:
                level = ERROR if source == SOURCE_ZERO else WARN
                problems.append(f'no fresh temperature: {SOURCE_NAMES[source]}')
            if new_sat.get(axis):
                level = max(level, WARN)
                problems.append(f'output saturated {new_sat[axis]}x')
            if new_t:
                level = max(level, WARN)
                problems.append('temperatures rejected: ' + ', '.join(f'{r} {n}x' for r, n in sorted(new_t.items())))
            if new_j:
                level = max(level, WARN)
                problems.append('joint states rejected: ' + ', '.join(f'{r} {n}x' for r, n in sorted(new_j.items())))
            if new_r:
                level = max(level, WARN)
                problems.append('reference velocities rejected: ' + ', '.join(f'{r} {n}x'
                                                                              for r, n in sorted(new_r.items())))
            if new_lost:
                level = max(level, WARN)
                problems.append('messages lost on the way: ' + ', '.join(f'{t} {n}'
                                                                          for t, n in sorted(new_lost.items())))
            if new_errors:
                level = ERROR
                problems.append('a callback failed (see values)')
            values: dict[str, Any] = {
                'temperature_c': temperature if math.isfinite(temperature) else 'none',
                'temperature_source': SOURCE_NAMES[source],
                'temperature_age_s': age if math.isfinite(age) else 'never',
                'model_range_c': f'{s.temperature_min_c:g}..{s.temperature_max_c:g}',
                'saturated_count': c.saturated.get(axis, 0),
                'max_torque_nm': s.max_torque_nm,
                'published': c.published,
                'rate_limited': rate_limited,
            }
            for reason, count in c.temperature_rejected.items():
                values[f'rejected_temperature: {reason}'] = count
            for reason, count in c.joint_state_rejected.items():
                values[f'rejected_joint_state: {reason}'] = count
            for reason, count in c.reference_rejected.items():
                values[f'rejected_reference: {reason}'] = count
            values['velocity_source'] = s.velocity_source
            values.update(input_values or {})
            values.update(errors)
            out.append(status(f'gimbal_friction/feedforward/{axis}', level, '; '.join(problems) or 'ok', axis,
                              values))
        return out
