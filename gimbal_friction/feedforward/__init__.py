"""The feedforward rule (direction, smooth sign, freshness, stale policy, clamp) and its learned correction.

One implementation used by the node, the in-process API (gimbal_friction.controller), replay and the simulator.
May import common, physics and streams; never recording, nodes or cli.
"""
