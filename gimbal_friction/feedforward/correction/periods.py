r"""Ripple periods found in the residuals: a weighted periodogram over the joint angle (pure numpy and scipy).

One job in one module: :func:`strongest_period_GLS_Zechmeister_2009`, the strongest sinusoid in unevenly sampled
data with its significance.

A race's waviness makes the friction ripple with the joint angle θ at periods nobody tells the suite. The residuals
a correction keeps (relative to the model friction, pooled over temperatures and directions at each position bin,
:func:`~gimbal_friction.feedforward.correction.fit.fit_joint`) are sampled unevenly in θ (a sine scan dwells at its
ends, a sweep covers the travel once, bins without data are missing), so the periodogram is the generalised
Lomb–Scargle one of Zechmeister & Kürster (2009): at every trial frequency f a weighted least-squares fit

.. math:: y(\theta) \approx c + a\cos(2\pi f\theta) + b\sin(2\pi f\theta)

(:func:`scipy.signal.lombscargle` with ``weights`` and ``floating_mean``). The best frequency is refined on a finer
grid, and the amplitude :math:`A = \sqrt{a^2 + b^2}` is judged against its standard error from the fit's own
scatter: :math:`z = A / \sigma_A`. Without a ripple, :math:`z^2` is χ² with two degrees of freedom at each
frequency, so over the ~``(f_max − f_min) · span`` independent frequencies searched a ``z`` of 6 appears by chance
with a probability of about ``span · f_max · e^{-18}`` (1e-5 for a 20° travel and 0.2° periods).

References: N. R. Lomb (1976), Astrophys. Space Sci. 39, 447; J. D. Scargle (1982), ApJ 263, 835;
M. Zechmeister & M. Kürster (2009), A&A 496, 577, DOI 10.1051/0004-6361:200811296.

>>> theta = np.sort(np.random.default_rng(1).uniform(-0.1, 0.2, 400))       # rad, uneven
>>> y = 0.05 * np.sin(2 * np.pi * theta / np.radians(3.4) + 0.3)             # a 3.4 deg ripple of 5 %
>>> y = y + np.random.default_rng(2).normal(0.0, 0.02, theta.size)
>>> p = strongest_period_GLS_Zechmeister_2009(theta, y, np.ones(theta.size), 0.004, 0.15)
>>> round(float(np.degrees(p.period_rad)), 2), round(p.amplitude, 3), p.z > 20
(3.4, 0.05, True)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['Period', 'sinusoid_fit', 'strongest_period_GLS_Zechmeister_2009']

Array = NDArray[np.float64]
#: trial frequencies per independent frequency (1 / span) of the coarse search [-]
OVERSAMPLING = 8
#: the coarse peak is refined on a grid this many times finer [-]
REFINE = 16


class Period(NamedTuple):
    """A sinusoid found in the data, with its evidence."""

    period_rad: float     #: period in the joint angle [rad]
    amplitude: float      #: amplitude A [units of y]
    z: float              #: A over its standard error [-]
    power: float          #: fraction of the weighted variance about the mean the sinusoid explains [-]
    samples: float        #: the weight's count behind it (points used) [-]
    span_rad: float       #: angle range of the data [rad]


def sinusoid_fit(theta: Array, y: Array, w: Array, f: float) -> tuple[Array, Array, float]:
    """Weighted least-squares fit of ``c + a cos(2π f θ) + b sin(2π f θ)`` at frequency ``f`` [cycles/rad]:
    (coefficients (c, a, b), their covariance scaled by the fit's own residual variance, residual variance)."""
    phase = 2.0 * math.pi * f * theta
    x = np.stack([np.ones(theta.shape), np.cos(phase), np.sin(phase)], axis=1)
    xtw = x.T * w
    a = xtw @ x
    beta = np.linalg.solve(a + 1e-12 * np.trace(a) * np.eye(3), xtw @ y)
    e = y - x @ beta
    dof = max(theta.size - 3, 1)
    s2 = float(w @ (e * e)) / dof
    cov = np.linalg.inv(a + 1e-12 * np.trace(a) * np.eye(3)) * s2
    return beta, cov, s2


def strongest_period_GLS_Zechmeister_2009(theta: ArrayLike, y: ArrayLike, w: ArrayLike, period_min_rad: float,
                                          period_max_rad: float) -> Period | None:
    """The strongest sinusoid of ``y`` over the joint angle ``theta`` [rad] with weights ``w`` (inverse variances up
    to a common factor) among periods in [``period_min_rad``, ``period_max_rad``] [rad] (the longest is held to half
    the span of ``theta``); None when fewer than 8 points or no period fits in the span.

    The generalised Lomb–Scargle periodogram (floating mean, weights) on a grid of ``OVERSAMPLING`` frequencies per
    1/span, its peak refined ``REFINE`` times finer, then the amplitude and its standard error from a weighted fit.
    """
    th = np.asarray(theta, dtype=float)
    yy = np.asarray(y, dtype=float)
    ww = np.asarray(w, dtype=float)
    keep = np.isfinite(th) & np.isfinite(yy) & np.isfinite(ww) & (ww > 0.0)
    th, yy, ww = th[keep], yy[keep], ww[keep]
    if th.size < 8:
        return None
    span = float(th.max() - th.min())
    p_max = min(period_max_rad, 0.5 * span)
    if not (span > 0.0 and p_max > period_min_rad > 0.0):
        return None
    from scipy.signal import lombscargle
    centre = float(np.average(th, weights=ww))
    x = th - centre                                  # (phases near 0: better conditioned)
    df = 1.0 / (OVERSAMPLING * span)
    freqs = np.arange(1.0 / p_max, 1.0 / period_min_rad + df, df)
    power = lombscargle(x, yy, 2.0 * math.pi * freqs, weights=ww / ww.sum(), floating_mean=True,
                        normalize=True)
    i = int(np.argmax(power))
    fine = np.linspace(freqs[max(i - 1, 0)], freqs[min(i + 1, freqs.size - 1)], 2 * REFINE + 1)
    fine_power = lombscargle(x, yy, 2.0 * math.pi * fine, weights=ww / ww.sum(), floating_mean=True,
                             normalize=True)
    j = int(np.argmax(fine_power))
    f = float(fine[j])
    beta, cov, _ = sinusoid_fit(x, yy, ww, f)
    a, b = float(beta[1]), float(beta[2])
    amp = math.hypot(a, b)
    if amp <= 0.0:
        return None
    grad = np.array([a / amp, b / amp])
    var = float(grad @ cov[1:, 1:] @ grad)
    z = amp / math.sqrt(var) if var > 0.0 else math.inf
    return Period(1.0 / f, amp, z, float(fine_power[j]), float(th.size), span)
