"""Robustness tests (a package, so that its conftest does not clash with test/ros/conftest.py)."""
