"""The nodes' ``/diagnostics`` in words and numbers, without ROS (pure: no rclpy, no message types).

One job in one module: how a node's status reads — its level, its message, its values as the strings
``diagnostic_msgs/KeyValue`` carries — so the rules are testable without a ROS graph. The nodes turn a
:class:`Status` into a ``diagnostic_msgs/DiagnosticStatus`` field by field (``gimbal_friction.nodes._common``).

- values: a float with 6 significant digits (``0.00123457``), anything else as ``str``; a statistic that must
  read back exactly (the estimator's ``/gimbal/friction/statistics``) as the shortest round-trip decimal
  (:func:`exact`);
- a managed node's state: its first status carries ``lifecycle_state``, and while it is not active every message
  starts with the state (``inactive: not logging``), once (:func:`with_lifecycle_state`);
- the estimator's statistics: one status per (joint, direction, plateau) (:func:`statistics_statuses`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NamedTuple

#: the levels of diagnostic_msgs/DiagnosticStatus (its OK, WARN, ERROR, STALE bytes)
OK, WARN, ERROR, STALE = b'\x00', b'\x01', b'\x02', b'\x03'


class Status(NamedTuple):
    """One diagnostic status: name, level (:data:`OK` ...), message, hardware id and its values, in order."""

    name: str
    level: bytes
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


def value_text(value: object) -> str:
    """A value as a KeyValue string: a float with 6 significant digits, anything else as ``str``.

    >>> value_text(0.00123456789), value_text(12), value_text('none'), value_text(float('nan'))
    ('0.00123457', '12', 'none', 'nan')
    """
    return f'{value:.6g}' if isinstance(value, float) else str(value)


def exact(value: float) -> str:
    """A float as the shortest decimal that reads back to the same double (``repr``).

    >>> exact(0.1), exact(3)
    ('0.1', '3.0')
    """
    return repr(float(value))


def status(name: str, level: bytes, message: str, hardware_id: str, values: Mapping[str, Any]) -> Status:
    """A :class:`Status` with ``values`` as strings (:func:`value_text`).

    >>> status('gimbal_friction/estimator', WARN, 'no sample accepted yet', '', {'accepted': 0}).values
    (('accepted', '0'),)
    """
    return Status(name, level, message, hardware_id, tuple((k, value_text(v)) for k, v in values.items()))


def with_lifecycle_state(statuses: Sequence[Status], state: str | None) -> list[Status]:
    """``statuses`` of a managed node in ``state`` (a lifecycle_msgs label; None: not a managed node, unchanged):
    the first carries ``lifecycle_state``; while not active each message starts with the state, once.

    >>> s = with_lifecycle_state([status('a', OK, 'ok', '', {}), status('b', OK, 'inactive: x', '', {})], 'inactive')
    >>> [(x.message, x.values) for x in s]
    [('inactive: ok', (('lifecycle_state', 'inactive'),)), ('inactive: x', ())]
    >>> with_lifecycle_state([status('a', OK, 'ok', '', {})], 'active')[0].message
    'ok'
    """
    if state is None:
        return list(statuses)
    out = []
    for k, one in enumerate(statuses):
        values = (*one.values, ('lifecycle_state', str(state))) if k == 0 else one.values
        message = one.message
        if state != 'active' and not message.startswith(f'{state}:'):   # (not publishing its output)
            message = f'{state}: {message}'
        out.append(one._replace(message=message, values=values))
    return out


def statistics_statuses(records: Iterable[Mapping[str, Any]], prefix: str = 'gimbal_friction/estimator/statistics'
                        ) -> list[Status]:
    """The estimator's ``/gimbal/friction/statistics``: one OK status per record of
    ``EstimatorLogic.statistics()`` (joint, direction, plateau [°C] or None, count, mean, std, ripple [N·m],
    position range [rad]), named ``<prefix>/<joint>/<+1|-1>/<plateau_c|unknown>``, every number exact.

    >>> (s,) = statistics_statuses([{'joint': 'el', 'direction': -1, 'plateau_c': -40.0, 'count': 3,
    ...     'mean_nm': 0.0021, 'std_nm': 1e-5, 'ripple_nm': 2e-5, 'min_position': -0.1, 'max_position': 0.2}])
    >>> s.name, s.message, dict(s.values)['mean_nm']
    ('gimbal_friction/estimator/statistics/el/-1/-40.0', 'mean 2.1 N*mm, 3 samples', '0.0021')
    """
    out = []
    for rec in records:
        plateau = 'unknown' if rec['plateau_c'] is None else exact(rec['plateau_c'])
        direction = '+1' if rec['direction'] > 0 else '-1'
        values = (
            ('joint', str(rec['joint'])), ('direction', direction), ('plateau_c', plateau),
            ('count', str(rec['count'])), ('mean_nm', exact(rec['mean_nm'])), ('std_nm', exact(rec['std_nm'])),
            ('ripple_nm', exact(rec['ripple_nm'])), ('min_position_rad', exact(rec['min_position'])),
            ('max_position_rad', exact(rec['max_position'])),
        )
        out.append(Status(f'{prefix}/{rec["joint"]}/{direction}/{plateau}', OK,
                          f'mean {rec["mean_nm"] * 1e3:.4g} N*mm, {rec["count"]} samples', str(rec['joint']), values))
    return out
