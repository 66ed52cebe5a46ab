"""The start of a learning worker process: its priority lowered before it imports anything heavy (no rclpy, no I/O).

One job in one module: :func:`run_fit_worker`, the target of the child process that
:class:`~gimbal_friction.feedforward.correction.worker.BackgroundLearner` starts. Importing the correction's modules
(numpy, scipy) takes about a second of CPU; at the node's priority it would take it from the node's share, so this
module imports nothing but the standard library until :func:`lower_priority` has run.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any

__all__ = ['lower_priority', 'run_fit_worker']


def lower_priority(nice: int) -> None:
    """This process at ``nice`` [-] below its parent, where the OS allows: its own session (under Linux's autogroup
    scheduling a nice value counts only within a session, so a worker in the node's would take from the node's share
    of the CPU) with that session's nice raised, its own nice raised, and the batch policy (never preempting the node
    on a wake-up)."""
    with contextlib.suppress(OSError):
        os.setsid()
    with contextlib.suppress(OSError), open('/proc/self/autogroup', 'w', encoding='ascii') as f:
        f.write(str(nice))
    with contextlib.suppress(OSError):
        os.nice(nice)
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))


def run_fit_worker(conn: Any, nice: int) -> None:
    """The child process: lower its priority, then serve jobs on ``conn``
    (:func:`~gimbal_friction.feedforward.correction.worker.serve`)."""
    lower_priority(nice)
    from gimbal_friction.feedforward.correction.worker import serve
    serve(conn)
