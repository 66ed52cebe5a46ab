"""gimbal_friction: gimbal-bearing friction torque versus temperature (Yu & Shang 2017) for ROS 2.

Folders, bottom to top (each imports only folders below it; ``test/test_layers.py`` checks it): ``common``,
``physics`` (the paper's equations), ``streams``, ``feedforward`` and ``estimation``, ``recording``, ``refit``,
``export`` and ``plots``, ``sim``, ``config``, ``chamber``, ``runs``, then the thin ``nodes`` (ROS 2) and ``cli``
(``gimbal-friction``). Public facades at this level: :mod:`gimbal_friction.controller` (the feedforward in your own
process), :mod:`gimbal_friction.demo` (the main job: ``python -m gimbal_friction.demo``) and
:mod:`gimbal_friction.core` (the model without ROS).
"""

from __future__ import annotations

__version__ = '0.1.0'
