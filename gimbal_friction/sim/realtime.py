"""One simulated run stepped at wall-clock pace with an external feedforward: the logic of the ``gimbal_sim`` node.

Pure (no rclpy, no I/O): the node (:mod:`gimbal_friction.nodes.gimbal_sim`) converts messages and paces the
steps; everything else is here, so it is tested without ROS and the offline study runs the very same
:class:`~gimbal_friction.sim.engine.ClosedLoop`.

:class:`RealtimeRun` wraps a closed loop of one run (case ``feedforward`` when the feedforward is used, else
``none``). At each controller tick :meth:`RealtimeRun.step` applies the latest feedforward torque received (what
the seeker controller does with the ``/gimbal/friction/feedforward`` effort of its joint: it adds it to its
output), advances the loop and returns what the node publishes (:class:`TickOutput`). Stamps are the run's
epoch plus the simulated time, so the suite's nodes see the controller's sample times. A feedforward message
carries the stamp of the joint state that produced it (docs/ros.md), so :meth:`RealtimeRun.on_feedforward` knows
its tick and measures

- the **transport latency**: wall time it arrived − wall time that joint state was published [s];
- the **age** of the torque applied at each tick: ticks since the joint state that produced it (1 = the
  previous tick's, the best a separate process can do); a torque older than ``feedforward_timeout_s`` is not
  applied (0 N·m, age −1), as the offline loop does with a latency beyond the timeout.

>>> from gimbal_friction.physics.params import AxisParams
>>> cfg = SimConfig(tracking_duration_s=0.01)
>>> run = RealtimeRun(cfg, AxisParams(), RealtimeSettings(profile='tracking', environment_temperature_c=-40.0),
...                   epoch_ns=10**9)
>>> out = run.step(wall_s=0.0)
>>> out.tick, out.stamp_ns, round(out.temperature_c)   # the sensor's first sample (0.1 degC noise)
(0, 1000000000, -40)
>>> run.on_feedforward(0.003, out.stamp_ns, wall_s=0.0004)
True
>>> _ = run.step(wall_s=0.001)
>>> run.feedforward_age[:2].tolist(), [round(x, 6) for x in run.transport_latency_s]
([-1, 1], [0.0004])
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.physics.params import AxisParams
from gimbal_friction.sim.compensation import CASE_NONE, Compensator, ControllerInputs
from gimbal_friction.sim.config import RealtimeSettings, SimConfig
from gimbal_friction.sim.engine import BatchResult, ClosedLoop, Run
from gimbal_friction.sim.profiles import make_profile

Array = NDArray[np.float64]

__all__ = ['CASE_FEEDFORWARD', 'RealtimeRun', 'RealtimeSettings', 'TickOutput', 'percentile']

#: Case name of a run that adds the received feedforward.
CASE_FEEDFORWARD = 'feedforward'


class TickOutput(NamedTuple):
    """What the node publishes for one controller tick (SI)."""

    tick: int
    stamp_ns: int                 #: stamp of every message of this tick [ns]
    joint_position_rad: float     #: resolver angle relative to the base [rad]
    joint_velocity_rad_s: float   #: resolver (RDC) rate relative to the base [rad/s]
    current_a: float              #: motor current as the sensor reads it [A]
    reference_velocity_rad_s: float  #: reference joint velocity [rad/s]
    temperature_c: float | None   #: bearing temperature sample of this tick [°C] (None: no sample this tick)
    position_error_rad: float     #: LOS angle − target angle [rad]
    rate_error_rad_s: float       #: LOS rate − target rate [rad/s]
    friction_nm: float            #: truth friction torque [N·m]
    feedforward_nm: float         #: feedforward torque applied at this tick [N·m]


def percentile(values: ArrayLike, q: float) -> float:
    """The ``q``-th percentile of ``values`` (NaN when empty)."""
    x = np.asarray(values, dtype=float)
    return float(np.percentile(x, q)) if x.size else math.nan


class RealtimeRun:
    """One run of the closed loop, stepped tick by tick, with the feedforward coming from outside.

    Parameters
    ----------
    config : SimConfig
        Simulator configuration.
    axis : AxisParams
        The configured model of the simulated axis.
    settings : RealtimeSettings
        Profile, environment temperature, duration, whether the feedforward is used, seed.
    epoch_ns : int
        Stamp of tick 0 [ns] (the node: the wall clock when the run starts).

    Raises:
        ConfigError: invalid settings.
    """

    def __init__(self, config: SimConfig, axis: AxisParams, settings: RealtimeSettings, epoch_ns: int) -> None:
        settings.validate()
        self.config, self.axis, self.settings = config, axis, settings
        self.case = CASE_FEEDFORWARD if settings.use_feedforward else CASE_NONE
        duration = settings.duration_s if settings.duration_s > 0.0 else None
        self.profile = make_profile(config, settings.profile, duration)
        self.period_ns = int(round(config.controller_period_s * NS_PER_S))
        self.epoch_ns = int(epoch_ns)
        comps = {CASE_FEEDFORWARD: Compensator(self._hook, delayed=False)} if settings.use_feedforward else {}
        self.loop = ClosedLoop(config, axis, self.profile,
                               [Run(self.case, settings.environment_temperature_c, settings.run_seed)], comps)
        n = self.loop.ticks
        self._ff_nm = 0.0
        self._ff_tick = -1
        #: per tick, ticks since the joint state of the latest feedforward received (-1: none yet); it is applied
        #: when 0 <= age <= config.timeout_ticks
        self.feedforward_age = np.full(n, -1, dtype=np.int64)
        self.publish_wall_s = np.full(n, math.nan)          #: wall time each tick's messages were published [s]
        self.transport_latency_s: list[float] = []         #: per feedforward received [s]
        self.received = 0        #: feedforward messages received for this run
        self.stale = 0           #: received for a tick older than the one applied (ignored)
        self.foreign = 0         #: stamps that are no tick of this run (ignored)
        self.timed_out = 0       #: ticks whose latest feedforward was older than feedforward_timeout_s (0 N·m)

    # ------------------------------------------------------------------ stepping
    @property
    def ticks(self) -> int:
        """Ticks of the run [-]."""
        return int(self.loop.ticks)

    @property
    def done(self) -> bool:
        """Every tick simulated."""
        return self.loop.done

    def due_wall_s(self, start_wall_s: float, tick: int) -> float:
        """Wall time [s] at which ``tick`` is due for a run started at ``start_wall_s``."""
        return start_wall_s + tick * self.config.controller_period_s / self.settings.realtime_factor

    def stamp_ns(self, tick: int) -> int:
        """Stamp of ``tick`` [ns]: the epoch plus the simulated time."""
        return int(self.epoch_ns + tick * self.period_ns)

    def _hook(self, inputs: ControllerInputs) -> Array:
        k = self.loop.k
        age = k - self._ff_tick if self._ff_tick >= 0 else -1
        fresh = self.config.feedforward_fresh(age)
        self.feedforward_age[k] = age
        if age >= 0 and not fresh:
            self.timed_out += 1
        return np.full(inputs.temperature_c.shape, self._ff_nm if fresh else 0.0)

    def step(self, wall_s: float) -> TickOutput:
        """Simulate the next tick with the latest feedforward received; ``wall_s`` [s] is when its messages go out.

        Raises:
            ConfigError: the run is over.
        """
        k = self.loop.k
        self.loop.step()
        self.publish_wall_s[k] = wall_s
        tr = self.loop.last()
        prof = self.profile
        sample = float(tr.temperature_c[0]) if self.loop.sampled[k] else None
        return TickOutput(k, self.stamp_ns(k), float(tr.joint_position_rad[0]), float(tr.joint_velocity_rad_s[0]),
                          float(tr.current_measured_a[0]), float(tr.reference_velocity_rad_s[0]), sample,
                          float(tr.los_angle_rad[0] - prof.target_angle_rad[k]),
                          float(tr.los_rate_rad_s[0] - prof.target_rate_rad_s[k]), float(tr.friction_nm[0]),
                          float(tr.feedforward_nm[0]))

    # ------------------------------------------------------------------ the feedforward
    def on_feedforward(self, torque_nm: float, stamp_ns: int, wall_s: float) -> bool:
        """A feedforward torque [N·m] for the joint state of ``stamp_ns`` [ns], arrived at ``wall_s`` [s]. Returns
        whether it is used from the next tick on (a non-finite torque, a stamp of no tick of this run or an
        older tick than the torque in use is ignored)."""
        offset = stamp_ns - self.epoch_ns
        tick, rest = divmod(offset, self.period_ns)
        if offset < 0 or rest != 0 or tick >= self.loop.k or not math.isfinite(torque_nm):
            self.foreign += 1
            return False
        self.received += 1
        self.transport_latency_s.append(wall_s - float(self.publish_wall_s[tick]))
        if tick <= self._ff_tick:
            self.stale += 1
            return False
        self._ff_nm, self._ff_tick = float(torque_nm), int(tick)
        return True

    # ------------------------------------------------------------------ results
    def result(self) -> BatchResult:
        """The run so far as a batch of one (traces of the ticks simulated)."""
        return self.loop.result()

    def latency_summary(self) -> dict[str, float]:
        """Transport latency p50/p95/max [s] and the age of the latest feedforward at the ticks p50/p95 [ticks]
        (NaN before any feedforward)."""
        ages = self.feedforward_age[: self.loop.k]
        ages = ages[ages >= 0]
        lat = self.transport_latency_s
        return {'feedforward_latency_p50_s': percentile(lat, 50.0),
                'feedforward_latency_p95_s': percentile(lat, 95.0),
                'feedforward_latency_max_s': float(max(lat)) if lat else math.nan,
                'feedforward_age_p50_ticks': percentile(ages, 50.0),
                'feedforward_age_p95_ticks': percentile(ages, 95.0),
                'feedforward_received': float(self.received),
                'feedforward_timed_out_ticks': float(self.timed_out)}
