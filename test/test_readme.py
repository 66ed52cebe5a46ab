"""The README's examples run (the parameters are documented in docs/ros.md: test/test_docs.py checks it)."""

from __future__ import annotations

import doctest
from pathlib import Path

README = Path(__file__).resolve().parents[1] / 'README.md'


def test_readme_doctest():
    result = doctest.testfile(str(README), module_relative=False, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 2 and result.failed == 0
