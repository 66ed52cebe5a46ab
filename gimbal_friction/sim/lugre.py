r"""The LuGre dynamic friction model (Canudas de Wit, Olsson, Åström & Lischinsky 1995), vectorised.

The contact is a set of elastic bristles with mean deflection ``z``; the friction torque of a relative velocity
``v`` is, in the form of the 1995 paper (Sec. 2),

.. math::

    \frac{dz}{dt} = v - \frac{\sigma_0 |v|}{g(v)} z, \qquad
    F = \sigma_0 z + \sigma_1 \frac{dz}{dt} + \sigma_2 v, \qquad
    g(v) = F_C + (F_S - F_C)\, e^{-(v/v_s)^2}

(the paper writes :math:`\sigma_0 g(v)` for the right-hand side of the last equation and drops the
:math:`\sigma_0` from the first; the two forms are identical). At constant velocity the deflection settles at
:math:`z_{ss} = g(v)\,\mathrm{sgn}(v)/\sigma_0` and the torque at the static Stribeck curve
:math:`F_{ss}(v) = g(v)\,\mathrm{sgn}(v) + \sigma_2 v` (:func:`stribeck_curve_LuGre_1995`). Near zero velocity
the bristles act as a spring of stiffness σ0 with damping σ1 (pre-sliding: no motion until the applied torque
exceeds the breakaway level F_S, reached after a deflection of about F_S/σ0).

No maintained Python implementation of the model is on PyPI here, so it is implemented from the paper.

Reference
---------
.. [1] C. Canudas de Wit, H. Olsson, K. J. Åström, P. Lischinsky, "A new model for control of systems with
   friction", IEEE Trans. Automatic Control 40(3), 419–425, 1995. DOI 10.1109/9.376053.

Units here are rotational (the gimbal axis): torque [N·m], angle [rad], velocity [rad/s]; the functions are
unit-agnostic as long as they are consistent.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = ['lugre_force_1995', 'lugre_g_1995', 'lugre_steady_state_z', 'lugre_z_step',
           'stribeck_curve_LuGre_1995']


def lugre_g_1995(v: ArrayLike, F_C: ArrayLike, F_S: ArrayLike, v_s: float) -> Array:
    """Stribeck level g(v) of the LuGre model [1]_: ``F_C + (F_S − F_C) exp(−(v/v_s)²)``, [N·m].

    Parameters
    ----------
    v : array_like
        Relative velocity, [rad/s].
    F_C : array_like
        Coulomb (sliding) friction level, [N·m] (> 0).
    F_S : array_like
        Stiction (breakaway) level, [N·m] (≥ F_C for a Stribeck dip).
    v_s : float
        Stribeck velocity, [rad/s] (> 0).

    Returns
    -------
    Array
        g(v) > 0, [N·m].

    >>> float(lugre_g_1995(0.0, 1.0, 1.5, 0.001))
    1.5
    """
    x = np.asarray(v, dtype=float) / v_s
    F_C = np.asarray(F_C, dtype=float)
    return np.asarray(F_C + (np.asarray(F_S, dtype=float) - F_C) * np.exp(-x * x))


def stribeck_curve_LuGre_1995(v: ArrayLike, F_C: ArrayLike, F_S: ArrayLike, v_s: float,
                              sigma2: float = 0.0) -> Array:
    """Steady-state (static) friction of the LuGre model [1]_: ``g(v) sgn(v) + σ2 v``, [N·m].

    Parameters
    ----------
    v : array_like
        Relative velocity, [rad/s].
    F_C, F_S : array_like
        Coulomb and stiction levels, [N·m].
    v_s : float
        Stribeck velocity, [rad/s].
    sigma2 : float
        Viscous coefficient, [N·m·s/rad].

    Returns
    -------
    Array
        Friction torque opposing the motion (signed like ``v``), [N·m].

    Notes
    -----
    Worked example with the parameters of the 1995 paper's simulation (F_C = 1 N, F_S = 1.5 N,
    v_s = 0.001 m/s, σ2 = 0.4 N·s/m) at v = v_s: 1 + 0.5 e⁻¹ + 0.4e-3 = 1.18434 N.

    >>> round(float(stribeck_curve_LuGre_1995(0.001, 1.0, 1.5, 0.001, 0.4)), 5)
    1.18434
    """
    v = np.asarray(v, dtype=float)
    return np.asarray(lugre_g_1995(v, F_C, F_S, v_s) * np.sign(v) + sigma2 * v)


def lugre_steady_state_z(v: ArrayLike, g: ArrayLike, sigma0: float) -> Array:
    """Steady-state bristle deflection ``z_ss = g(v) sgn(v) / σ0`` [1]_, [rad].

    Parameters
    ----------
    v : array_like
        Relative velocity, [rad/s].
    g : array_like
        Stribeck level g(v), [N·m].
    sigma0 : float
        Bristle stiffness, [N·m/rad].
    """
    return np.asarray(np.sign(np.asarray(v, dtype=float)) * np.asarray(g, dtype=float) / sigma0)


def lugre_z_step(z: ArrayLike, v: ArrayLike, g: ArrayLike, sigma0: float, h: float) -> Array:
    """Bristle deflection after a step ``h`` with ``v`` and ``g`` held: the exact solution of dz/dt [1]_, [rad].

    With ``v`` and ``g(v)`` constant over the step, ``dz/dt = v − a z`` with ``a = σ0 |v| / g`` is linear, so

    ``z(h) = z_ss + (z − z_ss) e^{−a h}``,  ``z_ss = g sgn(v)/σ0``

    This is unconditionally stable (the sliding regime is stiff: ``a h`` reaches 10⁴ at 1 rad/s for a
    millisecond step) and exact at standstill (``v = 0`` keeps ``z``), so the deflection never overshoots its
    steady state and the torque never exceeds the stiction level through the ``σ0 z`` term.

    Parameters
    ----------
    z : array_like
        Deflection at the start of the step, [rad].
    v : array_like
        Relative velocity over the step, [rad/s].
    g : array_like
        Stribeck level g(v) over the step, [N·m] (> 0).
    sigma0 : float
        Bristle stiffness, [N·m/rad].
    h : float
        Step, [s].

    Returns
    -------
    Array
        Deflection at the end of the step, [rad].

    >>> z = 0.0
    >>> for _ in range(100):
    ...     z = lugre_z_step(z, 0.01, 2e-3, 100.0, 1e-3)
    >>> round(float(z) * 100.0 / 2e-3, 9)       # settled at z_ss = g / sigma0
    1.0
    """
    v = np.asarray(v, dtype=float)
    g = np.asarray(g, dtype=float)
    decay = np.exp(-sigma0 * np.abs(v) * h / g)
    return np.asarray(np.asarray(z, dtype=float) * decay + (1.0 - decay) * np.sign(v) * g / sigma0)


def lugre_force_1995(z: ArrayLike, dz_dt: ArrayLike, v: ArrayLike, sigma0: float, sigma1: float,
                     sigma2: float = 0.0) -> Array:
    """Friction torque of the LuGre model [1]_: ``σ0 z + σ1 dz/dt + σ2 v``, [N·m].

    Parameters
    ----------
    z : array_like
        Bristle deflection, [rad].
    dz_dt : array_like
        Its rate, [rad/s] (in a fixed-step simulation the mean over the step, ``(z_new − z)/h``).
    v : array_like
        Relative velocity, [rad/s].
    sigma0, sigma1, sigma2 : float
        Stiffness [N·m/rad], bristle damping [N·m·s/rad], viscous coefficient [N·m·s/rad].
    """
    return sigma0 * np.asarray(z, dtype=float) + sigma1 * np.asarray(dz_dt, dtype=float) + \
        sigma2 * np.asarray(v, dtype=float)
