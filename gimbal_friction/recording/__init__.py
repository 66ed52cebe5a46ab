"""File I/O of the suite (no rclpy): chamber-test bags in, residual logs (MCAP) out."""
