"""The doctests of gimbal_friction.sim (pytest.ini collects doctests from gimbal_friction/core only)."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ['config', 'lugre', 'truth', 'profiles', 'compensation', 'metrics', 'realtime']


@pytest.mark.parametrize('name', MODULES)
def test_module_doctests(name):
    module = importlib.import_module(f'gimbal_friction.sim.{name}')
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS)
    assert result.attempted > 0
    assert result.failed == 0
