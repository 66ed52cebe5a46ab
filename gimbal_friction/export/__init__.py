"""The model (and its learned correction) as an interpolation table with an error bound: CSV, C header, ROS YAML.

May import common, physics, streams and feedforward; never recording, nodes or cli.
"""
