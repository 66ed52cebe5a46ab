"""ROS 2 nodes: thin rclpy adapters (declare parameters, convert messages, publish) around one library object each.

May import every library folder; nothing imports nodes.
"""
