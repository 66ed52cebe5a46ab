"""Rules about inputs shared by every node and the offline replay, each written once.

- **A joint named by the user must be configured** (:func:`unconfigured_joints`): one error text for every
  command, node, file and API that takes joint (axis) names.
- **Which entry of a message is a joint's** (:func:`index_joints`): the first entry naming a configured joint;
  a repeated name, an unknown name and a value array shorter or longer than the name array are counted.
- **The time of a message** (:func:`effective_time`): its ``header.stamp``; a zero stamp (a driver that does not
  stamp) falls back to the arrival time (the receive time live, the log time of a bag offline).
- **A valid bearing temperature** (:func:`temperature_rejection`): finite and inside the credible range
  ``[temperature_min_c, temperature_max_c]`` of the node.
- **A fresh temperature** (:func:`is_fresh`): the time of the sample that uses it and the time of the temperature
  differ by at most ``temperature_timeout_s`` (either way: a temperature stamped in the future by more than the
  timeout is not fresh either). The temperature used is always the latest valid one received.
- **The latest valid sample before each event, on arrays** (:func:`latest_before`): the one search of the batch
  paths (offline estimator, bag feedforward) for "the last valid temperature (reference) received before this
  joint state", with the value carried from an earlier batch where none precedes.

Live and offline apply the same functions to the same values (times from the message stamps), so a bag replayed
offline gives what the live nodes gave.

>>> unconfigured_joints(['roll'], ['elevation'])
"axis 'roll' is not configured (configured: elevation)"
>>> index_joints(['azimuth', 'elevation', 'elevation'], (3,), ('elevation',))
JointIndex(position={'elevation': 1}, mismatch=False, unknown=1, duplicate=1)
>>> effective_time(0.0, 12.5), effective_time(3.0, 12.5)
(12.5, 3.0)
>>> temperature_rejection(-300.0, -60.0, 120.0)
'temperature out of range'
>>> is_fresh(10.0, 4.0, 5.0, SCALAR), is_fresh(10.0, 6.0, 5.0, SCALAR)
(False, True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.xp import SCALAR, BoolOrArray, Namespace, X

T_NON_FINITE = 'non-finite temperature'
T_RANGE = 'temperature out of range'
J_MISMATCH = 'value/name length mismatch'
J_UNKNOWN = 'unknown joint name'
J_DUPLICATE = 'duplicate joint name'
J_NONE = 'no configured joint'

__all__ = [
    'J_DUPLICATE',
    'J_MISMATCH',
    'J_NONE',
    'J_UNKNOWN',
    'SCALAR',
    'T_NON_FINITE',
    'T_RANGE',
    'JointIndex',
    'effective_time',
    'index_joints',
    'is_fresh',
    'latest_before',
    'temperature_rejection',
    'temperature_valid',
    'unconfigured_joints',
]


class JointIndex(NamedTuple):
    """Where each configured joint is in a message, and what was odd about the message."""

    position: dict[str, int]  #: configured joint -> index of its first entry (absent: not in the message)
    mismatch: bool          #: a value array is not as long as the name array (the message is unusable)
    unknown: int            #: entries naming no configured joint [-]
    duplicate: int          #: later entries repeating a configured joint (ignored) [-]


def unconfigured_joints(wanted: Sequence[str], configured: Sequence[str]) -> str | None:
    """Why joint (axis) names asked for are refused: the rule text naming those not in ``configured`` and the
    configured ones (None: all configured)."""
    missing = [name for name in wanted if name not in configured]
    if not missing:
        return None
    names = ', '.join(repr(name) for name in missing)
    verb = 'axis {} is' if len(missing) == 1 else 'axes {} are'
    return f'{verb.format(names)} not configured (configured: {", ".join(configured)})'


def index_joints(names: Sequence[str], value_lengths: Sequence[int], configured: Sequence[str]) -> JointIndex:
    """Index of each configured joint among ``names`` (first entry wins); ``value_lengths`` are the lengths of
    the value arrays the reader needs (a mismatch makes the message unusable: the index is then empty)."""
    n = len(names)
    if any(k != n for k in value_lengths):
        return JointIndex({}, True, 0, 0)
    wanted = set(configured)
    index: dict[str, int] = {}
    unknown = duplicate = 0
    for i, name in enumerate(names):
        if name not in wanted:
            unknown += 1
        elif name in index:
            duplicate += 1
        else:
            index[name] = i
    return JointIndex(index, False, unknown, duplicate)


def latest_before(keys: NDArray[np.int64] | NDArray[np.float64], query: NDArray[np.int64] | NDArray[np.float64],
                  values: Sequence[NDArray[np.float64]], *,
                  inclusive: bool, carried: Sequence[float] | None = None) -> tuple[NDArray[np.float64], ...]:
    """For each ``query`` key, each of ``values`` at the latest valid sample whose (sorted) key is before it
    (``inclusive``: at or before it: a sample logged at the same time arrived first); where none is, the
    ``carried`` value (from an earlier batch; default NaN). Keys: log times [ns] or arrival positions [-].

    >>> latest_before(np.array([10, 20]), np.array([5, 10, 25]), [np.array([1.0, 2.0])], inclusive=True)[0]
    array([nan,  1.,  2.])
    """
    k = np.searchsorted(keys, query, side='right' if inclusive else 'left') - 1
    have = k >= 0
    kk = np.maximum(k, 0)
    fill = [math.nan] * len(values) if carried is None else list(carried)
    return tuple(np.where(have, v[kk] if v.size else f, f) for v, f in zip(values, fill, strict=True))


#: a time of a message: s (float) or ns (int), one value or an array
Time = TypeVar('Time', float, int, NDArray[np.float64], NDArray[np.int64])


def effective_time(stamp: Time, arrival: Time) -> Time:
    """The time of a message: its header stamp, or its arrival (log) time where the stamp is zero (same unit
    as the inputs: s or ns; floats, ints or arrays)."""
    if isinstance(stamp, np.ndarray):
        return np.where(stamp != 0, stamp, arrival)
    return stamp if stamp != 0 else arrival


def temperature_rejection(temperature_c: float, t_min_c: float, t_max_c: float) -> str | None:
    """Why a bearing temperature [°C] is refused (None: valid)."""
    if not math.isfinite(temperature_c):
        return T_NON_FINITE
    if not t_min_c <= temperature_c <= t_max_c:
        return T_RANGE
    return None


def temperature_valid(temperature_c: NDArray[np.float64], t_min_c: float, t_max_c: float
                      ) -> tuple[NDArray[np.bool_], dict[str, int]]:
    """:func:`temperature_rejection` over an array: the valid mask and the count of each rejection reason."""
    t = np.asarray(temperature_c, dtype=np.float64)
    finite = np.isfinite(t)
    valid = finite & (t >= t_min_c) & (t <= t_max_c)
    counts = {T_NON_FINITE: int(np.count_nonzero(~finite)), T_RANGE: int(np.count_nonzero(finite & ~valid))}
    return valid, {k: v for k, v in counts.items() if v}


def is_fresh(sample_time: X | float, temperature_time: X | float, timeout: float, xp: Namespace[X]) -> BoolOrArray:
    """A temperature of time ``temperature_time`` is fresh for a sample of time ``sample_time`` (same unit as
    ``timeout``). NaN times (no temperature yet) are never fresh."""
    return xp.abs(sample_time - temperature_time) <= timeout
