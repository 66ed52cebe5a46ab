"""Closed-loop simulation of a gimbal axis with the suite's friction compensation (pure: numpy, scipy, lower layers).

Never imports rclpy and does no file I/O: the ``gimbal_sim`` node (:mod:`gimbal_friction.nodes.gimbal_sim`) and the
``loop-study`` CLI (:mod:`gimbal_friction.runs.loop_study`, :mod:`gimbal_friction.runs.loop_live`) are thin
adapters around it.

- :mod:`~gimbal_friction.sim.config`: :class:`SimConfig`, every simulator parameter with its unit;
- :mod:`~gimbal_friction.sim.lugre`: the LuGre model (Canudas de Wit et al. 1995);
- :mod:`~gimbal_friction.sim.truth`: the truth friction, the simulator's own whatever the configuration under test
  says (the paper's bearing with its own lubricant and motor + LuGre + ripple + asymmetry);
- :mod:`~gimbal_friction.sim.profiles`: tracking / scan / pointing references and base motion;
- :mod:`~gimbal_friction.sim.compensation`: the compensation hook and the cases;
- :mod:`~gimbal_friction.sim.engine`: the vectorised closed-loop simulation;
- :mod:`~gimbal_friction.sim.metrics`, :mod:`~gimbal_friction.sim.study`: LOS error metrics and the study;
- :mod:`~gimbal_friction.sim.realtime`: one run stepped at wall-clock pace with an external feedforward (the node).
"""

from __future__ import annotations

from gimbal_friction.sim.compensation import CASES, Compensator, ControllerInputs, constant_coulomb, suite_feedforward
from gimbal_friction.sim.config import PROFILES, RealtimeSettings, SimConfig
from gimbal_friction.sim.engine import BatchResult, ClosedLoop, EstimatorTrace, Run, Traces, simulate
from gimbal_friction.sim.metrics import RunMetrics, batch_metrics
from gimbal_friction.sim.profiles import Profile, make_profile
from gimbal_friction.sim.realtime import RealtimeRun
from gimbal_friction.sim.study import (
    DEFAULT_TEMPERATURES,
    FeedforwardSetup,
    RefitOutcome,
    StudyResult,
    estimator_rows,
    goal_checks,
    refit_rows,
    run_study,
)
from gimbal_friction.sim.truth import TruthFriction

__all__ = ['CASES', 'DEFAULT_TEMPERATURES', 'PROFILES', 'BatchResult', 'ClosedLoop', 'Compensator', 'ControllerInputs',
           'EstimatorTrace', 'FeedforwardSetup', 'Profile', 'RealtimeRun', 'RealtimeSettings', 'RefitOutcome', 'Run',
           'RunMetrics', 'SimConfig',
           'StudyResult', 'Traces', 'TruthFriction', 'batch_metrics', 'constant_coulomb', 'estimator_rows',
           'goal_checks', 'make_profile', 'refit_rows', 'run_study', 'simulate', 'suite_feedforward']
