"""Measuring friction from motor current: K_T calibration (Eq. 23), the estimator's gates, statistics, residuals.

One implementation for the live estimator node, replay, the simulator and fleet.
May import common, physics and streams; never recording, nodes or cli.
"""
