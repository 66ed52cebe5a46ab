"""Whole runs built from the parts: the loop study offline and live, the process supervisor (also the main job's).

May import every library folder; never nodes' internals or cli (it starts nodes and commands as processes).
"""
