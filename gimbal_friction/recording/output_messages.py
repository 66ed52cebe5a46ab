"""The feedforward node's output messages as CDR bytes: templates made once per layout, the stamp and the torques
packed into them per message (no rclpy).

One job in one module: the output-message templates of ``friction_feedforward`` (``/gimbal/friction/feedforward``,
``sensor_msgs/JointState``; ``/gimbal/friction/feedforward_commands``, ``std_msgs/Float64MultiArray``), built from
the suite's one CDR encoder (:mod:`gimbal_friction.recording.cdr`).
"""

from __future__ import annotations

import struct
from typing import Protocol

from gimbal_friction.common.units import NS_PER_S
from gimbal_friction.recording.cdr import float64_multi_array_cdr, joint_state_cdr

_STAMP = struct.Struct('<iI')  #: builtin_interfaces/Time in CDR (int32 sec, uint32 nanosec), after the 4-byte header


class _Time(Protocol):
    sec: int
    nanosec: int


class Header(Protocol):
    """What :meth:`OutputBytes.feedforward` reads of a ``std_msgs/Header``."""

    stamp: _Time
    frame_id: str


class OutputBytes:
    """The serialized (CDR) outputs of one joint-state message, published as bytes.

    rclpy converts a message object field by field and serializes it on every publish (in the running node at
    1 kHz the commands' publish took 26 µs as a message object, 6 µs as bytes); the bytes of the suite's one CDR
    encoder (:func:`~gimbal_friction.recording.cdr.joint_state_cdr`,
    :func:`~gimbal_friction.recording.cdr.float64_multi_array_cdr`) are made once per layout (frame_id and joint
    names) and per message only the stamp and the torques are packed into them. Subscribers read the same messages
    as from the message objects (``test/ros/test_feedforward_node.py`` deserializes them; the bytes differ from
    rclpy's only in padding rclpy leaves unset and in its trailing padding).

    Parameters
    ----------
    n_joints : int
        Configured joints (the length of the commands).
    """

    MAX_LAYOUTS = 64  #: layouts kept (a stream with ever new frame_ids or names is packed without a template)

    def __init__(self, n_joints: int) -> None:
        commands = float64_multi_array_cdr([0.0] * n_joints, 'joints')
        self._commands_head = commands[:len(commands) - 8 * n_joints]
        self._commands = struct.Struct(f'<{n_joints}d')
        #: (frame_id, names) -> (bytes before the stamp, bytes between the stamp and the efforts, efforts' packer)
        self._layouts: dict[tuple[str, tuple[str, ...]], tuple[bytes, bytes, struct.Struct]] = {}

    def feedforward(self, header: Header, names: list[str], torques_nm: list[float]) -> bytes:
        """``sensor_msgs/JointState`` with ``header`` (std_msgs/Header: its stamp and frame_id), ``names`` and
        effort = ``torques_nm`` [N·m] (position and velocity empty)."""
        key = (header.frame_id, tuple(names))
        layout = self._layouts.get(key)
        if layout is None:
            layout = self._layout(*key)
        head, middle, efforts = layout
        stamp = header.stamp
        return head + _STAMP.pack(stamp.sec, stamp.nanosec) + middle + efforts.pack(*torques_nm)

    def commands(self, commands_nm: list[float]) -> bytes:
        """``std_msgs/Float64MultiArray`` of ``commands_nm`` [N·m], one dimension ``joints``."""
        return self._commands_head + self._commands.pack(*commands_nm)

    def _layout(self, frame_id: str, names: tuple[str, ...]) -> tuple[bytes, bytes, struct.Struct]:
        """The encoder's bytes of this layout split around the stamp and the efforts; checked: the bytes of another
        stamp and other efforts differ from them exactly there."""
        n = len(names)
        zero = joint_state_cdr(0, names, effort=[0.0] * n, frame_id=frame_id)
        head, middle, efforts = zero[:4], zero[4 + _STAMP.size:len(zero) - 8 * n], struct.Struct(f'<{n}d')
        probe = joint_state_cdr(NS_PER_S + 2, names, effort=[1.0] * n, frame_id=frame_id)
        if probe != head + _STAMP.pack(1, 2) + middle + efforts.pack(*[1.0] * n):
            raise RuntimeError('JointState CDR layout: stamp or efforts not where OutputBytes packs them')
        layout = (head, middle, efforts)
        if len(self._layouts) < self.MAX_LAYOUTS:
            self._layouts[(frame_id, names)] = layout
        return layout
