"""ament_python package gimbal_friction (colcon build on a ROS 2 install, or pip install in a venv)."""

import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'gimbal_friction'
# the one version of the package: package.xml's (what ROS reads); `gimbal-friction --version` reports it from the
# installed metadata
version = re.search(r'<version>\s*([^<\s]+)\s*</version>',
                    (Path(__file__).resolve().parent / 'package.xml').read_text(encoding='utf-8')).group(1)

setup(
    name=package_name,
    version=version,
    packages=find_packages(include=['gimbal_friction', 'gimbal_friction.*']),
    package_data={package_name: ['data/*.yaml', 'data/*.json', 'py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.json')),
        ('share/' + package_name + '/config/truths', glob('config/truths/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    # The ROS 2 Python packages come from the ROS install (colcon) or from requirements.txt (pip wheels);
    # they are deliberately not install_requires so a sourced ROS never gets the PyPI wheels mixed in.
    install_requires=['setuptools'],
    extras_require={
        'ros': ['ros-rclpy[fastrtps]==9.1.2', 'ros-std-msgs==5.5.1', 'ros-sensor-msgs==5.5.1',
                'ros-diagnostic-msgs==5.5.1'],
        'core': ['numpy', 'scipy', 'PyYAML', 'matplotlib', 'mcap', 'mcap-ros2-support', 'rosbags'],
        # `gimbal-friction fleet` only (refused in one line without it); rosdep has no key for Dask
        'fleet': ['dask[distributed]'],
    },
    zip_safe=True,
    maintainer='gimbal_friction developers',
    maintainer_email='gimbal-friction@example.com',
    description='Gimbal-bearing friction torque vs temperature (Yu & Shang 2017) as ROS 2 nodes and tools',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'friction_feedforward = gimbal_friction.nodes.feedforward:main',
            'friction_estimator = gimbal_friction.nodes.estimator:main',
            'residual_logger = gimbal_friction.nodes.residual_logger:main',
            'chamber_replay = gimbal_friction.nodes.chamber_replay:main',
            'gimbal_sim = gimbal_friction.nodes.gimbal_sim:main',
            'gimbal-friction = gimbal_friction.cli.main:entry',
        ],
    },
)
