"""The learned correction of residual logs against the model of a layered configuration (``refit`` and ``fleet``).

The model is the one the feedforward will run: the parameter files in order, the refitted file last; the
correction's layout and shrinkage come from the ``correction_*`` parameters of ``friction_feedforward`` (defaults
for those not given), so the node accepts the file. The rows are streamed by
:func:`~gimbal_friction.refit.logs.read_correction`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from gimbal_friction.common.settings import settings_from, settings_from_parameters
from gimbal_friction.config.loader import all_axis_params, load_parameters
from gimbal_friction.feedforward.correction import CorrectionSettings
from gimbal_friction.feedforward.rule import FeedforwardSettings
from gimbal_friction.refit.logs import LearnedCorrection, correction_table, read_correction

__all__ = ['correction_record', 'correction_settings', 'learn_correction']


def correction_settings(params: Mapping[str, Any]) -> CorrectionSettings:
    """The layout of a learned correction from the ``correction_<field>`` parameters of ``friction_feedforward``
    (merged ``ros__parameters``; defaults for those not given), validated (ConfigError naming the parameter)."""
    return settings_from(CorrectionSettings, {k[len('correction_'):]: v for k, v in params.items()
                                              if k.startswith('correction_')})


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
