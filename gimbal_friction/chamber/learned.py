"""The learned correction of a chamber test: from residual logs against the model of a layered configuration
(``refit`` and ``fleet``), or from a chamber test's streams through the whole chamber path (the loop study's case
``chamber``, :func:`chamber_correction`).

The model is the one the feedforward will run: the parameter files in order, the refitted file last; the
correction's layout and shrinkage come from the ``correction_*`` parameters of ``friction_feedforward`` (defaults
for those not given), so the node accepts the file. The rows are streamed by
:func:`~gimbal_friction.refit.logs.read_correction`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gimbal_friction.chamber.replay import replay_arrays
from gimbal_friction.common.settings import settings_from, settings_from_parameters
from gimbal_friction.config.loader import all_axis_params, load_parameters
from gimbal_friction.estimation.estimator import EstimatorSettings
from gimbal_friction.feedforward.correction import RETIRED, Correction, CorrectionSettings, model_identity
from gimbal_friction.feedforward.rule import Feedforward, FeedforwardSettings
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.refit.logs import LearnedCorrection, correction_table, learn_rows, read_correction
from gimbal_friction.streams.arrays import ChamberArrays

__all__ = ['chamber_correction', 'correction_record', 'correction_settings', 'learn_correction']


def correction_settings(params: Mapping[str, Any]) -> CorrectionSettings:
    """The layout of a learned correction from the ``correction_<field>`` parameters of ``friction_feedforward``
    (merged ``ros__parameters``; defaults for those not given), validated (ConfigError naming the parameter)."""
    return settings_from(CorrectionSettings, {k[len('correction_'):]: v for k, v in params.items()
                                              if k.startswith('correction_') and k[len('correction_'):] not in RETIRED})


def learn_correction(logs: Sequence[Path], layers: Sequence[Path], label: str = 'correction: reading'
                     ) -> LearnedCorrection:
    """The correction of ``logs`` against the model of the parameter files ``layers`` (the configuration with the
    refitted file last), learned and settled (not saved)."""
    node = load_parameters(list(layers), node_name='friction_feedforward')
    return read_correction(list(logs), all_axis_params(load_parameters(list(layers))),
                           settings=correction_settings(node),
                           feedforward_settings=settings_from_parameters(FeedforwardSettings, node), label=label)


def correction_record(learned: LearnedCorrection, path: Path) -> dict[str, Any]:
    """The JSON record of a written correction: the file, its cells (N*mm, °C), rows read and samples refused per
    joint, the samples learned."""
    _, records = correction_table(learned.correction)
    return {'out': str(path), 'cells': records, 'rows': learned.rows, 'refused': learned.refused,
            'samples': sum(r['samples'] for r in records)}


def chamber_correction(streams: Sequence[ChamberArrays], axis: AxisParams, estimator: EstimatorSettings,
                       settings: CorrectionSettings, joint: str = 'elevation',
                       feedforward: FeedforwardSettings | None = None) -> tuple[Correction, dict[str, Any]]:
    """The correction a chamber test's streams give through the chamber path: each plateau's streams (in time order)
    replayed through the three nodes' logic (:func:`~gimbal_friction.chamber.replay.replay_arrays`: the estimator's
    rules, the residual rows the logger would log), the rows learned test-then-train in time order with the node's
    guard (:func:`~gimbal_friction.refit.logs.learn_rows`), then settled. Also what it read: ``rows``,
    ``measurements`` and ``refused`` (per reason). The model is ``axis`` as ``joint`` (the configuration under
    test)."""
    axes = {joint: axis}
    ff_settings = feedforward or FeedforwardSettings()
    ff = Feedforward(axes, ff_settings)
    c = Correction(settings, model_identity(axes))
    refused: dict[str, dict[str, int]] = {}
    n_rows = n_meas = 0
    for arrays in streams:
        _, _, measured, _, _, rows = replay_arrays(arrays, axes, ff_settings, estimator)
        n_meas += len(measured)
        n_rows += learn_rows(c, ff, rows, refused)
    c.settle()
    return c, {'rows': n_rows, 'measurements': n_meas, 'refused': refused.get(joint, {}),
               'plateaus': len(streams), 'samples': int(np.sum([c.stats(joint).samples()]))}
