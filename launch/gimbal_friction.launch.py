"""Start the gimbal_friction suite with the packaged parameter file (needs a full ROS 2 install: launch_ros).

    ros2 launch gimbal_friction gimbal_friction.launch.py [params_file:=/path/extra.yaml] [log_dir:=/tmp/res]
        [sim:=true] [sim_params_file:=/path/gimbal_sim.yaml] [autostart:=false]

Every node gets the packaged parameter file once, then ``params_file`` if given. The residual log folder
(default ``$ROS_HOME/gimbal_friction/residuals``, ROS_HOME defaulting to ``~/.ros``) is made absolute and printed.

``sim:=true`` also starts ``gimbal_sim``, a simulated gimbal axis in closed loop that publishes the suite's input
topics and adds its feedforward (config/gimbal_sim.yaml; no hardware needed).

``autostart`` (default true) is passed to the managed (lifecycle) nodes ``friction_feedforward``,
``friction_estimator`` and ``residual_logger``: true, they configure and activate themselves; false, they come up
unconfigured and wait for a lifecycle manager (``ros2 lifecycle set /friction_feedforward configure``, nav2's
``lifecycle_manager``). ``gimbal_sim`` is a plain node and does not take it.

Without a ROS install (PyPI wheels only: no ``launch``, no ``ros2 run``) start the three executables the same way
(each on PATH after ``pip install``, or in ``install/gimbal_friction/lib/gimbal_friction/`` after ``colcon build``):

    friction_feedforward --ros-args --params-file config/gimbal_friction.yaml
    friction_estimator   --ros-args --params-file config/gimbal_friction.yaml
    residual_logger      --ros-args --params-file config/gimbal_friction.yaml -p output_dir:=residuals

or run ``python -m gimbal_friction.demo``, which starts them as processes, plays a chamber-test bag into them with
``chamber_replay`` and stops them cleanly.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

if TYPE_CHECKING:  # only for the annotations (launch exports them; the tests run against stand-ins)
    from launch import Action, LaunchContext

EXECUTABLES = ('friction_feedforward', 'friction_estimator', 'residual_logger')


def default_log_dir() -> str:
    """``$ROS_HOME/gimbal_friction/residuals`` (ROS_HOME defaults to ``~/.ros``): the same folder wherever
    ``ros2 launch`` is started."""
    ros_home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return os.path.join(ros_home, 'gimbal_friction', 'residuals')


def parameter_files(default_params: str, extra: str) -> list[str]:
    """The parameter files every node gets: the packaged file once, then ``extra`` if it is another file."""
    files = [default_params]
    if extra and os.path.realpath(os.path.expanduser(extra)) != os.path.realpath(default_params):
        files.append(os.path.expanduser(extra))
    return files


def absolute_log_dir(log_dir: str) -> str:
    """``log_dir`` as an absolute path (a relative one is taken from the folder ``ros2 launch`` was started in)."""
    return os.path.abspath(os.path.expanduser(log_dir or default_log_dir()))


def flag(text: str, name: str) -> bool:
    """A launch argument that is true or false (``true``/``false``, ``1``/``0``, ``yes``/``no``)."""
    value = text.strip().lower()
    if value not in ('true', 'false', '1', '0', 'yes', 'no'):
        msg = f'gimbal_friction.launch.py: {name}:={text!r} must be true or false'
        raise ValueError(msg)
    return value in ('true', '1', 'yes')


def launch_nodes(context: LaunchContext, share: str) -> list[Action]:
    """The nodes, with the launch arguments resolved (OpaqueFunction): parameter files, the absolute log
    folder (printed) and ``autostart`` for the managed nodes."""
    default_params = os.path.join(share, 'config', 'gimbal_friction.yaml')
    config = context.launch_configurations
    files = parameter_files(default_params, config.get('params_file', ''))
    log_dir = absolute_log_dir(config.get('log_dir', ''))
    autostart = flag(config.get('autostart', 'true'), 'autostart')
    actions = [LogInfo(msg=f'gimbal_friction: parameter files: {", ".join(files)}; residual log folder: {log_dir}'
                       + ('' if autostart else '; managed nodes unconfigured until a lifecycle manager configures '
                          'them (autostart:=false)'))]
    for exe in EXECUTABLES:   # every one a managed (lifecycle) node
        parameters: list[str | dict[str, object]] = list(files)
        if exe == 'residual_logger':
            parameters.append({'output_dir': log_dir})
        parameters.append({'autostart': autostart})
        actions.append(Node(package='gimbal_friction', executable=exe, name=exe, output='screen',
                            parameters=parameters, emulate_tty=True))
    actions.append(Node(package='gimbal_friction', executable='gimbal_sim', name='gimbal_sim', output='screen',
                        parameters=[*files, os.path.expanduser(config.get('sim_params_file', ''))],
                        emulate_tty=True, condition=IfCondition(LaunchConfiguration('sim'))))
    return actions


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory('gimbal_friction')
    default_sim_params = os.path.join(share, 'config', 'gimbal_sim.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value='',
                              description='extra parameter file layered over the packaged defaults (which every '
                              'node gets once)'),
        DeclareLaunchArgument('log_dir', default_value=default_log_dir(),
                              description='folder of the residual log written by residual_logger (a relative '
                              'path is resolved against the current folder; the absolute path is printed)'),
        DeclareLaunchArgument('sim', default_value='false',
                              description='also start gimbal_sim (a simulated gimbal axis in closed loop)'),
        DeclareLaunchArgument('sim_params_file', default_value=default_sim_params,
                              description='parameter file of gimbal_sim (its gimbal_sim section)'),
        DeclareLaunchArgument('autostart', default_value='true',
                              description='the managed nodes configure and activate themselves (false: they wait, '
                              'unconfigured, for a lifecycle manager)'),
        OpaqueFunction(function=launch_nodes, args=[share]),
    ])
