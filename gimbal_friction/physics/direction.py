r"""Direction dependence of the friction torque: the constant factors and a temperature-dependent asymmetry.

Yu & Shang (2017), Sec. 6 and Fig. 13 (DOI 10.1299/jamdsm.2017jamdsm0052), measured the mean friction of the pitch
axis clockwise (CW, our positive direction) and counter-clockwise (CCW) separately:

=========  ==========  ==========
direction  −40 °C      +60 °C
=========  ==========  ==========
CW         3.19 N·mm   1.05 N·mm
CCW        −2.45 N·mm  −1.34 N·mm
=========  ==========  ==========

so the two directions differ, the difference changes sign between the cold and the warm end, and at 20 °C they
were "almost same". The paper attributes it to "uneven distribution of grease at lower temperature" and gives no
model. The grease a ball pushes ahead of it piles up at the end of a short back-and-forth sweep (−6…+11° here, not
symmetric about the mechanical zero); how much stays there and which way it drags depends on how stiff the
grease is (its consistency and oil bleed change strongly with temperature), so the direction difference is a
function of temperature that is not tied to either torque component.

The form used here is the simplest one with the properties the data call for. The *asymmetry* ``a(T)`` is linear
in temperature between two anchors and held constant outside them (no extrapolation):

.. math::

    a(T) = a_c + (a_w - a_c)\,w(T),\qquad
    w(T) = \mathrm{clip}\Big(\frac{T - T_c}{T_w - T_c}, 0, 1\Big)

and the torque for motion in direction ``d = ±1`` is the model magnitude ``M(T, n)`` times

.. math:: k_d(T) = s_d\,(1 + d\,a(T))

with ``s_+ = scale_positive``, ``s_- = scale_negative`` (the constant factors, unchanged) and
``a_c = direction_asymmetry_cold`` at ``T_c = direction_asymmetry_cold_c``, ``a_w = direction_asymmetry_warm`` at
``T_w = direction_asymmetry_warm_c``. Why this form:

- it is zero when ``a_c = a_w = 0`` (the defaults): the model and the paper reproduction are unchanged;
- it can change sign between the cold and the warm end, as measured;
- it moves CW up and CCW down by the same fraction, so it leaves the mean of the two directions to the model
  (``(k_+ + k_-)/2 = 1`` for ``s_± = 1``): the refit determines the viscosity from the mean and the asymmetry from
  the difference, and the two are not confounded;
- it is linear in ``a_c`` and ``a_w``: one cold and one warm plateau with both directions determine them, and the
  refit's intervals are those of a linear parameter.

With the paper's means, ``a(−40 °C) = (3.19 − 2.45)/(3.19 + 2.45) = 0.131`` and ``a(+60 °C) = (1.05 − 1.34)/(1.05 +
1.34) = −0.121``; linear in between, ``a(20 °C) = −0.02`` ("almost same"). A form proportional to the viscous
fraction M_L/M (grease churning only) was tried and rejected: the viscous fraction is 0.70 at −40 °C and 0.56 at
+60 °C, so a sign change would need opposite asymmetries of about +0.7 on M_L and −1.3 on M_R + M_S.

The rule is written once against a numeric namespace ``xp`` (:mod:`gimbal_friction.common.xp`): ``SCALAR`` per
controller tick (well under a microsecond more than the constant factor), ``ARRAY`` for a whole bag.

>>> p = AxisParams(direction_asymmetry_cold=0.131, direction_asymmetry_warm=-0.121)
>>> round(direction_factor(p, -40.0, 1.0, SCALAR), 3), round(direction_factor(p, -40.0, -1.0, SCALAR), 3)
(1.131, 0.869)
>>> round(direction_asymmetry(p, 20.0, SCALAR), 4)
-0.0202
>>> direction_factor(p, np.array([-50.0, 60.0, 70.0]), np.array([1.0, -1.0, 1.0]), ARRAY).round(3).tolist()
[1.131, 1.121, 0.879]
>>> direction_factor(AxisParams(), 12.0, -1.0, SCALAR)    # defaults: the constant factor, 1
1.0
"""

from __future__ import annotations

import numpy as np

from gimbal_friction.common.xp import ARRAY, SCALAR, Namespace, X
from gimbal_friction.physics.params import AxisParams

__all__ = ['ARRAY', 'SCALAR', 'asymmetry_weight', 'direction_asymmetry', 'direction_factor', 'direction_factors',
           'select_direction']

_ = np  # the doctests use numpy


def asymmetry_weight(p: AxisParams, temperature_c: X, xp: Namespace[X]) -> X:
    """Weight ``w(T)`` of the warm anchor: 0 at or below ``direction_asymmetry_cold_c``, 1 at or above
    ``direction_asymmetry_warm_c``, linear in between, [-].

    Parameters
    ----------
    p : AxisParams
        Model parameters (the anchor temperatures).
    temperature_c : float or ndarray
        Bearing temperature, [°C].
    xp : namespace
        :data:`~gimbal_friction.common.xp.SCALAR` or :data:`~gimbal_friction.common.xp.ARRAY`.
    """
    t_c = p.direction_asymmetry_cold_c
    return xp.clip((temperature_c - t_c) / (p.direction_asymmetry_warm_c - t_c), 0.0, 1.0)


def direction_asymmetry(p: AxisParams, temperature_c: X, xp: Namespace[X]) -> X:
    """Asymmetry ``a(T) = a_c + (a_w − a_c) w(T)``: positive when the positive (CW) direction has more friction,
    [-]. See the module notes for the form and its rationale."""
    a_c = p.direction_asymmetry_cold
    return a_c + (p.direction_asymmetry_warm - a_c) * asymmetry_weight(p, temperature_c, xp)


def direction_factors(p: AxisParams, temperature_c: X, xp: Namespace[X]) -> tuple[X, X]:
    """The factors ``(k_+(T), k_-(T)) = (s_+ (1 + a(T)), s_- (1 - a(T)))`` of the two directions at
    ``temperature_c`` [°C], [-] (they depend on temperature only: a per-call caller computes them once per
    temperature and picks one with :func:`select_direction`)."""
    a = direction_asymmetry(p, temperature_c, xp)
    return p.scale_positive * (1.0 + a), p.scale_negative * (1.0 - a)


def select_direction(velocity_sign: X | float, k_positive: X, k_negative: X, xp: Namespace[X]) -> X:
    """The factor of the direction of ``velocity_sign``: ``>= 0`` is the positive direction (the paper's CW),
    [-]."""
    return xp.where(velocity_sign >= 0.0, k_positive, k_negative)


def direction_factor(p: AxisParams, temperature_c: X, velocity_sign: X | float, xp: Namespace[X]) -> X:
    """Factor on the model magnitude for motion in the direction of ``velocity_sign`` at ``temperature_c``:
    ``k_d(T) = s_d (1 + d a(T))``, [-].

    Parameters
    ----------
    p : AxisParams
        Model parameters: ``scale_positive``, ``scale_negative`` and the ``direction_asymmetry_*`` values.
    temperature_c : float or ndarray
        Bearing temperature, [°C] (NaN gives NaN).
    velocity_sign : float or ndarray
        Velocity, or its sign; ``>= 0`` is the positive direction (the paper's CW), [any unit].
    xp : namespace
        :data:`~gimbal_friction.common.xp.SCALAR` (Python floats) or :data:`~gimbal_friction.common.xp.ARRAY`.

    Returns
    -------
    k : float or ndarray
        Direction factor, [-]; equals ``scale_positive`` / ``scale_negative`` with the default (zero) asymmetry.
    """
    k_positive, k_negative = direction_factors(p, temperature_c, xp)
    return select_direction(velocity_sign, k_positive, k_negative, xp)
