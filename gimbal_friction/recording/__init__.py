"""File I/O of the suite (no rclpy): chamber-test bags in, residual logs (MCAP) out, CDR, recovery of damaged files.

May import common, physics, streams and estimation (the K_T fit of a calibration read); never feedforward rules,
refit, nodes or cli.
"""
