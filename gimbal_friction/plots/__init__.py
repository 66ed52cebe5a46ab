"""Figures (matplotlib, loaded lazily): the paper's figures, model vs measured, KT, refit and fleet plots.

May import common and physics; never nodes or cli.
"""
