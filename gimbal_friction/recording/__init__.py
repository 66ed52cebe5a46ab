"""File I/O of the suite (no rclpy): chamber-test bags in, residual logs (MCAP) out, CDR, recovery of damaged files.

May import common, physics and streams; never feedforward rules, refit, nodes or cli.
"""
