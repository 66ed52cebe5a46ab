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
from collections.abc import Sequence
from typing import Protocol, TypeAlias, TypeVar, cast

import numpy as np
from numpy.typing import NDArray

__all__ = ['ARRAY', 'SCALAR', 'BoolArray', 'BoolOrArray', 'FloatArray', 'FloatOrArray', 'Namespace', 'X',
           'namespace']

#: an array of float64 values (numpy's float64 is also what the rules compute in)
FloatArray: TypeAlias = NDArray[np.float64]
#: an array of booleans (the result of a comparison of a :data:`FloatArray`)
BoolArray: TypeAlias = NDArray[np.bool_]
#: what a rule takes and returns: a Python float (:data:`SCALAR`) or a float64 array (:data:`ARRAY`)
FloatOrArray: TypeAlias = float | FloatArray
#: the result of a comparison of a :data:`FloatOrArray`
BoolOrArray: TypeAlias = bool | BoolArray

#: one value of a rule, float or array: a rule ``f(x: X, xp: Namespace[X]) -> X`` returns a float for floats
#: evaluated with :data:`SCALAR` and an array for arrays evaluated with :data:`ARRAY`
X = TypeVar('X', float, FloatArray)
_T = TypeVar('_T')


class Namespace(Protocol[_T]):
    """The functions a rule may call on its namespace ``xp``, for values of type ``_T`` (float or array).

    Every argument may also be a plain float (a constant, a limit, one value broadcast against an array, as numpy
    broadcasts it);
    conditions of :meth:`where` are what a comparison of ``_T`` gives (bool or a boolean array). The index of
    :meth:`floor_index` and :meth:`take` travels as a ``_T``: an int for SCALAR (a float to the type checker), an
    int64 array for ARRAY (numpy promotes it in arithmetic with floats).
    """

    def tanh(self, x: _T | float, /) -> _T: ...
    def log10(self, x: _T | float, /) -> _T: ...
    def log2(self, x: _T | float, /) -> _T: ...
    def sqrt(self, x: _T | float, /) -> _T: ...
    def exp(self, x: _T | float, /) -> _T: ...
    def abs(self, x: _T | float, /) -> _T: ...
    def cbrt(self, x: _T | float, /) -> _T: ...
    def copysign(self, x: _T | float, y: _T | float, /) -> _T: ...
    def isfinite(self, x: _T | float, /) -> BoolOrArray: ...
    def where(self, condition: BoolOrArray, a: _T | float, b: _T | float, /) -> _T: ...
    def clip(self, x: _T | float, lo: float, hi: float, /) -> _T: ...
    def minimum(self, a: _T | float, b: _T | float, /) -> _T: ...
    def maximum(self, a: _T | float, b: _T | float, /) -> _T: ...
    def floor_index(self, x: _T, hi: int, /) -> _T: ...
    def take(self, values: Sequence[float] | FloatArray, index: _T, /) -> _T: ...


def _cbrt(x: float) -> float:
    """Real cube root of a float (``math.cbrt`` before Python 3.11)."""
    return math.copysign(abs(x) ** (1.0 / 3.0), x)


class _Scalar:
    """numpy's names on Python floats (``where`` and ``clip`` evaluate like numpy's, on one value); written with
    conditional expressions, not ``min``/``max`` (a builtin ``min`` of two floats costs ~0.1 µs, a conditional
    ~0.01 µs)."""

    tanh = staticmethod(math.tanh)
    log10 = staticmethod(math.log10)
    log2 = staticmethod(math.log2)
    sqrt = staticmethod(math.sqrt)
    exp = staticmethod(math.exp)
    abs = staticmethod(abs)
    copysign = staticmethod(math.copysign)
    isfinite = staticmethod(math.isfinite)
    cbrt = staticmethod(getattr(math, 'cbrt', _cbrt))  # math.cbrt: Python >= 3.11

    @staticmethod
    def where(condition: object, a: float, b: float, /) -> float:
        return a if condition else b

    @staticmethod
    def clip(x: float, lo: float, hi: float, /) -> float:
        """``lo`` below ``lo``, ``hi`` above ``hi``, else ``x`` (NaN stays NaN, as numpy's)."""
        return lo if x < lo else (hi if hi < x else x)  # noqa: FURB136  # min() costs ~0.1 µs more

    @staticmethod
    def minimum(a: float, b: float, /) -> float:
        return a if a < b else b  # noqa: FURB136  # (see the class notes)

    @staticmethod
    def maximum(a: float, b: float, /) -> float:
        return a if a > b else b  # noqa: FURB136  # (see the class notes)

    @staticmethod
    def floor_index(x: float, hi: int, /) -> int:
        """``min(floor(x), hi)`` as an index, for ``x ≥ 0``."""
        i = int(x)
        return hi if hi < i else i  # noqa: FURB136  # (see the class notes)

    @staticmethod
    def take(values: Sequence[float] | FloatArray, index: float, /) -> float:
        return float(values[index])  # type: ignore[call-overload]  # the index is the int of floor_index (int <: float)


class _Array:
    """numpy, plus the two helpers the scalar namespace needs under numpy's names."""

    tanh = staticmethod(np.tanh)
    log10 = staticmethod(np.log10)
    log2 = staticmethod(np.log2)
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
    def floor_index(x: FloatArray, hi: int, /) -> NDArray[np.int64]:
        """``min(floor(x), hi)`` as an int64 index array, for ``x ≥ 0``."""
        return np.minimum(np.asarray(x).astype(np.int64), hi)

    @staticmethod
    def take(values: FloatArray, index: NDArray[np.int64], /) -> FloatArray:
        return np.take(values, index)


_SCALAR_CHECKED: Namespace[float] = _Scalar()  # the type checker checks _Scalar against Namespace here
#: the namespace of a rule evaluated on Python floats: a class whose attributes are the plain functions of
#: :class:`_Scalar` (the interpreter specialises ``SCALAR.tanh`` on a class to a dictionary hit, ~0.015 µs less per
#: use than a static method of an instance, which a rule on floats pays a few times per call)
SCALAR: Namespace[float] = cast('Namespace[float]', type('SCALAR', (), {
    name: getattr(_Scalar, name) for name in vars(_Scalar) if not name.startswith('_')}))
#: the namespace of a rule evaluated on numpy arrays. A cast: numpy's stubs type its ufuncs' results as ``Any``
#: (and :meth:`_Array.floor_index` gives an int64 array where the protocol says the value type); numpy returns
#: float64 arrays for float64 arrays, which the tests of every rule check against SCALAR.
ARRAY: Namespace[FloatArray] = cast('Namespace[FloatArray]', _Array())


def namespace(*values: object) -> Namespace[float] | Namespace[FloatArray]:
    """:data:`ARRAY` if any of ``values`` is a numpy array, else :data:`SCALAR`."""
    return ARRAY if any(isinstance(v, np.ndarray) for v in values) else SCALAR
