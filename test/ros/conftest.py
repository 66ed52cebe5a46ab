"""test/ros: the live-node harness (``ros_env``, ``spawn``, ``probe``) is in test/conftest.py, shared with
test/robustness. The node tests need the ros-* wheels."""

from __future__ import annotations

import pytest

pytest.importorskip('rclpy', reason='node tests need the ros-* wheels (requirements.txt)')
