"""Whole runs built from the parts: the main job (demo), the loop study offline and live, the process supervisor.

May import every library folder; never nodes' internals or cli (it starts nodes and commands as processes).
"""
