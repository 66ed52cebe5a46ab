"""Topic names and message types of the contract (docs/ros.md), shared by nodes, bags and logs."""

from __future__ import annotations

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
