"""The feedforward rule, its learned correction and the in-process API. May import physics (gimbal_friction.core
today); never nodes or cli."""
