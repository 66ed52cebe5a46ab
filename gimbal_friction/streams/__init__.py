"""Plain records of the suite's data streams and the input rules shared by live nodes and offline replay.

Arrays of a chamber bag, joint lookup and temperature freshness, the measurement and the residual row (no I/O).
May import gimbal_friction.common only.
"""
