r"""The Generalized Maxwell-Slip (GMS) friction model (Al-Bender, Lampaert & Swevers 2005), vectorised.

A second pre-sliding form for the simulator's truth, not of LuGre's (:mod:`gimbal_friction.sim.lugre`): the contact
is ``N`` elasto-slide (Maxwell-slip) elements in parallel, all moving with the same relative displacement ``x``.
Element ``i`` is a spring of stiffness ``k_i`` whose force ``F_i`` is bounded by its share of the Stribeck curve,
``W_i s(v)``. In the form of the 2005 paper (Sec. II, the GMS state equations)

.. math::

    \text{stick:}\quad \frac{dF_i}{dt} = k_i v, \qquad
    \text{slip:}\quad \frac{dF_i}{dt} = C \left(\mathrm{sgn}(v) - \frac{F_i}{W_i s(v)}\right), \qquad
    F = \sum_i F_i + \sigma_2 v

An element sticks until its force reaches its limit ``|F_i| = W_i s(v)``; it then slips (its force attracted to
``sgn(v) W_i s(v)`` at the rate set by the attraction parameter ``C``) until the velocity passes through zero, when
it sticks again. With ``C → ∞`` a slipping element is dragged at its limit (the classical Maxwell-slip / Iwan
element with a velocity-dependent limit): ``F_i = sgn(v) W_i s(v)``. Either way, at constant velocity every element
slips and the torque settles at ``Σ W_i s(v) sgn(v) + σ_2 v``: with weights summing to 1 the static curve is the
Stribeck curve ``s(v)`` itself, the same as a LuGre truth's with the same ``s``.

What distinguishes it from LuGre (one bristle state): pre-sliding **hysteresis with non-local memory**. Below the
breakaway level the force-displacement curve is piecewise linear (the *virgin curve*
``F_v(x) = Σ min(k_i x, W_i s)`` from rest, :func:`gms_virgin_curve`), the branch after a reversal at
``(x_r, F_r)`` follows Masing's rule ``F = F_r − 2 F_v((x_r − x)/2)``, and a minor loop closed inside a major one
returns the force to the point of the major branch it left (*return-point memory*): the elements remember every
unclosed reversal, a state no function of the present velocity can hold. These are the properties the paper
states for the GMS model (and of the Maxwell-slip hysteresis it extends) and that ``test/sim/test_gms_truth.py``
checks.

No maintained Python implementation of the model is on PyPI here, so it is implemented from the paper.

Reference
---------
.. [1] F. Al-Bender, V. Lampaert, J. Swevers, "The generalized Maxwell-slip model: a novel model for friction
   simulation and compensation", IEEE Trans. Automatic Control 50(11), 1883–1887, 2005.
   DOI 10.1109/TAC.2005.858676.

Units here are rotational (the gimbal axis): torque [N·m], angle [rad], velocity [rad/s], stiffness [N·m/rad],
attraction ``C`` [N·m/s]; the functions are unit-agnostic as long as they are consistent.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = ['gms_force_AlBender_2005', 'gms_step_AlBender_2005', 'gms_virgin_curve']


def gms_step_AlBender_2005(force: ArrayLike, slipping: ArrayLike, v: ArrayLike, s: ArrayLike,
                           stiffness: ArrayLike, weights: ArrayLike, h: float,
                           attraction: float = 0.0) -> tuple[Array, NDArray[np.bool_]]:
    """Element forces and slip states after a step ``h`` with ``v`` and ``s(v)`` held, [N·m] [1]_.

    A sticking element integrates ``dF_i/dt = k_i v`` exactly over the step (``F_i + k_i v h``); one whose force
    reaches its limit ``W_i s`` within the step slips from there on. A slipping element keeps slipping while the
    velocity keeps the sign of its force and sticks again when the velocity is zero or reversed. In slip the force
    follows the paper's attraction law ``dF_i/dt = C (sgn v − F_i/(W_i s))`` with ``s`` held, solved exactly
    (``F_i → sgn(v) W_i s + (F_i − sgn(v) W_i s) e^{−C h/(W_i s)}``), or with ``attraction = 0`` (meaning
    ``C → ∞``) is dragged at the limit, ``F_i = sgn(v) W_i s``. Both updates are unconditionally stable: a force
    never leaves ``[−W_i s, W_i s]`` through the stick update and never overshoots its limit in slip.

    Parameters
    ----------
    force : array_like
        Element forces ``F_i`` at the start of the step, shape (..., N), [N·m].
    slipping : array_like of bool
        Elements slipping at the start of the step, shape (..., N).
    v : array_like
        Relative velocity over the step, shape (...), [rad/s].
    s : array_like
        Stribeck level ``s(v)`` over the step (> 0), shape (...), [N·m].
    stiffness : array_like
        Element stiffnesses ``k_i`` (> 0), shape (N,), [N·m/rad].
    weights : array_like
        Element shares ``W_i`` of the Stribeck level (> 0, summing to 1 for a static curve equal to ``s``),
        shape (N,), [-].
    h : float
        Step, [s].
    attraction : float
        The attraction parameter ``C`` of the slip law, [N·m/s]; 0: the limit ``C → ∞`` (drag at the limit).

    Returns
    -------
    tuple of Array and bool array
        Element forces [N·m] and slip states at the end of the step.

    From rest, a displacement of 10 µrad in one step (v = 0.01 rad/s for 1 ms) against two elements of
    100 and 10 N·m/rad with limits 0.5 and 0.5 mN·m: the stiff one saturates (slips), the soft one sticks.

    >>> f, slip = gms_step_AlBender_2005([0.0, 0.0], [False, False], 0.01, 1e-3, [100.0, 10.0], [0.5, 0.5], 1e-3)
    >>> [round(float(x) * 1e3, 6) for x in f], [bool(b) for b in slip]
    ([0.5, 0.1], [True, False])
    """
    v = np.asarray(v, dtype=float)[..., None]
    s = np.asarray(s, dtype=float)[..., None]
    force = np.asarray(force, dtype=float)
    slip: NDArray[np.bool_] = np.asarray(slipping, dtype=bool)
    limit = np.asarray(weights, dtype=float) * s
    direction = np.sign(v)
    # a slipping element moving on keeps slipping; at zero or reversed velocity it sticks
    slip = slip & (direction * np.sign(force) > 0.0)
    trial = force + np.asarray(stiffness, dtype=float) * v * h
    starts = ~slip & (np.abs(trial) >= limit)
    target = direction * limit
    if attraction > 0.0:
        relaxed = target + (force - target) * np.exp(-attraction * h / limit)
    else:
        relaxed = target
    new = np.where(slip, relaxed, np.where(starts, np.clip(trial, -limit, limit), trial))
    return np.asarray(new), np.asarray(slip | starts)


def gms_force_AlBender_2005(force: ArrayLike, d_force_dt: ArrayLike, v: ArrayLike, stiffness_total: float,
                            sigma1: float = 0.0, sigma2: float = 0.0) -> Array:
    """Friction torque of the GMS model [1]_: ``Σ F_i + σ1/K dΣF_i/dt + σ2 v``, [N·m].

    The paper's torque is ``Σ F_i + σ2 v``. The middle term is the simulator's own addition: a damping of the
    pre-sliding springs, written like LuGre's ``σ1 dz/dt`` with the deflection ``ΣF_i/K`` of the total stiffness
    ``K = Σ k_i`` (a ``σ1 v`` while every element sticks, none in steady sliding), so the pre-sliding resonance of
    the axis is damped as a LuGre truth's is and the static curve is unchanged.

    Parameters
    ----------
    force : array_like
        Element forces, shape (..., N), [N·m].
    d_force_dt : array_like
        Rate of the sum of the element forces, shape (...), [N·m/s] (in a fixed-step simulation the mean over
        the step).
    v : array_like
        Relative velocity, shape (...), [rad/s].
    stiffness_total : float
        ``K = Σ k_i`` (> 0), [N·m/rad].
    sigma1, sigma2 : float
        Pre-sliding damping [N·m·s/rad] and viscous coefficient [N·m·s/rad].

    >>> round(float(gms_force_AlBender_2005([1e-3, 2e-3], 0.0, 0.0, 100.0)), 6)
    0.003
    """
    total = np.sum(np.asarray(force, dtype=float), axis=-1)
    return np.asarray(total + sigma1 / stiffness_total * np.asarray(d_force_dt, dtype=float) +
                      sigma2 * np.asarray(v, dtype=float))


def gms_virgin_curve(x: ArrayLike, stiffness: ArrayLike, weights: ArrayLike, s: float) -> Array:
    """Virgin (initial loading) curve of the GMS model with a constant level ``s`` [1]_: ``Σ min(k_i |x|, W_i s)
    sgn(x)``, [N·m].

    The force from rest (every element unloaded) after a monotonic displacement ``x`` [rad]; piecewise linear with a
    break where each element saturates (at ``x_i = W_i s / k_i``), equal to ``Σ W_i s`` beyond the last. Masing's
    rule builds every reversal branch from it (see the module notes).

    Parameters
    ----------
    x : array_like
        Displacement from rest, [rad].
    stiffness : array_like
        Element stiffnesses, shape (N,), [N·m/rad].
    weights : array_like
        Element shares of ``s``, shape (N,), [-].
    s : float
        Stribeck level (constant: a pre-sliding motion is slow), [N·m].

    >>> [round(float(f) * 1e3, 6) for f in gms_virgin_curve([5e-6, 1e-3], [100.0, 10.0], [0.5, 0.5], 1e-3)]
    [0.55, 1.0]
    """
    x = np.asarray(x, dtype=float)[..., None]
    limit = np.asarray(weights, dtype=float) * s
    per = np.minimum(np.asarray(stiffness, dtype=float) * np.abs(x), limit) * np.sign(x)
    return np.asarray(np.sum(per, axis=-1))
