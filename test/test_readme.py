"""The README's example runs, and every model parameter is documented in it."""

from __future__ import annotations

import doctest
from pathlib import Path

from gimbal_friction.physics.params import parameter_specs

README = Path(__file__).resolve().parents[1] / 'README.md'


def test_readme_doctest():
    result = doctest.testfile(str(README), module_relative=False, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 2 and result.failed == 0


def test_readme_documents_every_parameter():
    text = README.read_text(encoding='utf-8')
    missing = [s['name'] for s in parameter_specs() if f"`{s['name']}`" not in text]
    assert missing == []
