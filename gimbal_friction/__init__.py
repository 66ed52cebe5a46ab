"""gimbal_friction: gimbal-bearing friction torque versus temperature (Yu & Shang 2017) for ROS 2.

The physics lives in :mod:`gimbal_friction.core` (pure Python, never imports rclpy); the ROS 2 nodes in
:mod:`gimbal_friction.nodes` and the ``gimbal-friction`` command line in :mod:`gimbal_friction.tools` are thin
adapters around it.
"""

from __future__ import annotations

__version__ = '0.1.0'
