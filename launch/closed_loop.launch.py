"""The closed loop: ``gimbal_sim`` and the suite's three nodes, wired and parameterised as ``loop-study --live``.

    ros2 launch gimbal_friction closed_loop.launch.py [params_file:=/path/extra.yaml] [axis:=elevation]
        [work_dir:=/tmp/loop] [temperature_c:=-40.0] [profile:=tracking] [duration_s:=30.0]
        [use_feedforward:=true] [realtime_factor:=1.0] [publish_every_ticks:=2] [exit_when_done:=true]
        [autostart:=true]

The wiring is :mod:`gimbal_friction.runs.loop_wiring`'s, the one ``gimbal-friction loop-study --live`` starts
its processes with: ``friction_feedforward``, ``friction_estimator`` (method ``observer``) and
``residual_logger`` (into ``<work_dir>/residuals``), then ``gimbal_sim`` for one run of ``profile`` at the plateau
``temperature_c`` [degC] for ``duration_s`` [s] (default the profile's configured duration), with the
feedforward added to its motor command (``use_feedforward``), recorded to ``<work_dir>/run_feedforward.npz``
(``run_none.npz`` without the feedforward: ``gimbal_friction.runs.loop_live.load_run`` reads it). Every node
gets the same parameter files, written into ``<work_dir>/params`` when the launch starts: the packaged defaults,
the axis studied (``axis``, default the first configured; its model only), and the study's own (estimator and
feedforward settings, the simulator's ``gimbal_sim`` section), all built from the packaged defaults with
``params_file`` layered over them (like ``loop-study --config``). With ``exit_when_done`` (the default) the
launch shuts down once the run is done. ``work_dir`` defaults to ``$ROS_HOME/gimbal_friction/closed_loop``
(ROS_HOME defaulting to ``~/.ros``); a relative one is taken from the folder ``ros2 launch`` runs in.
``autostart`` (default true) is passed to the three managed (lifecycle) nodes: false, they come up unconfigured
and the loop starts once a lifecycle manager has configured and activated them (``gimbal_sim`` waits for their
subscriptions and the feedforward's publisher).

Without a ROS install (PyPI wheels: no ``launch``) the same loop runs with ``gimbal-friction loop-study --live``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from launch.actions import DeclareLaunchArgument, EmitEvent, LogInfo, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch_ros.actions import Node

from launch import LaunchDescription

if TYPE_CHECKING:  # only for the annotations (launch exports them; the tests run against stand-ins)
    from launch import Action, LaunchContext

#: the launch arguments and their defaults (those of ``loop-study --live``; '' = the configured value)
ARGUMENTS = {
    'params_file': ('', ('parameter file layered over the packaged defaults (model, axes, nodes, gimbal_sim '
                         'section), like loop-study --config')),
    'axis': ('', 'configured axis the loop simulates (default the first)'),
    'work_dir': ('', ('folder of the parameter files, the residual log and the run record (default '
                      '$ROS_HOME/gimbal_friction/closed_loop)')),
    'temperature_c': ('-40.0', 'temperature plateau of the run [degC]'),
    'profile': ('tracking', 'profile of the run: tracking, scan, pointing or weave'),
    'duration_s': ('', "duration of the run [s] (default the profile's configured duration)"),
    'use_feedforward': ('true', "add friction_feedforward's torque to gimbal_sim's motor command"),
    'realtime_factor': ('1.0', 'simulated seconds per wall second [-]'),
    'publish_every_ticks': ('2', 'gimbal_sim publishes its topics every N controller ticks (2: 500 Hz)'),
    'exit_when_done': ('true', 'end gimbal_sim after the run, and with it the launch'),
    'autostart': ('true', ('the managed nodes (friction_feedforward, friction_estimator, residual_logger) '
                           'configure and activate themselves; false: they wait for a lifecycle manager')),
}


def default_work_dir() -> str:
    """``$ROS_HOME/gimbal_friction/closed_loop`` (ROS_HOME defaults to ``~/.ros``)."""
    ros_home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return os.path.join(ros_home, 'gimbal_friction', 'closed_loop')


def _flag(text: str, name: str) -> bool:
    value = text.strip().lower()
    if value not in ('true', 'false', '1', '0', 'yes', 'no'):
        msg = f'closed_loop.launch.py: {name}:={text!r} must be true or false'
        raise ValueError(msg)
    return value in ('true', '1', 'yes')


def launch_loop(context: LaunchContext) -> list[Action]:
    """The loop's nodes with the launch arguments resolved (OpaqueFunction): the parameter files are written, the
    work folder printed; ``gimbal_sim`` ending shuts the launch down when ``exit_when_done``."""
    from pathlib import Path

    from gimbal_friction.config.loader import MANAGED_NODES
    from gimbal_friction.runs.loop_study import load_study_inputs
    from gimbal_friction.runs.loop_wiring import SimRun, closed_loop, write_parameter_files

    config = context.launch_configurations
    work = Path(os.path.abspath(os.path.expanduser(config.get('work_dir', '') or default_work_dir())))
    extra = config.get('params_file', '')
    inputs = load_study_inputs([os.path.expanduser(extra)] if extra else [], config.get('axis', '') or None)
    files = write_parameter_files(inputs, work / 'params')
    profile = config.get('profile', 'tracking')
    duration = config.get('duration_s', '')
    use = _flag(config.get('use_feedforward', 'true'), 'use_feedforward')
    done = _flag(config.get('exit_when_done', 'true'), 'exit_when_done')
    autostart = _flag(config.get('autostart', 'true'), 'autostart')
    run = SimRun(duration_s=float(duration) if duration else inputs.sim.profile_duration_s(profile),
                 use_feedforward=use, temperature_c=float(config.get('temperature_c', '-40.0')), profile=profile,
                 realtime_factor=float(config.get('realtime_factor', '1.0')),
                 publish_every_ticks=int(config.get('publish_every_ticks', '2')),
                 record_path=str(work / f'run_{"feedforward" if use else "none"}.npz'), exit_when_done=done)
    actions: list[Action] = [LogInfo(msg=f'gimbal_friction closed loop: axis {inputs.axis_name}, {profile} at '
                                     f'{run.temperature_c:+g} degC for {run.duration_s:g} s; parameter files, '
                                     f'residual log and run record in {work}')]
    nodes = [Node(package='gimbal_friction', executable=spec.executable, name=spec.name, output='screen',
                  parameters=[*spec.parameter_files, dict(spec.parameters),
                              *([{'autostart': autostart}] if spec.executable in MANAGED_NODES else [])],
                  remappings=list(spec.remappings), emulate_tty=True)
             for spec in closed_loop(files, work / 'residuals', run)]
    actions += nodes
    if done:
        actions.append(RegisterEventHandler(OnProcessExit(
            target_action=nodes[-1],
            on_exit=[LogInfo(msg='gimbal_friction closed loop: gimbal_sim finished; shutting down'),
                     EmitEvent(event=Shutdown(reason='gimbal_sim finished its run'))])))
    return actions


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in ARGUMENTS.items()),
        OpaqueFunction(function=launch_loop),
    ])
