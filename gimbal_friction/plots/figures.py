"""Figures of the model (paper Figs. 5, 7–11) drawn with matplotlib's Agg backend (no display needed)."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.common.xp import ARRAY
from gimbal_friction.physics.direction import direction_factor
from gimbal_friction.physics.model import FrictionResult, friction_torque
from gimbal_friction.physics.params import AxisParams

#: Paper test means, Sec. 6 / Fig. 13: (temperature [°C], |torque| [N·mm]) per direction.
PAPER_TEST_CW = ((-40.0, 3.19), (60.0, 1.05))
PAPER_TEST_CCW = ((-40.0, 2.45), (60.0, 1.34))
#: The files :func:`model_figures` writes, in order.
MODEL_FIGURE_FILES = ('fig05_free_contact_angle.png', 'fig07_axial_force_gasket.png',
                      'fig08_axial_force_interference.png', 'fig09_torque_gasket.png', 'fig10_torque_interference.png',
                      'fig11_components.png')
#: The file of ``report``'s Fig. 13 (model vs measured).
FIG13_FILE = 'fig13_model_vs_measured.png'


def pyplot() -> Any:
    """matplotlib.pyplot on the non-interactive Agg backend (imported on first use)."""
    import matplotlib as mpl
    mpl.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig: Any, path: Path) -> Path:
    """Save ``fig`` as PNG at ``path`` (folders created; written atomically) and close it; an unwritable path is
    a GimbalFrictionError with the reason."""
    import io

    from gimbal_friction.common.files import write_bytes_atomic

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format='png', dpi=110)
    finally:
        pyplot().close(fig)
    write_bytes_atomic(path, buf.getvalue())  # whole or not at all: a full disk leaves no partial PNG
    return path


def plot_components(result: FrictionResult, path: Path, *, title: str = '', paper_points: bool = True) -> Path:
    """Fig. 11: M_L, M_S + M_R and M of the axis versus temperature [N·mm], with the paper's test means."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    t = result.temperature_c
    ax.plot(t, result.m_viscous_nmm, label='$M_L$ viscous (Eq. 9)')
    ax.plot(t, result.m_sliding_nmm + result.m_rolling_nmm, label='$M_S + M_R$ (Eqs. 3, 8)')
    ax.plot(t, result.m_total_nmm, lw=2.2, label='$M$ total (Eq. 10)')
    if paper_points:
        ax.plot(*zip(*PAPER_TEST_CW), 's', color='k', label='paper test mean, CW')
        ax.plot(*zip(*PAPER_TEST_CCW), '^', color='0.4', label='paper test mean, |CCW|')
    ax.set_xlabel('temperature [°C]')
    ax.set_ylabel('friction torque of the axis [N·mm]')
    ax.set_title(title or 'Friction torque and its components (paper Fig. 11)')
    ax.grid(True, alpha=0.4)
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, path)


def _family(params: AxisParams, t: np.ndarray, field: str, values: Sequence[float]) -> list[FrictionResult]:
    return [friction_torque(params.replace(**{field: v}), t) for v in values]


def _family_plot(path: Path, t: np.ndarray, results: list[FrictionResult], labels: list[str], quantity: str,
                 ylabel: str, title: str) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for res, label in zip(results, labels):
        y = res.m_sliding_nmm + res.m_rolling_nmm if quantity == 'ms_mr' else getattr(res, quantity)
        ax.plot(t, y, label=label)
    ax.set_xlabel('temperature [°C]')
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.4)
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, path)


def model_figures(params: AxisParams, out_dir: Path, t_min: float = -40.0, t_max: float = 60.0) -> list[Path]:
    """Paper Figs. 5, 7, 8, 9, 10 and 11 from the model, as PNG files in ``out_dir``."""
    t = np.linspace(t_min, t_max, 401)
    out = []
    deltas = [0.0, 0.004, 0.006, 0.008]
    res = _family(params, t, 'interference_mm', deltas)
    out.append(_family_plot(out_dir / MODEL_FIGURE_FILES[0], t, res, [f'Δ = {d:g} mm' for d in deltas],
                            'free_contact_angle_deg', 'free contact angle α° [deg]',
                            'Free contact angle vs temperature for several interferences (paper Fig. 5)'))
    gaskets = [0.0, 0.01, 0.02, 0.03]
    res_p = _family(params, t, 'gasket_thickness_mm', gaskets)
    labels_p = [f'P = {g:g} mm' for g in gaskets]
    d_now = params.interference_mm
    out.append(_family_plot(out_dir / MODEL_FIGURE_FILES[1], t, res_p, labels_p, 'axial_force_n',
                            'axial force per bearing F_a [N]',
                            f'Axial force for several gasket thicknesses, Δ = {d_now:g} mm (paper Fig. 7)'))
    deltas8 = [0.004, 0.006, 0.008]
    res_d = _family(params, t, 'interference_mm', deltas8)
    labels_d = [f'Δ = {d:g} mm' for d in deltas8]
    p_now = params.gasket_thickness_mm
    out.append(_family_plot(out_dir / MODEL_FIGURE_FILES[2], t, res_d, labels_d, 'axial_force_n',
                            'axial force per bearing F_a [N]',
                            f'Axial force for several interferences, P = {p_now:g} mm (paper Fig. 8)'))
    out.append(_family_plot(out_dir / MODEL_FIGURE_FILES[3], t, res_p, labels_p, 'ms_mr',
                            '$M_S + M_R$ of the axis [N·mm]',
                            f'$M_S + M_R$ for several gasket thicknesses, Δ = {d_now:g} mm (paper Fig. 9)'))
    out.append(_family_plot(out_dir / MODEL_FIGURE_FILES[4], t, res_d, labels_d, 'ms_mr',
                            '$M_S + M_R$ of the axis [N·mm]',
                            f'$M_S + M_R$ for several interferences, P = {p_now:g} mm (paper Fig. 10)'))
    out.append(plot_components(friction_torque(params, t), out_dir / MODEL_FIGURE_FILES[5]))
    return out


def plot_model_vs_measured(summary: Sequence[dict[str, Any]], models: dict[str, AxisParams], path: Path, *,
                           title: str = '', offsets_nmm: Mapping[str, float] | None = None,
                           fitted_direction: Mapping[str, str] | None = None,
                           notes: Sequence[str] = ()) -> Path:
    """Fig. 13: measured mean friction per plateau by direction (|CCW| shown positive) and model curves.

    ``summary`` holds records of :func:`gimbal_friction.estimation.residuals.plateau_summary` (signed means [N·mm]);
    ``models`` maps a label to the parameters of a model curve (e.g. before and after a refit); ``offsets_nmm`` a
    label to the calibration torque offset [N·mm] a refit fitted beside its parameters, added to that curve's
    magnitude (the refit model of the measurement, as the refit's table shows it); ``fitted_direction`` a label to
    the one direction ('cw' or 'ccw') its refit was fitted on: that curve is drawn for that direction, and the other
    direction's thin and grey, labelled as not fitted; ``notes`` are lines printed under the title (what a model is
    good for).
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    temps = [float(r['temperature_c']) for r in summary] or [-40.0, 60.0]
    t = np.linspace(min(*temps, -40.0), max(*temps, 60.0), 301)
    for (label, params), style in zip(models.items(), ('-', '--', ':', '-.')):
        m = friction_torque(params, t).m_total_nmm
        shift = float((offsets_nmm or {}).get(label, 0.0))
        cw, ccw = (direction_factor(params, t, np.full(t.shape, d), ARRAY) * m + shift for d in (1.0, -1.0))
        if shift:
            label = f'{label}, offset {shift:+.3g} N·mm'
        side = (fitted_direction or {}).get(label.split(', offset')[0], 'both')
        if side in ('cw', 'ccw'):   # fitted on one direction: the other is drawn as what it is, not a fit
            fitted, other = (cw, ccw) if side == 'cw' else (ccw, cw)
            name, other_name = side.upper(), ('CCW' if side == 'cw' else 'CW')
            ax.plot(t, fitted, style, lw=2, color='tab:blue' if side == 'cw' else 'k',
                    label=f'model {name}: {label} (fitted on {name} only)')
            ax.plot(t, other, ':', lw=1, color='0.6', label=f'model |{other_name}|: {label} (NOT fitted: '
                    f'{name} fit, for {name} motion)')
        elif np.allclose(cw, ccw):
            ax.plot(t, cw, style, lw=2, label=f'model: {label}')
        else:  # a per-direction term: both curves
            ax.plot(t, cw, style, lw=2, color='tab:blue', label=f'model CW: {label}')
            ax.plot(t, ccw, style, lw=2, color='k', label=f'model |CCW|: {label}')
    for direction, marker, color in (('cw', 's', 'tab:blue'), ('ccw', '^', 'k')):
        rows = [r for r in summary if r['direction'] == direction]
        if rows:
            ax.errorbar([float(r['temperature_c']) for r in rows], [abs(float(r['measured_mean_nmm'])) for r in rows],
                        yerr=[float(r.get('measured_std_nmm', 0.0)) for r in rows], fmt=marker, color=color,
                        capsize=3,
                        label=f'measured mean ± std, {direction.upper()}' + (' (|.|)' if direction == 'ccw' else ''))
    ax.plot(*zip(*PAPER_TEST_CW), 'x', color='tab:red', label='paper test mean, CW')
    ax.set_xlabel('temperature [°C]')
    ax.set_ylabel('friction torque of the axis [N·mm]')
    head = title or 'Model vs measured friction by direction (paper Fig. 13)'
    lines = [line for note in notes for line in textwrap.wrap(note, 100)]
    ax.set_title('\n'.join([head, *lines]), fontsize=8 if notes else None)
    ax.grid(True, alpha=0.4)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
