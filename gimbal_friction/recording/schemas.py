"""The message definitions and RIHS01 type hashes of the standard messages the residual log writes, as
``rosbags`` generates them from the type store of :data:`~gimbal_friction.recording.cdr.DEFAULT_STORE`
(``generate_msgdef(msgtype, ros_version=2)``, ``hash_rihs01(msgtype)``).

Kept as text so that writing a log needs no type store: building one takes about 0.1 s, most of a replay of a
small bag. ``test/recording/test_schemas.py`` checks every entry against the type store; a type not listed
here is taken from the type store by the writer.
"""

from __future__ import annotations

__all__ = ['SCHEMAS']

#: msgtype -> (message definition, RIHS01 hash)
SCHEMAS: dict[str, tuple[str, str]] = {
    'sensor_msgs/msg/JointState': ((
        'std_msgs/Header header\n'
        'string[] name\n'
        'float64[] position\n'
        'float64[] velocity\n'
        'float64[] effort\n'
        '================================================================================\n'
        'MSG: std_msgs/Header\n'
        'builtin_interfaces/Time stamp\n'
        'string frame_id\n'
        '================================================================================\n'
        'MSG: builtin_interfaces/Time\n'
        'int32 sec\n'
        'uint32 nanosec\n'
    ), 'RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e'),
    'sensor_msgs/msg/Temperature': ((
        'std_msgs/Header header\n'
        'float64 temperature\n'
        'float64 variance\n'
        '================================================================================\n'
        'MSG: std_msgs/Header\n'
        'builtin_interfaces/Time stamp\n'
        'string frame_id\n'
        '================================================================================\n'
        'MSG: builtin_interfaces/Time\n'
        'int32 sec\n'
        'uint32 nanosec\n'
    ), 'RIHS01_72514a14126ab9f8a9abec974c78e5610a367b59db5da355ff1fb982d5bad4b8'),
    'std_msgs/msg/Float64MultiArray': ((
        'std_msgs/MultiArrayLayout layout\n'
        'float64[] data\n'
        '================================================================================\n'
        'MSG: std_msgs/MultiArrayLayout\n'
        'std_msgs/MultiArrayDimension[] dim\n'
        'uint32 data_offset\n'
        '================================================================================\n'
        'MSG: std_msgs/MultiArrayDimension\n'
        'string label\n'
        'uint32 size\n'
        'uint32 stride\n'
    ), 'RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f'),
}
