"""Where the model holds: the temperatures its equations, its calibrated values and its lubricant data support
(docs/model.md §5, "Validity range"). Pure numpy/scipy, no I/O.

The validity range is **−40…+60 °C**, narrower for parameters whose bearing pair loses its preload inside it:

- the paper computed the friction (Fig. 11) and measured it (Sec. 6) from −40 to +60 °C, and the values it does not
  give (docs/model.md §7: the shaft length L, the spin coefficient μ, Palmgren's s0, the frame compliance) were
  calibrated on that curve: nothing supports them outside it;
- the lubricant fit (Eqs. 20–22) rests on DuPont's data from −32 to 204 °C (Table 2); the paper itself extrapolates
  it to −40 °C and no further (below, ν grows a decade every ~10 °C: 4.1e6 cSt at −60 °C, 2.2e15 cSt at −100 °C, a
  friction of 30 N·m);
- the thermal interference model (Eqs. 15–19) holds while the bearing pair is preloaded: where the squeeze X of
  Eq. (16) turns negative (the paper's F_a < 0: a gap between the pair) the contact loads are not the model's. With
  such a gap inside −40…+60 °C the range is the largest interval without one (:func:`validity_range`).

Every entry point keeps to it: :func:`check_temperatures` refuses a temperature outside (``gimbal_friction.core``,
``gimbal-friction model``), the feedforward clamps a credible temperature outside to the range's edge and counts it
(:class:`~gimbal_friction.feedforward.rule.Feedforward`: the node, the replay, the in-process API), an exported
table spans the range. The equations themselves (:func:`~gimbal_friction.physics.model.friction_torque`) evaluate
anywhere in ``MODEL_T_MIN_C…MODEL_T_MAX_C`` (−200…400 °C: a simulated truth, a figure past the range).

>>> validity_range(AxisParams())
ValidityRange(low_c=-40.0, high_c=60.0, note='')
>>> r = validity_range(AxisParams(gasket_thickness_mm=0.0))     # no gasket: the pair is loose above 20 degC
>>> r.text, r.note[:38]
('-40..20 degC', 'the bearing pair has no axial preload ')
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from gimbal_friction.common.errors import ModelDomainError
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.thermal import axial_squeeze

__all__ = ['LUBRICANT_DATA_C', 'LUBRICANT_T_MAX_C', 'LUBRICANT_T_MIN_C', 'VALID_T_MAX_C', 'VALID_T_MIN_C',
           'ValidityRange', 'check_temperatures', 'validity_range']

#: The model's validity range with the paper's parameters [°C]: where the paper computed and measured the friction.
VALID_T_MIN_C, VALID_T_MAX_C = -40.0, 60.0
#: Temperatures of the lubricant data the viscosity fits rest on (Table 2, Krytox 143AA) [°C].
LUBRICANT_DATA_C = (-32.0, 204.0)
#: Where the viscosity fit is used (:func:`gimbal_friction.core.viscosity_cst`): the data, and down to −40 °C as the
#: paper uses it [°C].
LUBRICANT_T_MIN_C, LUBRICANT_T_MAX_C = VALID_T_MIN_C, LUBRICANT_DATA_C[1]
#: grid the preload is looked at on [°C]
_STEP_C = 0.1
#: a squeeze below this is a gap [mm] (1 pm: the rounding of the sum, not a gap)
_TOUCH_MM = 1e-9


class ValidityRange(NamedTuple):
    """The temperatures the model holds for, for one parameter set."""

    low_c: float   #: lowest temperature [°C]
    high_c: float  #: highest temperature [°C]
    note: str      #: why it is narrower than −40…+60 °C ('' when it is not)

    @property
    def text(self) -> str:
        """``-40..60 degC``."""
        return f'{self.low_c:g}..{self.high_c:g} degC'

    def clamp(self, t_c: float) -> float:
        """``t_c`` [°C] clamped to the range [°C]."""
        return min(max(t_c, self.low_c), self.high_c)


@functools.lru_cache(maxsize=128)
def validity_range(p: AxisParams) -> ValidityRange:
    """The model's validity range for ``p`` (see the module notes): −40…+60 °C, or the largest interval of it where
    the bearing pair keeps its preload (the squeeze X of Eq. 16 not negative).

    Raises:
        ModelDomainError: the pair has no preload anywhere in −40…+60 °C (one line, with the parameters to look at).
    """
    n = int(round((VALID_T_MAX_C - VALID_T_MIN_C) / _STEP_C)) + 1
    grid = np.linspace(VALID_T_MIN_C, VALID_T_MAX_C, n)
    with np.errstate(all='ignore'):
        squeeze = np.asarray(axial_squeeze(p, grid), dtype=float)
    gap = ~(squeeze >= -_TOUCH_MM)   # (NaN: no preload either)
    if not gap.any():
        return ValidityRange(VALID_T_MIN_C, VALID_T_MAX_C, '')
    ok = ~gap
    if not ok.any():
        raise ModelDomainError(f'the bearing pair has no axial preload anywhere in {VALID_T_MIN_C:g}..'
                               f'{VALID_T_MAX_C:g} degC (the squeeze of Eq. 16 is negative: a gap between the pair, '
                               'where the model does not hold); check gasket_thickness_mm and interference_mm')
    # the longest run of preloaded grid points, its edges refined to where the squeeze crosses zero
    edges = np.flatnonzero(np.diff(np.concatenate(([0], ok.astype(np.int8), [0]))))
    starts, ends = edges[0::2], edges[1::2] - 1
    k = int(np.argmax(ends - starts))
    i, j = int(starts[k]), int(ends[k])
    low = float(grid[i]) if i == 0 else _crossing(p, float(grid[i - 1]), float(grid[i]))
    high = float(grid[j]) if j == n - 1 else _crossing(p, float(grid[j]), float(grid[j + 1]))
    lost = grid[gap]
    note = (f'the bearing pair has no axial preload at {float(lost.min()):.1f}..{float(lost.max()):.1f} degC (the '
            "squeeze of Eq. 16 turns negative: the paper's F_a < 0, a gap between the pair)")
    return ValidityRange(low, high, note)


def _crossing(p: AxisParams, a: float, b: float) -> float:
    """Where the squeeze crosses zero between ``a`` and ``b`` [°C], rounded inwards to 0.01 °C."""
    def squeeze(t: float) -> float:
        return float(axial_squeeze(p, t)) + _TOUCH_MM

    try:
        t = float(brentq(squeeze, a, b, xtol=1e-6))
    except ValueError:   # pragma: no cover - the grid saw the sign change
        return a if squeeze(a) >= 0.0 else b
    inward = math.ceil(t * 100.0) / 100.0 if squeeze(a) < 0.0 else math.floor(t * 100.0) / 100.0
    return round(inward, 2)


def check_temperatures(p: AxisParams, t_c: ArrayLike, low_c: float | None = None, high_c: float | None = None,
                       what: str = 'temperature') -> None:
    """Raise unless every temperature of ``t_c`` [°C] lies in the model's validity range for ``p`` (or in
    ``[low_c, high_c]`` where given: the lubricant fit's range).

    Raises:
        ModelDomainError: one line naming the first temperature outside, the range and why.

    >>> check_temperatures(AxisParams(), [-100.0, 20.0])
    Traceback (most recent call last):
    ...
    gimbal_friction.common.errors.ModelDomainError: temperature -100 degC lies outside the model's validity range \
-40..60 degC (where the paper computed and measured the friction; the lubricant data reach -32..204 degC)
    """
    t = np.atleast_1d(np.asarray(t_c, dtype=float))
    if not np.all(np.isfinite(t)):
        raise ModelDomainError(f'{what}s must be finite')
    if low_c is None or high_c is None:
        r = validity_range(p)
        low_c, high_c = r.low_c, r.high_c
        why = (f' for these parameters: {r.note}' if r.note else
               f' (where the paper computed and measured the friction; the lubricant data reach '
               f'{LUBRICANT_DATA_C[0]:g}..{LUBRICANT_DATA_C[1]:g} degC)')
        name = "the model's validity range"
    else:
        why = (f' (the lubricant data reach {LUBRICANT_DATA_C[0]:g}..{LUBRICANT_DATA_C[1]:g} degC, and the paper '
               f'uses the fit down to {VALID_T_MIN_C:g} degC)')
        name = "the viscosity fit's range"
    outside = t[(t < low_c) | (t > high_c)]
    if outside.size:
        raise ModelDomainError(f'{what} {float(outside[0]):g} degC lies outside {name} {low_c:g}..{high_c:g} degC'
                               f'{why}')
