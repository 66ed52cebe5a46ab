"""Refitting the model to measured friction: sufficient statistics, the weighted fit (results, model, problem,
identifiability, fit) with intervals and identifiability, reading logs, JSON records and the refit run.

May import common, physics, streams, feedforward (the learned correction), estimation and recording (reading
residual logs); never nodes or cli.
"""
