"""What a correction keeps of its residuals: the gate and the sufficient statistics (pure numpy; no rclpy, no I/O).

One job in one module: the rule that accepts or refuses a residual sample (:func:`gate_code`, written once against
``xp`` for floats and arrays) and the rows it is kept in (:class:`JointStats`).

A residual sample is the measured friction minus the model friction, both signed like the motion [N·m], at a
temperature [°C], velocity [rad/s] and joint angle [rad], with the model friction ``|model|`` [N·m]. An accepted
sample is added to one **row**: (direction, temperature bin, speed octave, position bin). A row keeps the count
``n``, the sum of the residuals along the motion ``Σr`` [N·m], of ``|model|`` ``Σm`` [N·m] and of the speed's octave
coordinate ``Σu`` [-] (u = log2(|v| / min_speed_rad_s)), so a fit can place the row's speed inside its octave; each
cell (direction × temperature bin) also keeps ``Σr²`` [N²·m²]. Rows are sparse (only those with data exist): a
position bin is ``position_resolution_rad`` wide (0.05° by default) over a turn, plus one bin for samples without a
position. These sums lose nothing a correction needs: any ripple period, speed profile or trend is fitted from them
again (:mod:`~gimbal_friction.feedforward.correction.fit`), however the periods found change.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.xp import ARRAY, SCALAR
from gimbal_friction.feedforward.correction.settings import CorrectionSettings

__all__ = ['REASONS', 'JointStats', 'gate_code', 'row_key', 'speed_octave']

Array = NDArray[np.float64]
#: reason of a refused sample, by gate code (0 = accepted)
REASONS = ('', 'non-finite', 'stale temperature', 'near reversal', 'temperature outside the bins',
           'implausible speed', 'implausible friction')
#: the rows' sums, in the order of :attr:`JointStats.sums`' columns
SUMS = ('n', 'sum_nm', 'sum_model_nm', 'sum_octave')


def gate_code(s: CorrectionSettings, t_c: Any, v: Any, r: Any, m: Any, fresh: Any, xp: Any) -> Any:
    """Gate of a residual sample: 0 accepted, else the index of its reason in :data:`REASONS`.

    ``t_c`` temperature [°C], ``v`` velocity [rad/s], ``r`` residual and ``m`` model torque [N·m], ``fresh`` the
    temperature was fresh. Physically implausible samples are refused before they reach a sum, so no sum can grow
    without bound: a speed above ``max_speed_rad_s``, a residual beyond ``max_residual_relative`` × |model| +
    ``max_residual_floor_nm``. (The position is not gated: a sample without a finite one is kept for the speed
    profile and the level, not for the ripple or the trend.)

    >>> s = CorrectionSettings()
    >>> [REASONS[gate_code(s, -40.0, v, 1e-4, 3e-3, True, SCALAR)] for v in (0.03, 0.001, float('nan'), 1e300)]
    ['', 'near reversal', 'non-finite', 'implausible speed']
    >>> REASONS[gate_code(s, -40.0, 0.03, 1e308, 3e-3, True, SCALAR)]
    'implausible friction'
    """
    ok = xp.isfinite(t_c) & xp.isfinite(v) & xp.isfinite(r) & xp.isfinite(m)
    speed = xp.abs(v)
    code = xp.where(t_c < s.temperature_min_c, 4, xp.where(t_c > s.temperature_max_c, 4, 0))
    code = xp.where(xp.abs(r) > s.max_residual_relative * xp.abs(m) + s.max_residual_floor_nm, 6, code)
    code = xp.where(speed > s.max_speed_rad_s, 5, code)
    code = xp.where(speed < s.min_speed_rad_s, 3, code)
    code = xp.where(fresh, code, 2)
    return xp.where(ok, code, 1)


def speed_octave(s: CorrectionSettings, v: Any, xp: Any) -> Any:
    """The speed's octave coordinate u = log2(|v| / ``min_speed_rad_s``) [-] of velocities ``v`` [rad/s], held at 0
    below the slowest speed learned and at ``speed_bins`` above the fastest octave (finite for any finite v).

    >>> s = CorrectionSettings()
    >>> speed_octave(s, -0.02, SCALAR), speed_octave(s, 0.0, SCALAR)
    (2.0, 0.0)
    """
    a = xp.clip(xp.abs(v), s.min_speed_rad_s, s.min_speed_rad_s * 2.0 ** s.speed_bins)
    return xp.log2(a / s.min_speed_rad_s)


def row_key(s: CorrectionSettings, t_c: Any, v: Any, p: Any, xp: Any) -> tuple[Any, Any, Any]:
    """Row key, cell (direction × temperature bin: ``cw`` first) and octave coordinate u of accepted samples at
    temperatures ``t_c`` [°C], velocities ``v`` [rad/s] and joint angles ``p`` [rad] (not finite: the bin of
    samples without a position)."""
    nt, ns, npos = s.n_temperature, s.n_speed, s.n_position
    cell = xp.where(v > 0.0, 0, nt) + xp.floor_index((t_c - s.temperature_min_c) / s.temperature_bin_c, nt - 1)
    u = speed_octave(s, v, xp)
    k = xp.floor_index(u, ns - 1) if ns > 1 else 0
    known = xp.isfinite(p)
    angle = xp.where(known, p, 0.0) + math.pi
    j = xp.where(known, xp.floor_index((angle % (2.0 * math.pi)) / s.position_resolution_rad, npos - 1), npos)
    return (cell * ns + k) * (npos + 1) + j, cell, u


class JointStats:
    """The sparse rows of one joint (see the module notes), grown as samples arrive.

    ``keys`` maps a row key (:func:`row_key`) to its index in :attr:`sums` (columns :data:`SUMS`); ``cell_sq`` holds
    Σr² per cell [N²·m²].
    """

    __slots__ = ('cell_sq', 'index', 'settings', 'sums')

    def __init__(self, settings: CorrectionSettings) -> None:
        self.settings = settings
        self.index: dict[int, int] = {}
        self.sums = np.zeros((0, len(SUMS)))
        self.cell_sq = np.zeros(2 * settings.n_temperature)

    def __len__(self) -> int:
        return len(self.index)

    @property
    def keys(self) -> NDArray[np.int64]:
        """The row keys, in row order."""
        return np.fromiter(self.index, dtype=np.int64, count=len(self.index))

    def _rows_for(self, keys: NDArray[np.int64]) -> NDArray[np.int64]:
        """Row indices of ``keys`` (new rows added)."""
        out = np.empty(keys.shape, dtype=np.int64)
        index = self.index
        grow = 0
        for i, k in enumerate(keys.tolist()):
            row = index.get(k)
            if row is None:
                row = index[k] = len(index)
                grow += 1
            out[i] = row
        if grow:
            self._reserve(len(index))
        return out

    def _reserve(self, n: int) -> None:
        if n > self.sums.shape[0]:
            bigger = np.zeros((max(n, 2 * self.sums.shape[0], 64), len(SUMS)))
            bigger[:self.sums.shape[0]] = self.sums
            self.sums = bigger

    def add(self, keys: NDArray[np.int64], cells: NDArray[np.int64], u: Array, along: Array, model: Array) -> None:
        """Add accepted samples: their row keys, cells, octave coordinates u [-], residuals along the motion [N·m]
        and |model| [N·m]."""
        if keys.size == 0:
            return
        uniq, inverse = np.unique(keys, return_inverse=True)
        rows = self._rows_for(uniq)
        m = uniq.size
        for col, weights in enumerate((None, along, model, u)):
            self.sums[rows, col] += np.bincount(inverse, weights=weights, minlength=m)
        self.cell_sq += np.bincount(cells, weights=along * along, minlength=self.cell_sq.size)

    def add_one(self, key: int, cell: int, u: float, along: float, model: float) -> None:
        """:meth:`add` for one sample (floats)."""
        row = self.index.get(key)
        if row is None:
            row = self.index[key] = len(self.index)
            self._reserve(row + 1)
        r = self.sums[row]
        r[0] += 1.0
        r[1] += along
        r[2] += model
        r[3] += u
        self.cell_sq[cell] += along * along

    def rows(self) -> tuple[NDArray[np.int64], Array]:
        """(keys, sums) of the rows with data (copies; sums columns :data:`SUMS`)."""
        n = len(self.index)
        return self.keys, self.sums[:n].copy()

    def decode(self, keys: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                                                      NDArray[np.int64], NDArray[np.bool_]]:
        """(direction 0 cw / 1 ccw, temperature bin, speed octave, position bin, position known) of row keys."""
        s = self.settings
        nt, ns, npos = s.n_temperature, s.n_speed, s.n_position
        j = keys % (npos + 1)
        rest = keys // (npos + 1)
        k = rest % ns
        cell = rest // ns
        return cell // nt, cell % nt, k, j, j < npos

    def cell_counts(self) -> NDArray[np.int64]:
        """Samples per cell (direction × temperature bin, ``cw`` first) [-]."""
        s = self.settings
        keys, sums = self.rows()
        cell = keys // ((s.n_position + 1) * s.n_speed)
        return np.bincount(cell, weights=sums[:, 0], minlength=2 * s.n_temperature).round().astype(np.int64)

    def samples(self) -> int:
        """All samples kept [-]."""
        return int(round(float(self.sums[:len(self.index), 0].sum())))

    def clear(self) -> None:
        """Forget every sample."""
        self.index.clear()
        self.sums = np.zeros((0, len(SUMS)))
        self.cell_sq[:] = 0.0

    def copy(self) -> JointStats:
        """An independent copy."""
        out = JointStats(self.settings)
        out.index = dict(self.index)
        out.sums = self.sums.copy()
        out.cell_sq = self.cell_sq.copy()
        return out

    def __deepcopy__(self, memo: dict[int, Any]) -> JointStats:
        # (the rows' index holds only ints: copied as a dict, ~50x faster than item by item; the settings are frozen)
        return self.copy()

    def set_rows(self, keys: NDArray[np.int64], sums: Array, cell_sq: Array) -> None:
        """Replace the rows (a file's)."""
        self.index = {int(k): i for i, k in enumerate(keys.tolist())}
        self.sums = np.array(sums, dtype=float).reshape(len(self.index), len(SUMS))
        self.cell_sq = np.array(cell_sq, dtype=float)


# (SCALAR and ARRAY are the namespaces the rules above are written against)
_ = (ARRAY, SCALAR)
