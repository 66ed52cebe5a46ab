"""The truth friction of the simulated axis: the physics model plus what the model does not know.

Sliding (Coulomb) level of the truth at bearing temperature t, relative velocity v and joint angle θ::

    F_C(t, v, θ) = m(t) · k_dir(t, sgn v) · M_truth(t, |v|) · (1 + r(θ, t))

- ``M_truth`` is the suite's model through its one fast path, :class:`~gimbal_friction.physics.table.FrictionTable`
  (Yu & Shang 2017, Eq. 10: tabulated M_R + M_S, Palmgren's Eq. 9 evaluated exactly at |v|), of the *truth*
  axis parameters (:func:`truth_params`): the paper's bearing (:data:`PAPER_AXIS`, Table 1) with the truth's own
  lubricant (Walther ``truth_walther_a`` + ``lubricant_walther_a_shift``, ``truth_walther_b``), Palmgren factor
  (``truth_palmgren_factor``) and motor (``truth_torque_constant_nm_per_a``, ``truth_no_load_current_a``), all
  parameters of :class:`~gimbal_friction.sim.config.SimConfig`. The truth never reads the configuration under
  test (the :class:`~gimbal_friction.physics.params.AxisParams` the feedforward, the estimator and the controller
  use): a wrong configured lubricant costs, it does not move the truth.
- ``k_dir`` is the core's direction factor :func:`~gimbal_friction.physics.direction.direction_factor`
  ``1 + d a(t)`` with the truth's asymmetry: ``a = (CW − |CCW|)/(CW + |CCW|)`` of the paper's measured means at the
  two anchors (0.131 at −40 °C, −0.121 at +60 °C, Sec. 6), linear between them and held beyond (the core's form,
  so a refit of ``direction_asymmetry_cold``/``_warm`` can find it).
- ``m`` is the truth's *mean factor* (:func:`mean_factors`): the mean of the two measured directions over the
  paper's model (:data:`PAPER_AXIS`, the datasheet lubricant) at the paper's speed (1/3 rpm) at the anchors
  (0.897 at −40 °C, 1.103 at +60 °C), linear between them and held beyond. It is what the core's direction form
  cannot hold: the measured mean is not the model's. With the datasheet lubricant (the default
  ``truth_walther_a``/``_b``, ``truth_palmgren_factor``) and no lubricant shift the truth's means at 1/3 rpm are
  therefore exactly the paper's four measured means; with the default shift (+0.015, the synthetic chamber bag's
  truth) the cold end is more viscous (CW ≈ 3.97 N·mm at −40 °C, like the sample bag's measured 3.83).
- ``r`` is the position ripple of :func:`ripple`: a sum of sines in the joint angle, amplified in the cold.

The pre-sliding form is per truth (``presliding_model``): LuGre (the default) or the generalized Maxwell-slip model
(:mod:`gimbal_friction.sim.gms`, Al-Bender et al. 2005), whose elements' limits are the same Stribeck level ``g(v)``
shared by ``gms_weights`` (so its pre-sliding follows the truth's own temperature dependence and its static curve is
the same). The LuGre model (:mod:`gimbal_friction.sim.lugre`) makes it dynamic: Stribeck level
``g(v) = F_C + (F_S − F_C) e^{−(v/v_s)²}`` with ``F_S = breakaway_ratio · F_C`` (the breakaway torque relative to
the sliding level at the same low speed, i.e. to M(t, 0) of the lower Palmgren branch), plus the motor's
no-load torque ``T_0 = K_T I_0`` (the truth's) as a Coulomb term (the torque motor ``τ = K_T (i − sgn(ω) I_0)``,
with the sign smoothed by the bristle dynamics). At constant velocity the torque settles at
:meth:`TruthFriction.static_torque_nm`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.xp import ARRAY
from gimbal_friction.physics.direction import direction_factor
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.table import FrictionTable, TemperatureTerms
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.lugre import lugre_g_1995, stribeck_curve_LuGre_1995

Array = NDArray[np.float64]

__all__ = ['PAPER_AXIS', 'MeanFactors', 'TemperatureTerms', 'TruthFriction', 'TruthTerms', 'cold_weight',
           'mean_factors', 'position_ripple', 'ripple', 'truth_asymmetry', 'truth_params']

#: Temperatures where the ripple's cold amplification is full (−40 °C) and zero (+20 °C and above) [°C].
RIPPLE_COLD_C = -40.0
RIPPLE_WARM_C = 20.0
#: Temperature range and step of the truth's model table [°C] (the feedforward's defaults).
TABLE_RANGE_C = (-60.0, 120.0, 0.1)
#: The paper's gimbal axis (Table 1 bearing, Krytox 143AA datasheet lubricant, K_T 0.05 N·m/A, J 1e-4 kg·m²): the
#: bearing of the truth and the model the measured means are relative to (:func:`mean_factors`).
PAPER_AXIS = AxisParams()


def truth_asymmetry(config: SimConfig) -> tuple[float, float]:
    """Direction asymmetry of the truth at the cold and warm anchors, ``(CW − |CCW|)/(CW + |CCW|)`` of the measured
    means [-] (0, 0 when ``asymmetry_enabled`` is false).

    >>> [round(a, 4) for a in truth_asymmetry(SimConfig())]
    [0.1312, -0.1213]
    """
    if not config.asymmetry_enabled:
        return 0.0, 0.0
    cw, ccw = config.asymmetry_cw_nmm, config.asymmetry_ccw_nmm
    return (cw[0] - ccw[0]) / (cw[0] + ccw[0]), (cw[-1] - ccw[-1]) / (cw[-1] + ccw[-1])


def truth_params(config: SimConfig) -> AxisParams:
    """Truth model parameters, from ``config`` alone: the paper's bearing (:data:`PAPER_AXIS`) with the truth's
    lubricant (``walther_a = truth_walther_a + lubricant_walther_a_shift``, ``walther_b = truth_walther_b``),
    Palmgren factor and motor constants, no constant direction factors, and the truth's direction asymmetry
    (:func:`truth_asymmetry`) at the anchors.

    >>> p = truth_params(SimConfig())
    >>> round(p.walther_a, 4), p.walther_b, p.palmgren_factor, p.torque_constant_nm_per_a
    (8.6345, -21.2471, 1.917, 0.05)
    """
    a_cold, a_warm = truth_asymmetry(config)
    t_cold, t_warm = config.asymmetry_temperatures_c[0], config.asymmetry_temperatures_c[-1]
    return PAPER_AXIS.replace(walther_a=config.truth_walther_a + config.lubricant_walther_a_shift,
                              walther_b=config.truth_walther_b, palmgren_factor=config.truth_palmgren_factor,
                              torque_constant_nm_per_a=config.truth_torque_constant_nm_per_a,
                              no_load_current_a=config.truth_no_load_current_a, scale_positive=1.0,
                              scale_negative=1.0, direction_asymmetry_cold=a_cold, direction_asymmetry_warm=a_warm,
                              direction_asymmetry_cold_c=t_cold, direction_asymmetry_warm_c=t_warm)


class MeanFactors(NamedTuple):
    """The truth's mean factor at the anchor temperatures (measured mean / configured model)."""

    temperatures_c: Array   #: anchor temperatures [°C]
    factors: Array          #: m at the anchors [-]

    def at(self, t_c: ArrayLike) -> Array:
        """m at temperatures ``t_c`` [°C]: linear between the anchors, held beyond them."""
        return np.asarray(np.interp(np.asarray(t_c, dtype=float), self.temperatures_c, self.factors))


def mean_factors(config: SimConfig) -> MeanFactors:
    """Mean factors ``m(t_i) = (CW_i + |CCW_i|) / 2 / M(t_i, n)`` at the anchor temperatures ``t_i``, with ``M`` the
    paper's model (:data:`PAPER_AXIS`: its bearing and datasheet lubricant) at the paper's speed ``n`` = 1/3 rpm;
    factors of 1 when ``asymmetry_enabled`` is false. A fixed property of the paper's gimbal: neither the
    configuration under test nor the truth's lubricant changes it.

    With the paper's means (M = 3.143 N·mm at −40 °C, 1.084 at +60 °C):

    >>> [round(float(x), 4) for x in mean_factors(SimConfig()).factors]
    [0.8971, 1.1026]
    """
    temps = np.asarray(config.asymmetry_temperatures_c, dtype=float)
    if not config.asymmetry_enabled:
        return MeanFactors(temps, np.ones(temps.shape))
    m_nmm = np.atleast_1d(friction_torque(PAPER_AXIS, temps, PAPER_AXIS.speed_rpm).m_total_nmm)
    mean = 0.5 * (np.asarray(config.asymmetry_cw_nmm) + np.asarray(config.asymmetry_ccw_nmm))
    return MeanFactors(temps, mean / m_nmm)


def cold_weight(t_c: ArrayLike, cold_c: float = RIPPLE_COLD_C, warm_c: float = RIPPLE_WARM_C) -> Array:
    """Cold weight w(t): 1 at ``cold_c`` and below, 0 at ``warm_c`` and above, linear between [-] (temperatures
    [°C]; default −40 and +20 °C, the ripple's)."""
    t = np.asarray(t_c, dtype=float)
    return np.asarray(np.clip((warm_c - t) / (warm_c - cold_c), 0.0, 1.0))


def position_ripple(theta_rad: ArrayLike, t_c: ArrayLike, amplitudes: Sequence[float], periods_deg: Sequence[float],
                    phases_rad: Sequence[float], cold_gain: float, cold_c: float = RIPPLE_COLD_C,
                    warm_c: float = RIPPLE_WARM_C) -> Array:
    """Position ripple r(θ, t) = (1 + cold_gain · w(t)) Σ a_k sin(2π θ / p_k + φ_k), a fraction of the friction
    [-], at joint angles ``theta_rad`` [rad] and bearing temperatures ``t_c`` [°C]: amplitudes a_k [-], spatial
    periods p_k [deg], phases φ_k [rad], w the :func:`cold_weight` between ``cold_c`` and ``warm_c`` [°C]. The one
    ripple of the suite's truths (the simulator's and the synthetic chamber test's)."""
    theta_deg = np.degrees(np.asarray(theta_rad, dtype=float))
    out = np.zeros(np.broadcast_shapes(theta_deg.shape, np.shape(t_c)))
    for a, p, phi in zip(amplitudes, periods_deg, phases_rad, strict=True):
        out = out + a * np.sin(2.0 * math.pi * theta_deg / p + phi)
    return np.asarray(out * (1.0 + cold_gain * cold_weight(t_c, cold_c, warm_c)))


def ripple(config: SimConfig, theta_rad: ArrayLike, t_c: ArrayLike) -> Array:
    """The simulator's position ripple (:func:`position_ripple` with ``config``'s ``ripple_*``) [-].

    >>> c = SimConfig(ripple_amplitudes=(0.1,), ripple_periods_deg=(4.0,), ripple_phases_rad=(0.0,))
    >>> [round(float(x), 6) for x in ripple(c, np.radians([1.0, 1.0]), [20.0, -40.0])]
    [0.1, 0.2]
    """
    return position_ripple(theta_rad, t_c, config.ripple_amplitudes, config.ripple_periods_deg,
                           config.ripple_phases_rad, config.ripple_cold_gain)


class TruthTerms(NamedTuple):
    """Everything of the truth that depends on temperature only, per run."""

    model: TemperatureTerms[Array]   #: the core table's temperature terms of the truth parameters
    k_positive: Array         #: m(t) · k_+(t) [-]
    k_negative: Array         #: m(t) · k_-(t) [-]


class TruthFriction:
    """The truth friction of the axis (see the module notes), vectorised over runs.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration: the truth's lubricant, Palmgren factor and motor, LuGre, ripple, asymmetry. The
        configuration under test (:class:`~gimbal_friction.physics.params.AxisParams`) plays no part.
    """

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.params = truth_params(config)
        self.table = FrictionTable(self.params, *TABLE_RANGE_C)
        self.means = mean_factors(config)
        self.no_load_torque_nm = self.params.torque_constant_nm_per_a * self.params.no_load_current_a
        self.sigma0 = config.sigma0_nm_per_rad
        self.sigma1 = config.sigma1_nm_s_per_rad
        self.v_s = config.stribeck_velocity_rad_s
        self.beta = config.breakaway_ratio
        self.presliding = config.presliding_model
        self.gms_stiffness = np.asarray(config.gms_stiffness_nm_per_rad, dtype=float)
        self.gms_weights = np.asarray(config.gms_weights, dtype=float) / float(np.sum(config.gms_weights))
        self.gms_attraction = config.gms_attraction_nm_per_s

    @property
    def presliding_stiffness_nm_per_rad(self) -> float:
        """Initial stiffness of the pre-sliding contact from rest [N·m/rad]: σ0 (LuGre) or Σ k_i (GMS)."""
        return float(np.sum(self.gms_stiffness)) if self.presliding == 'gms' else float(self.sigma0)

    def terms(self, t_c: ArrayLike) -> TruthTerms:
        """Temperature-dependent terms at bearing temperatures ``t_c`` [°C]."""
        t = np.asarray(t_c, dtype=float)
        m = self.means.at(t)
        one = np.ones(t.shape)
        return TruthTerms(self.table.temperature_terms(t, ARRAY),
                          m * direction_factor(self.params, t, one, ARRAY),
                          m * direction_factor(self.params, t, -one, ARRAY))

    def coulomb_nm(self, terms: TruthTerms, v: Array, ripple_factor: Array | float = 1.0) -> Array:
        """Sliding level F_C = m k_dir M(t, |v|) (1 + r) [N·m] (``ripple_factor`` = 1 + r)."""
        k = np.where(v >= 0.0, terms.k_positive, terms.k_negative)
        return np.asarray(k * self.table.magnitude_from_terms(terms.model, v, ARRAY) * ripple_factor)

    def stribeck_level_nm(self, terms: TruthTerms, v: Array, ripple_factor: Array | float = 1.0) -> Array:
        """LuGre level g(v) = F_C + (β F_C − F_C) e^{−(v/v_s)²} + T_0 [N·m] (> 0)."""
        f_c = self.coulomb_nm(terms, v, ripple_factor)
        return lugre_g_1995(v, f_c, self.beta * f_c, self.v_s) + abs(self.no_load_torque_nm)

    def static_torque_nm(self, t_c: ArrayLike, v: ArrayLike, theta_rad: ArrayLike = 0.0) -> Array:
        """Steady-state truth friction at constant velocity ``v`` [rad/s]: the LuGre static Stribeck curve, [N·m].

        ``F_ss = stribeck_curve_LuGre_1995(v, F_C, β F_C, v_s) + T_0 sgn v`` with the ripple at ``theta_rad``.
        """
        v = np.asarray(v, dtype=float)
        t = np.broadcast_to(np.asarray(t_c, dtype=float), v.shape)
        terms = self.terms(t)
        f_c = self.coulomb_nm(terms, v, 1.0 + ripple(self.config, theta_rad, t))
        return np.asarray(stribeck_curve_LuGre_1995(v, f_c, self.beta * f_c, self.v_s) +
                          abs(self.no_load_torque_nm) * np.sign(v))
