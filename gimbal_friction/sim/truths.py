"""A seeded generator of physically plausible truths for the simulated axis: gimbals nobody described to the suite.

One job in one module: :func:`draw_truth` (every parameter of a truth drawn from one seeded stream, so truth ``k``
of seed ``s`` is the same on every machine).

A learned correction is judged on truths it was not tuned to. Each draw is the paper's bearing with its own:

- **lubricant**: another oil, with its own viscosity–temperature slope: its viscosity is the datasheet's × a factor
  log-uniform in [0.4, 3] at −40 °C and in [0.7, 1.5] at +60 °C, the Walther line (Eq. 21) through both points
  (``truth_walther_a``, ``truth_walther_b``; the slope then differs from the datasheet's by up to about ±1 %: the
  Walther constants are so sensitive that a slope 3 % off with the same a1 would make the oil 10⁴ times thicker at
  −40 °C, a grease no gimbal could move); Palmgren factor ``truth_palmgren_factor`` in [1.5, 2.5];
- **direction asymmetry and mean factor**: at −40 and +60 °C the measured means ``CW, |CCW| = M m (1 ± a)`` with
  the paper's model M, a mean factor m in [0.85, 1.15] and an asymmetry a in [−0.2, 0.2] at each anchor (either
  sign: a reversed asymmetry is as plausible as the paper's);
- **position ripple**: 1 to 3 sines with periods log-uniform in [0.5°, 6°], amplitudes in [1 %, 8 %] of the friction,
  random phases, amplified in the cold by a gain in [0, 1.5] (all amplitudes × (1 + gain) below 0.6);
- **Stribeck curve**: Stribeck velocity log-uniform in [0.001, 0.03] rad/s, breakaway ratio in [1, 2.5];
- **unbalance**: half the draws a constant torque in ±2.5 N·mm, half (independently) one that depends on the joint
  angle, amplitude up to 3 N·mm at a random phase;
- **motor**: a no-load current up to 4 mA in 30 % of the draws, the torque constant within ±3 % of the configured;
- **sensor**: a temperature offset in ±3 °C and a lag of 2 … 60 s;
- **plant**: the inertia 0.8 … 1.25 × the configured;
- **base motion**: the body rates × 0.5 … 3 (not a truth parameter: a configuration of the simulator);
- **pre-sliding family** (from a second seeded stream, so every other parameter of a truth is what it was before
  the family was drawn): half the draws LuGre (as above), half the generalized Maxwell-slip model
  (:mod:`gimbal_friction.sim.gms`) with 3 to 6 elements whose shares of the Stribeck level are Dirichlet-drawn and
  which saturate, at the truth's own breakaway level at +20 °C, after displacements log-uniform between a third and
  three times a characteristic pre-sliding distance, itself log-uniform in [5, 50] µrad (the stiffnesses then stay
  fixed and the limits follow the truth's Stribeck curve at every temperature; stiffnesses scaled down where the
  plant step would need ``h √(Σk/J)`` above 1.2);
- **unbalance at every plateau** (the same second stream, 40 % of the draws): a constant, direction-independent
  torque of 0.5 … 3 N·mm of either sign *and* an angle-dependent unbalance of 0.5 … 3 N·mm at a random phase (the
  ``m g r cos``-like term of the plant), both present at every temperature (they replace the draws above).

>>> a, b = draw_truth(7), draw_truth(7)
>>> a == b, a.truth['ripple_periods_deg'] == b.truth['ripple_periods_deg']
(True, True)
>>> cfg = a.config(SimConfig())          # validated: every draw is a truth the simulator accepts
>>> cfg.truth_walther_b == a.truth['truth_walther_b']
True
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from gimbal_friction.physics.model import friction_torque
from gimbal_friction.sim.config import SimConfig
from gimbal_friction.sim.truth import PAPER_AXIS, TruthFriction

__all__ = ['GeneratedTruth', 'draw_truth', 'draw_truths', 'truth_mapping']

#: The paper's model at the asymmetry anchors (−40, +60 °C) at 1/3 rpm [N·mm] (what the measured means scale).
_ANCHORS_C = (-40.0, 60.0)


class GeneratedTruth(NamedTuple):
    """One generated truth: its seed, its truth parameters and the simulator settings it changes."""

    seed: int
    truth: dict[str, Any]     #: truth parameters (``loop-study --truth`` accepts them)
    sim: dict[str, Any]       #: other simulator parameters (base motion)
    base_scale: float = 1.0   #: the body rates' factor over the configured [-]
    kinds: tuple[str, ...] = ()   #: named hidden kinds drawn for this truth (``unbalance at every plateau``)

    def config(self, base: SimConfig) -> SimConfig:
        """``base`` with this truth (validated)."""
        return SimConfig.from_mapping({**self.truth, **self.sim}, base=base)

    def describe(self) -> str:
        """One line: what is unusual about this truth."""
        t = self.truth
        rip = ', '.join(f'{p:.2g} deg {a * 100:.1f} %' for p, a in zip(t['ripple_periods_deg'],
                                                                       t['ripple_amplitudes'], strict=True))
        if t.get('presliding_model', 'lugre') == 'gms':
            family = (f'pre-sliding gms {len(t["gms_stiffness_nm_per_rad"])} elements '
                      f'(k {min(t["gms_stiffness_nm_per_rad"]):.3g}..{max(t["gms_stiffness_nm_per_rad"]):.3g} N*m/rad)')
        else:
            family = 'pre-sliding lugre'
        kinds = ''.join(f', {k}' for k in self.kinds)
        return (f'truth {self.seed}: {family}{kinds}, walther a {t["truth_walther_a"]:.4f} '
                f'b {t["truth_walther_b"]:.3f}, '
                f'palmgren {t["truth_palmgren_factor"]:.2f}, ripple {rip} (cold x{1 + t["ripple_cold_gain"]:.2f}), '
                f'stribeck {t["stribeck_velocity_rad_s"]:.3g} rad/s x{t["breakaway_ratio"]:.2f}, unbalance '
                f'{t["disturbance_torque_nm"] * 1e3:+.2f} N*mm + {t["unbalance_torque_nm"] * 1e3:.2f} N*mm sin, '
                f'sensor {t["temperature_bias_c"]:+.1f} degC lag {t["temperature_sensor_time_constant_s"]:.0f} s, '
                f'inertia x{t["inertia_truth_ratio"]:.2f}, base x{self.base_scale:.2f}')


def _walther_through(cfg: SimConfig, ratio_cold: float, ratio_warm: float) -> tuple[float, float]:
    """Walther constants (a1, b1) of Eq. 21 (``log log(ν + c1) = a1 + b1 log log T``) of an oil whose viscosity is the
    datasheet's (``cfg``'s truth lubricant) × ``ratio_cold`` at −40 °C and × ``ratio_warm`` at +60 °C."""
    from gimbal_friction.physics.viscosity import nu_Walther
    c1 = PAPER_AXIS.viscosity_offset_cst
    a0, b0 = cfg.truth_walther_a + cfg.lubricant_walther_a_shift, cfg.truth_walther_b
    temps = np.array(_ANCHORS_C) + 273.0
    nu = np.asarray(nu_Walther(temps, a0, b0, c1)) * np.array([ratio_cold, ratio_warm])
    y = np.log10(np.log10(nu + c1))
    x = np.log10(np.log10(temps))
    b1 = float((y[1] - y[0]) / (x[1] - x[0]))
    return float(y[0] - b1 * x[0]), b1


def draw_truth(seed: int, base: SimConfig | None = None) -> GeneratedTruth:
    """Truth number ``seed`` (see the module notes); ``base`` gives the configured base motion and K_T (default
    the simulator's defaults)."""
    cfg = base if base is not None else SimConfig()
    rng = np.random.default_rng([20261127, int(seed)])
    u = rng.uniform
    m_paper = np.atleast_1d(friction_torque(PAPER_AXIS, list(_ANCHORS_C), PAPER_AXIS.speed_rpm).m_total_nmm)
    mean = np.array([u(0.85, 1.15), u(0.85, 1.15)])
    asym = np.array([u(-0.2, 0.2), u(-0.2, 0.2)])
    cw = m_paper * mean * (1.0 + asym)
    ccw = m_paper * mean * (1.0 - asym)
    k = int(rng.integers(1, 4))
    periods = np.exp(u(math.log(0.5), math.log(6.0), k))
    amps = u(0.01, 0.08, k)
    gain = u(0.0, 1.5)
    total = float(amps.sum()) * (1.0 + gain)
    if total > 0.6:
        amps *= 0.6 / total
    constant = u(-2.5e-3, 2.5e-3) if rng.uniform() < 0.5 else 0.0
    angle_amp, angle_phase = (u(0.0, 3e-3), u(-math.pi, math.pi)) if rng.uniform() < 0.5 else (0.0, 0.0)
    no_load = u(0.0, 0.004) if rng.uniform() < 0.3 else 0.0
    a1, b1 = _walther_through(cfg, float(np.exp(u(math.log(0.4), math.log(3.0)))),
                              float(np.exp(u(math.log(0.7), math.log(1.5)))))
    truth: dict[str, Any] = {
        'truth_walther_a': round(a1, 6),
        'lubricant_walther_a_shift': 0.0,
        'truth_walther_b': round(b1, 6),
        'truth_palmgren_factor': round(u(1.5, 2.5), 4),
        'asymmetry_enabled': True,
        'asymmetry_temperatures_c': _ANCHORS_C,
        'asymmetry_cw_nmm': tuple(round(float(x), 4) for x in cw),
        'asymmetry_ccw_nmm': tuple(round(float(x), 4) for x in ccw),
        'ripple_amplitudes': tuple(round(float(a), 5) for a in amps),
        'ripple_periods_deg': tuple(round(float(p), 4) for p in periods),
        'ripple_phases_rad': tuple(round(float(x), 4) for x in u(0.0, 2.0 * math.pi, k)),
        'ripple_cold_gain': round(gain, 4),
        'stribeck_velocity_rad_s': round(float(np.exp(u(math.log(0.001), math.log(0.03)))), 6),
        'breakaway_ratio': round(u(1.0, 2.5), 4),
        'disturbance_torque_nm': round(constant, 7),
        'unbalance_torque_nm': round(angle_amp, 7),
        'unbalance_phase_rad': round(angle_phase, 4),
        'truth_no_load_current_a': round(no_load, 6),
        'truth_torque_constant_nm_per_a': round(cfg.truth_torque_constant_nm_per_a * u(0.97, 1.03), 6),
        'temperature_bias_c': round(u(-3.0, 3.0), 3),
        'temperature_sensor_time_constant_s': round(u(2.0, 60.0), 2),
        'inertia_truth_ratio': round(u(0.8, 1.25), 4),
    }
    scale = u(0.5, 3.0)
    sim = {'base_motion_amplitudes_rad_s': tuple(round(a * scale, 6) for a in cfg.base_motion_amplitudes_rad_s)}
    kinds = _draw_family_and_unbalance(np.random.default_rng([20261127, int(seed), 34]), truth, cfg)
    out = GeneratedTruth(int(seed), truth, sim, round(scale, 4), kinds)
    out.config(cfg)   # every draw must be a valid truth (raises ConfigError otherwise)
    return out


def _draw_family_and_unbalance(rng: np.random.Generator, truth: dict[str, Any], cfg: SimConfig) -> tuple[str, ...]:
    """Draw the pre-sliding family and the unbalance-at-every-plateau kind into ``truth`` (see the module notes);
    the kinds drawn. Every number is drawn whatever the family, so the unbalance draws do not depend on it."""
    u = rng.uniform
    gms = u() < 0.5
    n = int(rng.integers(3, 7))
    distance_rad = float(np.exp(u(math.log(5e-6), math.log(50e-6))))
    spread = np.sort(np.exp(u(math.log(1.0 / 3.0), math.log(3.0), n)))
    weights = np.maximum(rng.dirichlet(np.full(n, 2.0)), 1e-3)
    weights /= weights.sum()
    unbalance = u() < 0.4
    constant = u(0.5e-3, 3e-3) * (1.0 if u() < 0.5 else -1.0)
    angle_amp, angle_phase = u(0.5e-3, 3e-3), u(-math.pi, math.pi)
    truth['presliding_model'] = 'gms' if gms else 'lugre'
    if gms:
        w = [round(float(x), 5) for x in weights[:-1]]
        w.append(round(1.0 - sum(w), 5))
        level = TruthFriction(SimConfig.from_mapping(truth, base=cfg))
        s20 = float(level.stribeck_level_nm(level.terms(np.array([20.0])), np.zeros(1))[0])
        k = np.array(w) * s20 / (distance_rad * spread)
        j = PAPER_AXIS.inertia_kg_m2 * float(truth['inertia_truth_ratio'])
        k_max = (1.2 / cfg.plant_step_s) ** 2 * j
        if k.sum() > k_max:
            k *= k_max / k.sum()
        truth['gms_stiffness_nm_per_rad'] = tuple(float(f'{x:.5g}') for x in k)
        truth['gms_weights'] = tuple(w)
        truth['gms_attraction_nm_per_s'] = 0.0
    if unbalance:
        truth['disturbance_torque_nm'] = round(constant, 7)
        truth['unbalance_torque_nm'] = round(angle_amp, 7)
        truth['unbalance_phase_rad'] = round(angle_phase, 4)
        return ('unbalance at every plateau',)
    return ()


def draw_truths(n: int, first_seed: int = 0, base: SimConfig | None = None) -> list[GeneratedTruth]:
    """Truths ``first_seed`` … ``first_seed + n − 1``."""
    return [draw_truth(first_seed + k, base) for k in range(n)]


def truth_mapping(t: GeneratedTruth) -> Mapping[str, Any]:
    """The truth parameters as a ``loop-study --truth`` file holds them (lists for tuples)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in t.truth.items()}
