"""Topic names and message types of the contract (CONTRACT.md), shared by nodes, bags and logs."""

from __future__ import annotations

TEMPERATURE = '/gimbal/temperature'
JOINT_STATES = '/joint_states'
MOTOR_CURRENT = '/gimbal/motor_current'
FEEDFORWARD = '/gimbal/friction/feedforward'
FEEDFORWARD_COMMANDS = '/gimbal/friction/feedforward_commands'
MEASURED = '/gimbal/friction/measured'
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

#: data[] layout of RESIDUAL_DETAIL (SI units; torques in N*m, temperature in degC as sensor_msgs/Temperature)
RESIDUAL_FIELDS = (
    'stamp_s',          # stamp of the measured sample [s]
    'temperature_c',    # bearing temperature used for the prediction [degC]
    'position_rad',     # joint position [rad]
    'velocity_rad_s',   # joint velocity [rad/s]
    'current_a',        # motor current [A]
    'measured_nm',      # measured friction, signed [N*m]
    'predicted_nm',     # model feedforward, signed [N*m]
    'm_rolling_nm',     # model M_R magnitude [N*m]
    'm_sliding_nm',     # model M_S magnitude [N*m]
    'm_viscous_nm',     # model M_L magnitude [N*m]
    'residual_nm',      # measured - predicted [N*m]
)
