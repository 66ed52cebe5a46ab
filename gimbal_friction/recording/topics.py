"""Topic names and message types of the contract (docs/ros.md), shared by nodes, bags and logs."""

from __future__ import annotations

from collections.abc import Sequence

from gimbal_friction.common.errors import ConfigError
from gimbal_friction.streams.measurement import MEASUREMENT_FIELDS as _MEASUREMENT_FIELDS
from gimbal_friction.streams.residual_row import RESIDUAL_FIELDS as _RESIDUAL_FIELDS

TEMPERATURE = '/gimbal/temperature'
JOINT_STATES = '/joint_states'
MOTOR_CURRENT = '/gimbal/motor_current'
#: reference joint velocity (sensor_msgs/JointState, velocity [rad/s]): read by friction_feedforward and replay
REFERENCE_VELOCITY = '/gimbal/reference_velocity'
FEEDFORWARD = '/gimbal/friction/feedforward'
FEEDFORWARD_COMMANDS = '/gimbal/friction/feedforward_commands'
MEASURED = '/gimbal/friction/measured'
#: estimator: std_msgs/Float64MultiArray per accepted sample, fields MEASUREMENT_FIELDS, dim[0].label = joint
MEASURED_DETAIL = '/gimbal/friction/measured_detail'
#: estimator: running statistics (diagnostic_msgs/DiagnosticArray)
STATISTICS = '/gimbal/friction/statistics'
#: friction_feedforward: the learned correction (diagnostic_msgs/DiagnosticArray), one status per joint and per cell
CORRECTION = '/gimbal/friction/correction'
DIAGNOSTICS = '/diagnostics'
#: residual log only: one sensor_msgs/JointState per paired sample, effort = measured - predicted [N*m]
RESIDUAL = '/gimbal/friction/residual'
#: residual log only: std_msgs/Float64MultiArray per paired sample, fields RESIDUAL_FIELDS, dim[0].label = joint
RESIDUAL_DETAIL = '/gimbal/friction/residual_detail'

TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'
JOINT_STATE_TYPE = 'sensor_msgs/msg/JointState'
FLOAT64_MULTI_ARRAY_TYPE = 'std_msgs/msg/Float64MultiArray'
DIAGNOSTIC_ARRAY_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'

#: the topics every chamber-test bag must hold, with their types
CHAMBER_TOPICS = {
    TEMPERATURE: TEMPERATURE_TYPE,
    JOINT_STATES: JOINT_STATE_TYPE,
    MOTOR_CURRENT: JOINT_STATE_TYPE,
}

#: data[] layouts of RESIDUAL_DETAIL and MEASURED_DETAIL: defined once, in the core
RESIDUAL_FIELDS = _RESIDUAL_FIELDS
MEASUREMENT_FIELDS = _MEASUREMENT_FIELDS

#: the MCAP profile, schema encoding and message encoding of every file the suite writes (docs/ros.md)
MCAP_PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'


def parse_topic_map(items: Sequence[str], option: str = '--topic') -> dict[str, str]:
    """The one parser of a topic map (``replay --topic`` and the ``chamber_replay`` node's ``topic_map``):
    ``['/joint_states=/gimbal/joint_states']`` -> ``{'/joint_states': '/gimbal/joint_states'}`` (contract topic ->
    name recorded in the bag). ConfigError naming ``option`` for an entry without ``=`` or a key that is not a
    chamber-test topic.

    >>> parse_topic_map([' /joint_states = /gimbal/joint_states'])
    {'/joint_states': '/gimbal/joint_states'}
    """
    out = {}
    for item in items:
        if '=' not in item:
            raise ConfigError(option, 'expected CONTRACT=BAG, e.g. /joint_states=/gimbal/joint_states', item)
        key, value = (x.strip() for x in item.split('=', 1))
        if key not in CHAMBER_TOPICS:
            raise ConfigError(option, f'{key} is not a chamber-test topic ({", ".join(CHAMBER_TOPICS)})', item)
        out[key] = value
    return out
