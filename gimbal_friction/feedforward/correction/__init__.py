"""The learned correction: residue of the physics model learned in service, guarded, applied by the feedforward.

One folder, imported bottom-up (no module imports one above it in this list):

- :mod:`.settings` — the settings (``correction_*``, ``learning_*`` parameters), the model identity, the error type;
- :mod:`.stats` — the gate of a residual sample and the rows it is kept in;
- :mod:`.periods` — ripple periods found in the residuals (a weighted periodogram over the joint angle);
- :mod:`.fit` — the terms fitted from the rows (speed profile, ripple, trend, direction-independent torque);
- :mod:`.lookup` — the applied terms as the feedforward reads them (odd and even parts, floats and arrays);
- :mod:`.core` — :class:`Correction`: rows, candidate, the guard (test, then train), applied terms, reports;
- :mod:`.judge` — :class:`~.judge.LoopJudge`: the loop's error judges each cell in randomised on/off blocks;
- :mod:`.learner` — :class:`Learner`: in-service learning at a limited rate;
- :mod:`.file` — the YAML file, read as untrusted input;
- :mod:`.keeper` — :class:`CorrectionKeeper`: loaded, learned, saved in the background (what the node runs).

May import common, physics and streams; never recording, nodes or cli.
"""

from gimbal_friction.feedforward.correction.core import GUARD_TERMS, Correction, Verdict
from gimbal_friction.feedforward.correction.file import Loaded, load, load_file, save
from gimbal_friction.feedforward.correction.keeper import CorrectionKeeper
from gimbal_friction.feedforward.correction.learner import R_FROZEN, R_UNKNOWN, Learner
from gimbal_friction.feedforward.correction.settings import (
    DIRECTIONS,
    LAYOUT,
    RETIRED,
    CorrectionError,
    CorrectionSettings,
    JudgeSettings,
    LearningSettings,
    ModelIdentity,
    model_identity,
)
from gimbal_friction.feedforward.correction.stats import REASONS, gate_code

__all__ = ['DIRECTIONS', 'GUARD_TERMS', 'LAYOUT', 'REASONS', 'RETIRED', 'R_FROZEN', 'R_UNKNOWN', 'Correction',
           'CorrectionError', 'CorrectionKeeper', 'CorrectionSettings', 'JudgeSettings', 'Learner', 'LearningSettings',
           'Loaded', 'ModelIdentity', 'Verdict', 'gate_code', 'load', 'load_file', 'model_identity', 'save']
