"""One rule, two speeds: the numeric namespace a rule is written against (Python floats or numpy arrays).

A rule of the fast path (table interpolation, the Walther viscosity, Palmgren's Eq. 9, the feedforward torque, the
temperature freshness rule) is written once, against a namespace ``xp`` with numpy's names: ``xp.tanh``,
``xp.where``, ``xp.clip``, ... :data:`SCALAR` runs it on Python floats (about 1 µs per call: the in-process
controller API and the nodes, one message at a time); :data:`ARRAY` is numpy itself (the offline replay, a whole
bag at once). Same text, same operations; results agree to the last bit or two (numpy's vectorised
transcendental functions may round differently from libm).

This is the pattern of the Python array API standard (``xp = array_namespace(x)``), reduced to the few functions
the rules need.

>>> def smooth_sign(v, v_th, xp):
...     return xp.tanh(v / v_th)
>>> round(smooth_sign(0.01, 0.005, SCALAR), 6)
0.964028
>>> smooth_sign(np.array([0.01, -0.01]), 0.005, ARRAY).round(6).tolist()
[0.964028, -0.964028]
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _cbrt(x: float) -> float:
    """Real cube root of a float (``math.cbrt`` before Python 3.11)."""
    return math.copysign(abs(x) ** (1.0 / 3.0), x)


class _Scalar:
    """numpy's names on Python floats (``where`` and ``clip`` evaluate like numpy's, on one value)."""

    tanh = staticmethod(math.tanh)
    log10 = staticmethod(math.log10)
    sqrt = staticmethod(math.sqrt)
    exp = staticmethod(math.exp)
    abs = staticmethod(abs)
    copysign = staticmethod(math.copysign)
    isfinite = staticmethod(math.isfinite)

    @staticmethod
    def where(condition: bool, a: float, b: float) -> float:
        return a if condition else b

    @staticmethod
    def clip(x: float, lo: float, hi: float) -> float:
        return lo if x < lo else (hi if x > hi else x)

    @staticmethod
    def minimum(a: float, b: float) -> float:
        return a if a < b else b

    @staticmethod
    def maximum(a: float, b: float) -> float:
        return a if a > b else b

    cbrt = staticmethod(getattr(math, 'cbrt', _cbrt))  # math.cbrt: Python >= 3.11

    @staticmethod
    def floor_index(x: float, hi: int) -> int:
        """``min(floor(x), hi)`` as an index, for ``x ≥ 0``."""
        i = int(x)
        return hi if i > hi else i

    @staticmethod
    def take(values: Any, index: int) -> float:
        return float(values[index])


class _Array:
    """numpy, plus the two helpers the scalar namespace needs under numpy's names."""

    tanh = staticmethod(np.tanh)
    log10 = staticmethod(np.log10)
    sqrt = staticmethod(np.sqrt)
    exp = staticmethod(np.exp)
    abs = staticmethod(np.abs)
    copysign = staticmethod(np.copysign)
    isfinite = staticmethod(np.isfinite)
    where = staticmethod(np.where)
    clip = staticmethod(np.clip)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)
    cbrt = staticmethod(np.cbrt)

    @staticmethod
    def floor_index(x: Any, hi: int) -> Any:
        """``min(floor(x), hi)`` as an int64 index array, for ``x ≥ 0``."""
        return np.minimum(np.asarray(x).astype(np.int64), hi)

    @staticmethod
    def take(values: Any, index: Any) -> Any:
        return np.take(values, index)


#: the namespace of a rule evaluated on Python floats
SCALAR: Any = _Scalar()
#: the namespace of a rule evaluated on numpy arrays
ARRAY: Any = _Array()


def namespace(*values: object) -> Any:
    """:data:`ARRAY` if any of ``values`` is a numpy array, else :data:`SCALAR`."""
    return ARRAY if any(isinstance(v, np.ndarray) for v in values) else SCALAR
