"""The command sets numpy's huge-page advice off (numpy's documented ``NUMPY_MADVISE_HUGEPAGE``) before numpy is
imported, and leaves a user's own setting alone."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

PROBE = ("import sys, os; import gimbal_friction.cli.main; "
         "print(os.environ.get('NUMPY_MADVISE_HUGEPAGE'), 'numpy' in sys.modules)")


def _probe(env: dict[str, str]) -> str:
    return subprocess.run([sys.executable, '-c', PROBE], env=env, capture_output=True, text=True, check=True,
                          timeout=120).stdout.strip()


def test_the_command_turns_numpys_huge_page_advice_off_before_numpy_is_imported():
    env = {k: v for k, v in os.environ.items() if k != 'NUMPY_MADVISE_HUGEPAGE'}
    code = ("import sys, os; import gimbal_friction.cli; "
            "print(os.environ.get('NUMPY_MADVISE_HUGEPAGE'), 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True, check=True,
                         timeout=120).stdout.strip()
    assert out == '0 False'                      # set, and numpy not yet imported: numpy will read it
    assert _probe(env).split()[0] == '0'         # still set once the command's modules (numpy too) are loaded


@pytest.mark.parametrize('value', ['1', '0'])
def test_a_users_own_setting_is_kept(value):
    env = dict(os.environ, NUMPY_MADVISE_HUGEPAGE=value)
    assert _probe(env).split()[0] == value
