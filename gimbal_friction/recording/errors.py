"""The one error type of the recording area (bags in, residual logs out)."""

from __future__ import annotations

from gimbal_friction.core.errors import GimbalFrictionError


class RecordingError(GimbalFrictionError):
    """A bag or residual log cannot be opened, read or written.

    The message names the path and, where one is at fault, the topic, so a tool can print it as its one-line
    reason. Lower errors (``OSError``, rosbags and mcap errors) are wrapped with that context.
    """
