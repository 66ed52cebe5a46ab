"""Start the gimbal_friction suite with the packaged parameter file (needs a full ROS 2 install: launch_ros).

    ros2 launch gimbal_friction gimbal_friction.launch.py [params_file:=/path/extra.yaml] [log_dir:=/tmp/res]
        [sim:=true] [sim_params_file:=/path/gimbal_sim.yaml]

``sim:=true`` also starts ``gimbal_sim``, a simulated gimbal axis in closed loop that publishes the suite's input
topics and adds its feedforward (config/gimbal_sim.yaml; no hardware needed).

Without a ROS install (PyPI wheels only: no ``launch``, no ``ros2 run``) start the three executables the same way
(each on PATH after ``pip install``, or in ``install/gimbal_friction/lib/gimbal_friction/`` after ``colcon build``):

    friction_feedforward --ros-args --params-file config/gimbal_friction.yaml
    friction_estimator   --ros-args --params-file config/gimbal_friction.yaml
    residual_logger      --ros-args --params-file config/gimbal_friction.yaml -p output_dir:=residuals

or run ``python -m gimbal_friction.demo``, which starts them as processes, plays a chamber-test bag into them with
``chamber_replay`` and stops them cleanly.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

EXECUTABLES = ('friction_feedforward', 'friction_estimator', 'residual_logger')


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory('gimbal_friction')
    default_params = os.path.join(share, 'config', 'gimbal_friction.yaml')
    default_sim_params = os.path.join(share, 'config', 'gimbal_sim.yaml')
    params_file = LaunchConfiguration('params_file')
    log_dir = LaunchConfiguration('log_dir')
    nodes = []
    for exe in EXECUTABLES:
        parameters = [default_params, params_file]
        if exe == 'residual_logger':
            parameters.append({'output_dir': log_dir})
        nodes.append(Node(package='gimbal_friction', executable=exe, name=exe, output='screen',
                          parameters=parameters, emulate_tty=True))
    nodes.append(Node(package='gimbal_friction', executable='gimbal_sim', name='gimbal_sim', output='screen',
                      parameters=[default_params, params_file, LaunchConfiguration('sim_params_file')],
                      emulate_tty=True, condition=IfCondition(LaunchConfiguration('sim'))))
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='extra parameter file layered over the packaged defaults'),
        DeclareLaunchArgument('log_dir', default_value='residuals',
                              description='folder of the residual log written by residual_logger'),
        DeclareLaunchArgument('sim', default_value='false',
                              description='also start gimbal_sim (a simulated gimbal axis in closed loop)'),
        DeclareLaunchArgument('sim_params_file', default_value=default_sim_params,
                              description='parameter file of gimbal_sim (its gimbal_sim section)'),
        *nodes,
    ])
