"""The main job, ``python -m gimbal_friction.demo`` (this name is kept for users).

The code is in :mod:`gimbal_friction.runs.demo`.
"""

from __future__ import annotations

import sys

from gimbal_friction.runs.demo import main

if __name__ == '__main__':
    sys.exit(main())
