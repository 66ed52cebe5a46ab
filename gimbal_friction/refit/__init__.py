"""Refitting the model to measured friction: sufficient statistics, the weighted fit with intervals and identifiability.

May import common, physics, streams, estimation and recording (reading residual logs); never nodes or cli.
"""
