"""The per-plateau summary (the paper's Fig. 13 table) of a replayed bag or of residual logs: one rule for
``replay`` (``summary.json``) and ``report``, with the refit model of the measurement beside it for
``report --compare``.

Both judge the plateaus on the bearing-temperature stream (:mod:`gimbal_friction.estimation.plateaus`): the bag's
``/gimbal/temperature`` in a replay, the same topic as logged among the residual log's inputs in a report (a log
written without its inputs, ``replay --no-inputs`` or ``residual_logger`` with ``log_inputs`` false, falls back to
the samples' own temperatures and says so). The bins and the valid temperature range are the estimator's settings
(``temperature_bin_c``, ``temperature_min_c``, ``temperature_max_c`` of ``friction_estimator`` in the parameter
files), so a summary, the estimator's statistics and the refit's groups (same bin width) count the same samples on
every plateau they show.

The refit model of a plateau (:func:`log_summary` with ``compare``) is the mean over the plateau's samples of
:func:`~gimbal_friction.refit.model.measurement_model_nmm`: the compared parameters plus the calibration torque
offset the refit wrote into the file (:func:`~gimbal_friction.refit.records.read_refit_offsets`), which is what the
refit's own table shows as ``model after``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gimbal_friction.common.errors import GimbalFrictionError
from gimbal_friction.common.settings import settings_from_parameters
from gimbal_friction.common.units import NS_PER_S, rpm_from_rad_s
from gimbal_friction.config.loader import axis_params, load_parameters
from gimbal_friction.estimation.gating import EstimatorSettings
from gimbal_friction.estimation.plateaus import temperature_stream
from gimbal_friction.estimation.residuals import plateau_summary
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.recording.residual_read import ReadReport, read_residual_rows, read_temperature_stream
from gimbal_friction.refit.model import measurement_model_nmm
from gimbal_friction.refit.records import read_refit_offsets
from gimbal_friction.streams.arrays import ChamberArrays
from gimbal_friction.streams.inputs import effective_time
from gimbal_friction.streams.residual_row import ResidualRows

__all__ = ['LogSummary', 'log_summary', 'replay_summary']


def _summary(rows: ResidualRows, est: EstimatorSettings, stream: tuple[NDArray[np.float64], NDArray[np.float64]],
             compare: Any = None) -> list[dict[str, Any]]:
    """:func:`plateau_summary` of ``rows`` with the estimator's bins, judged on the (valid part of the) stream."""
    valid = temperature_stream(stream[0], stream[1], est.temperature_min_c, est.temperature_max_c)
    return plateau_summary(rows.temperature_c, rows.velocity_rad_s, rows.measured_nm, rows.predicted_nm,
                           joint=rows.joint.tolist(), bin_c=est.temperature_bin_c, stamp_s=rows.stamp_s,
                           temperature_stream=valid, compare=compare)


def replay_summary(arrays: ChamberArrays, rows: ResidualRows, est: EstimatorSettings) -> list[dict[str, Any]]:
    """The per-plateau summary of a replay: the residual ``rows``, the plateaus judged on the bag's temperature
    stream (``arrays.temperature``, at its stamps, or log times where a stamp is zero: the samples' time rule)."""
    t = arrays.temperature
    t_time = effective_time(np.asarray(t.stamp_ns, dtype=np.int64), np.asarray(t.log_time_ns, dtype=np.int64))
    return _summary(rows, est, (t_time / NS_PER_S, np.asarray(t.temperature_c, dtype=np.float64)))


class LogSummary(NamedTuple):
    """:func:`log_summary`'s result."""

    summary: list[dict[str, Any]]      #: per plateau and direction (:func:`plateau_summary`), ``compare_nmm`` too
    rows: int                          #: residual rows of the axis
    read: ReadReport                   #: what the read of the logs skipped
    stream_logged: bool                #: the logs hold the temperature stream (else: the samples' own temperatures)
    compared: AxisParams | None        #: the parameters of ``--config`` + the compared file (None: no compare)
    compare_offset_nm: float           #: the calibration torque offset the compared file carries [N·m] (0: none)


def log_summary(logs: Sequence[Path], axis: str, config_paths: Sequence[Path] = (),
                compare: Path | None = None) -> LogSummary:
    """The per-plateau summary of ``axis`` in residual logs (what ``report`` tabulates and draws as Fig. 13).

    With ``compare`` (a parameter file layered over ``config_paths``, e.g. refit's output) every record has
    ``compare_nmm``: the refit model of the measurement at the plateau (signed [N·mm]), with the torque offset the
    file carries (none for a file without refit's section).

    Raises:
        RecordingError: the logs cannot be read.
        ConfigError: a bad parameter file or refit section.
        GimbalFrictionError: the logs hold no samples of ``axis`` (the joints present, and what to pass).
    """
    data, report = read_residual_rows(list(logs))
    where = ', '.join(str(p) for p in logs)
    sel = data.joint == axis
    if not sel.any():
        present = sorted({str(j) for j in data.joint.tolist()})
        why = (f'joints present: {", ".join(present)}; pass --axis with one of them or --config with those axes'
               if present else f'no residual rows at all: {report.summary()}')
        msg = f'{where}: the residual logs hold no samples of axis {axis!r} ({why})'
        raise GimbalFrictionError(msg)
    rows = data.select(np.flatnonzero(sel))
    est = settings_from_parameters(EstimatorSettings, load_parameters(list(config_paths),
                                                                      node_name='friction_estimator'))
    stream = read_temperature_stream(list(logs))
    compared, offset_nm, model = None, 0.0, None
    if compare is not None:
        compared = axis_params(load_parameters([*config_paths, compare]), axis)
        offset_nm = read_refit_offsets(compare).get(axis, 0.0)
        params = compared

        def model(t_c: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
            sign = np.sign(v)
            return sign * measurement_model_nmm(params, t_c, rpm_from_rad_s(np.abs(v)), sign, offset_nm)

    summary = _summary(rows, est, stream, model)
    return LogSummary(summary, int(sel.sum()), report, stream[0].size >= 2, compared, offset_nm)
