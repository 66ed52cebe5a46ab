"""The main job, ``python -m gimbal_friction.demo`` (this name is kept for users).

The code is in :mod:`gimbal_friction.cli.demo`; its process supervisor in :mod:`gimbal_friction.runs.supervisor`.
"""

from __future__ import annotations

import sys

from gimbal_friction.cli.demo import main

if __name__ == '__main__':
    sys.exit(main())
