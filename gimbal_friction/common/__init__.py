"""Shared ground of every layer: error types, unit conversions, the array-or-float namespace, settings coercion.

Holds no physics and no I/O. Imports nothing from gimbal_friction; everything else may import it.
"""
