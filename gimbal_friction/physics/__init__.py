"""The paper's equations (Yu & Shang 2017): Hertz contact, thermal fits, Walther viscosity, friction components.

Pure numpy/scipy: no rclpy, no file or bag I/O. May import only gimbal_friction.common.
"""
