"""Start the gimbal_friction suite with the packaged parameter file (needs a full ROS 2 install: launch_ros).

    ros2 launch gimbal_friction gimbal_friction.launch.py [params_file:=/path/extra.yaml] [log_dir:=/tmp/res]

Without a ROS install (PyPI wheels only) use the plain supervisor instead: ``python -m gimbal_friction.suite``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

EXECUTABLES = ('friction_feedforward', 'friction_estimator', 'residual_logger')


def generate_launch_description():
    share = get_package_share_directory('gimbal_friction')
    default_params = os.path.join(share, 'config', 'gimbal_friction.yaml')
    params_file = LaunchConfiguration('params_file')
    log_dir = LaunchConfiguration('log_dir')
    nodes = []
    for exe in EXECUTABLES:
        parameters = [default_params, params_file]
        if exe == 'residual_logger':
            parameters.append({'output_dir': log_dir})
        nodes.append(Node(package='gimbal_friction', executable=exe, name=exe, output='screen',
                          parameters=parameters, emulate_tty=True))
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='extra parameter file layered over the packaged defaults'),
        DeclareLaunchArgument('log_dir', default_value='residuals',
                              description='folder of the residual log written by residual_logger'),
        *nodes,
    ])
