"""The model of the refit's samples (or fine bins): :class:`SampleModel`, the torque and its Jacobian in the fit
parameters (Eqs. 9, 20/21, the direction factor)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.physics.direction import ARRAY, asymmetry_weight, direction_asymmetry, direction_factor
from gimbal_friction.physics.friction import viscous_torque_Palmgren_1959
from gimbal_friction.physics.model import friction_torque
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.physics.thermal import radial_coupling
from gimbal_friction.physics.viscosity import nu_Walther, nu_Walther_fitting_jacobian, walther_abscissa
from gimbal_friction.refit.results import FIT_PARAMETERS, GRID_STEP_C, OFFSET, PALMGREN_THRESHOLD, Array

# ------------------------------------------------------------------------------------------------------------
# the model of the samples (or of the fine bins)


def _dML_dnu_Palmgren_1959(s0: float, nu0: Array, n: Array, d_m: Array) -> Array:
    """dM_L/dν of Eq. (9) (Palmgren 1959), [N·mm per mm²/s]: ``(2/3) M_L/ν`` in the upper branch ``ν n ≥ 2000``,
    0 in the lower one (where M_L does not depend on ν). Uses
    :func:`~gimbal_friction.physics.friction.viscous_torque_Palmgren_1959` for M_L."""
    m_l = viscous_torque_Palmgren_1959(s0, nu0, n, d_m)
    upper = nu0 * np.abs(n) >= PALMGREN_THRESHOLD
    safe = np.where(upper, nu0, 1.0)
    return np.where(upper, (2.0 / 3.0) * m_l / safe, 0.0)


class SampleModel:
    """|τ| of every sample (or fine bin) as a function of the fit parameters, with its analytic jacobian, [N·mm].

    M_R and S = M_S/μ come from the full model of ``base`` on a grid (they do not depend on the fit parameters);
    the pitch diameter d_m(t) likewise (steel expansion). Everything else is evaluated per call with the
    package's functions (Walther, Palmgren Eq. 9, the direction factor).

    Parameters
    ----------
    base : AxisParams
        Parameters held fixed (and the starting values of the fit).
    temperature_c, speed_rpm, direction : array_like
        Per sample: temperature [°C], speed magnitude [rpm], direction ±1.
    """

    def __init__(self, base: AxisParams, temperature_c: ArrayLike, speed_rpm: ArrayLike,
                 direction: ArrayLike) -> None:
        self.base = base
        self.t = np.asarray(temperature_c, dtype=float)
        self.n = np.abs(np.asarray(speed_rpm, dtype=float))
        self.d = np.where(np.asarray(direction, dtype=float) > 0.0, 1.0, -1.0)
        self.positive = self.d > 0.0
        lo = math.floor(float(self.t.min()) / GRID_STEP_C) * GRID_STEP_C - GRID_STEP_C
        hi = math.ceil(float(self.t.max()) / GRID_STEP_C) * GRID_STEP_C + GRID_STEP_C
        grid = lo + GRID_STEP_C * np.arange(int(round((hi - lo) / GRID_STEP_C)) + 1)
        unit = dataclasses.replace(base, sliding_friction_coefficient=1.0)
        res = friction_torque(unit, grid, 0.0)
        self.m_rolling = np.interp(self.t, grid, res.m_rolling_nmm)        # M_R of the axis [N·mm]
        self.s_unit = np.interp(self.t, grid, res.m_sliding_nmm)           # M_S at μ = 1 [N·mm]
        self.d_m = radial_coupling(base, self.t).d_m                       # [mm]
        self.T = self.t + base.kelvin_offset_k                             # [K]
        self.x = walther_abscissa(self.T, base.viscosity_model)                   # Walther abscissa [-]
        self.w = asymmetry_weight(base, self.t, ARRAY)                     # warm-anchor weight [-]

    def values(self, changes: Mapping[str, float] | None = None) -> dict[str, float]:
        """The fit parameters of ``base`` (and the offset, 0) with ``changes`` applied."""
        out = {name: float(getattr(self.base, name)) for name in FIT_PARAMETERS}
        out[OFFSET] = 0.0
        out.update({k: float(v) for k, v in (changes or {}).items()})
        return out

    def params(self, v: Mapping[str, float]) -> AxisParams:
        """``base`` with the fit parameters ``v`` (not validated: used inside the fit only)."""
        changes = cast('dict[str, Any]', {name: v[name] for name in FIT_PARAMETERS})
        return dataclasses.replace(self.base, **changes)

    def viscosity_cst(self, v: Mapping[str, float]) -> Array:
        """ν of every sample, Eq. (20)/(21), [mm²/s]."""
        return nu_Walther(self.T, v['walther_a'], v['walther_b'], v['viscosity_offset_cst'],
                          self.base.viscosity_model)

    def upper_branch(self, v: Mapping[str, float]) -> NDArray[np.bool_]:
        """Samples in Palmgren's upper branch ``ν·n ≥ 2000`` (M_L depends on ν), Eq. (9)."""
        return np.asarray(self.viscosity_cst(v) * self.n >= PALMGREN_THRESHOLD, dtype=bool)

    def torque_nmm(self, v: Mapping[str, float], *, offset: bool = True) -> Array:
        """|τ| of every sample, [N·mm] (with the offset, or the friction alone)."""
        tau = self._evaluate(v, ())[0]
        return tau if offset else tau - 1e3 * v[OFFSET]

    def jacobian_nmm(self, v: Mapping[str, float], names: Sequence[str]) -> Array:
        """d|τ|/dθ of every sample for the parameters ``names`` (raw, as in AxisParams; the offset per N·m),
        shape (n, len(names))."""
        return self._evaluate(v, names)[1]

    def _evaluate(self, v: Mapping[str, float], names: Sequence[str]) -> tuple[Array, Array]:
        model = self.base.viscosity_model
        a1, b1, c1, s0 = v['walther_a'], v['walther_b'], v['viscosity_offset_cst'], v['palmgren_factor']
        nu = nu_Walther(self.T, a1, b1, c1, model)
        z = float(self.base.bearings_per_axis)
        m_l = z * viscous_torque_Palmgren_1959(s0, nu, self.n, self.d_m)
        m = self.m_rolling + v['sliding_friction_coefficient'] * self.s_unit + m_l
        p = self.params(v)
        k = direction_factor(p, self.t, self.d, ARRAY)
        tau = k * m + 1e3 * v[OFFSET]
        if not names:
            return tau, np.empty((tau.shape[0], 0))
        dtau_dnu = k * z * _dML_dnu_Palmgren_1959(s0, nu, self.n, self.d_m)
        jac_nu = nu_Walther_fitting_jacobian(self.T, a1, b1, c1, model)       # dν/d(a1, b1, c1)
        a_t = direction_asymmetry(p, self.t, ARRAY)
        s_d = np.where(self.positive, p.scale_positive, -p.scale_negative)    # d k / d a
        cols = {
            'walther_a': dtau_dnu * jac_nu[:, 0],
            'walther_b': dtau_dnu * jac_nu[:, 1],
            'viscosity_offset_cst': dtau_dnu * jac_nu[:, 2],
            'palmgren_factor': k * m_l / s0 if s0 != 0.0 else k * 0.0,
            'sliding_friction_coefficient': k * self.s_unit,
            'scale_positive': np.where(self.positive, (1.0 + a_t) * m, 0.0),
            'scale_negative': np.where(self.positive, 0.0, (1.0 - a_t) * m),
            'direction_asymmetry_cold': s_d * (1.0 - self.w) * m,
            'direction_asymmetry_warm': s_d * self.w * m,
            OFFSET: np.full(tau.shape, 1e3),
        }
        return tau, np.column_stack([cols[name] for name in names])


def measurement_model_nmm(params: AxisParams, temperature_c: ArrayLike, speed_rpm: ArrayLike, direction: ArrayLike,
                          offset_nm: float = 0.0) -> Array:
    """What a refitted model says the measurement is at each sample (or fine bin), |τ| [N·mm]: the friction of
    ``params`` along the motion, ``k_d(t) M(t, n)`` (:class:`SampleModel`), plus the calibration torque offset the
    refit fitted beside it, ``offset_nm`` [N·m] (0: none).

    One function for "the refit model at a plateau": the refit's table (``model after``, the mean over a group's
    fine bins) and ``report --compare`` (``refit model``, the mean over a plateau's samples) both average it.
    ``temperature_c`` [°C], ``speed_rpm`` [rpm] (magnitude), ``direction`` ±1 (positive: the paper's CW).

    >>> from gimbal_friction.physics.params import AxisParams
    >>> base = measurement_model_nmm(AxisParams(), [20.0], [1 / 3], [1])
    >>> round(float(base[0]), 3)                                        # the model's 1.046 N*mm at 20 degC
    1.046
    >>> round(float(measurement_model_nmm(AxisParams(), [20.0], [1 / 3], [1], offset_nm=1e-4)[0] - base[0]), 9)
    0.1
    """
    model = SampleModel(params, temperature_c, speed_rpm, direction)
    return model.torque_nmm(model.values({OFFSET: offset_nm}))
