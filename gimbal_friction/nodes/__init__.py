"""ROS 2 nodes: thin rclpy adapters around gimbal_friction.core (declare params, convert messages, publish)."""
