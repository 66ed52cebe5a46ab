r"""The temperatures the estimator has received, searched by time (pure: no rclpy, no I/O).

A friction sample's temperature is the one *in force at its stamp* — the latest valid temperature whose time is not
later than the sample's — never simply the latest one to arrive: under load, messages of different topics arrive
out of their stamp order, and a rule on arrival order would give a live node and the replay of its bag different
answers (the same sample paired with the previous temperature live and with the next one offline).

:class:`TemperatureHistory` keeps the valid temperatures in arrival order with their arrival position (the
estimator's global message counter), their time [ns] and value [°C], and answers two questions, both restricted to
what had arrived by a given position so that the answer does not depend on how the messages were batched:

- :meth:`TemperatureHistory.ready_position`: the first arrival position at which a temperature of time ≥ ``t`` had
  arrived — from then on no temperature stamped at or before ``t`` is still expected (one publisher sends in stamp
  order), so the temperature at ``t`` is known;
- :meth:`TemperatureHistory.at`: the latest temperature of time ≤ ``t`` among those arrived by a position.

The history is bounded (:data:`TEMPERATURE_HISTORY` entries are kept after each batch) and restarts when the
temperatures' time jumps back by more than ``reset_ns`` (a bag played in a loop, simulated time restarted).

>>> h = TemperatureHistory(reset_ns=10**9)
>>> h.extend(np.array([0, 5, 9]), np.array([100, 300, 200]), np.array([20.0, 22.0, 21.0]))  # 200 arrived late
>>> h.at(np.array([250, 250, 50]), np.array([5, 9, 9]))[0].tolist()   # at t=250: before and after the late one
[20.0, 21.0, nan]
>>> h.ready_position(np.array([250, 300, 301])).tolist() == [5, 5, _I64_MAX]
True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.units import NS_PER_S

_I64_MAX = int(np.iinfo(np.int64).max)

#: valid temperatures kept between batches [-] (at 10 Hz: the last 51 s)
TEMPERATURE_HISTORY = 512
#: late arrivals (a temperature arriving after a newer one) looked back over when searching by time [-]
LATE_LOOKBACK = 16


class TemperatureHistory:
    """Valid temperatures in arrival order: arrival position, time [ns], value [°C] (see the module docstring).

    Parameters
    ----------
    reset_ns : int
        A temperature earlier than the latest time seen by more than this [ns] restarts the history.
    """

    def __init__(self, reset_ns: int) -> None:
        self.reset_ns = int(reset_ns)
        self.clear()

    def clear(self) -> None:
        """Forget every temperature."""
        i = np.empty(0, dtype=np.int64)
        self.pos, self.time_ns, self.value = i, i, np.empty(0, dtype=np.float64)
        self._runmax, self._runarg = i, i   #: running maximum of the times and the index where it is attained
        self._in_order = True               #: the times never decrease in arrival order (none arrived late)

    def __len__(self) -> int:
        return int(self.pos.shape[0])

    def extend(self, pos: NDArray[np.int64], time_ns: NDArray[np.int64], value: NDArray[np.float64]) -> None:
        """Append temperatures (arrival position increasing, later than every position held) [-, ns, °C]."""
        if pos.shape[0] == 0:
            return
        pos, time_ns = np.asarray(pos, dtype=np.int64), np.asarray(time_ns, dtype=np.int64)
        value = np.asarray(value, dtype=np.float64)
        prior = int(self._runmax[-1]) if len(self) else None
        run = np.maximum.accumulate(time_ns)
        if prior is not None:
            run = np.maximum(run, prior)
        before = np.concatenate([[prior if prior is not None else time_ns[0]], run[:-1]])
        jumps = np.flatnonzero(time_ns < before - self.reset_ns)
        if jumps.size:   # the time source jumped back: start again from the last jump
            k = int(jumps[-1])
            self.clear()
            pos, time_ns, value = pos[k:], time_ns[k:], value[k:]
        self.pos = np.concatenate([self.pos, pos])
        self.time_ns = np.concatenate([self.time_ns, time_ns])
        self.value = np.concatenate([self.value, value])
        self._recompute()

    def _recompute(self) -> None:
        t = self.time_ns
        n = t.shape[0]
        self._runmax = np.maximum.accumulate(t) if n else t
        is_max = np.concatenate([[True], t[1:] >= self._runmax[:-1]]) if n else np.empty(0, dtype=bool)
        self._runarg = np.maximum.accumulate(np.where(is_max, np.arange(n), 0)).astype(np.int64)
        self._in_order = bool(n < 2 or np.all(t[1:] >= t[:-1]))

    def keep(self, mask: NDArray[np.bool_]) -> None:
        """Keep only the temperatures where ``mask`` holds (a change of the valid range)."""
        self.pos, self.time_ns, self.value = self.pos[mask], self.time_ns[mask], self.value[mask]
        self._recompute()

    def trim(self, length: int = TEMPERATURE_HISTORY) -> None:
        """Keep the last ``length`` temperatures (between batches)."""
        if len(self) > length:
            self.keep(np.arange(len(self)) >= len(self) - length)

    def ready_position(self, time_ns: NDArray[np.int64]) -> NDArray[np.int64]:
        """The arrival position of the first temperature of time ≥ each ``time_ns`` [ns] (int64 max: none yet)."""
        t = np.asarray(time_ns, dtype=np.int64)
        if not len(self):
            return np.full(t.shape, _I64_MAX, dtype=np.int64)
        k = np.searchsorted(self._runmax, t, side='left')
        return np.where(k < len(self), self.pos[np.minimum(k, len(self) - 1)], _I64_MAX).astype(np.int64)

    def at(self, time_ns: NDArray[np.int64], upto_pos: NDArray[np.int64]
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The latest temperature of time ≤ ``time_ns`` [ns] among those arrived at or before ``upto_pos``: its value
        [°C] and time [s] (NaN where there is none)."""
        t = np.asarray(time_ns, dtype=np.int64)
        n = len(self)
        value = np.full(t.shape, np.nan)
        when = np.full(t.shape, np.nan)
        if n == 0 or t.size == 0:
            return value, when
        k = np.searchsorted(self.pos, np.asarray(upto_pos, dtype=np.int64), side='right')   # entries [0, k)
        f = np.searchsorted(self._runmax, t, side='right')            # before f every time is <= t
        head = np.minimum(f, k)
        best = np.where(head > 0, self._runarg[np.maximum(head - 1, 0)], -1)
        best_time = np.where(best >= 0, self.time_ns[np.maximum(best, 0)], np.iinfo(np.int64).min)
        # late arrivals after f may still be stamped <= t (none when the times never decrease: every time from f
        # on is at least the running maximum at f, which is later than t)
        for step in range(0 if self._in_order else LATE_LOOKBACK):
            i = f + step
            inside = i < k
            ic = np.minimum(i, n - 1)
            better = inside & (self.time_ns[ic] <= t) & (self.time_ns[ic] >= best_time)
            best = np.where(better, ic, best)
            best_time = np.where(better, self.time_ns[ic], best_time)
            if not np.any(inside):
                break
        found = best >= 0
        value[found] = self.value[best[found]]
        when[found] = self.time_ns[best[found]] / NS_PER_S
        return value, when
