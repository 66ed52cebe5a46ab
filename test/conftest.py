"""Hypothesis profiles for the whole suite.

``ci`` (the default): derandomized, so a run of the test command is reproducible (the same examples every time;
a failure is a bug in the code, not in the draw). ``explore``: random examples on every run (500 where a test sets no
count) — run it when hunting (``HYPOTHESIS_PROFILE=explore bash scripts/test.sh test/robustness``); a random draw
found the damaged-chunk overflow that test_files_damaged.py now pins.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile('ci', derandomize=True, print_blob=True, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile('explore', derandomize=False, print_blob=True, deadline=None,
                          max_examples=500, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))
