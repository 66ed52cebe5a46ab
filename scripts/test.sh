#!/usr/bin/env bash
# Sets up .venv (scripts/setup.sh) and runs the whole test suite. Usage: bash scripts/test.sh [pytest args]
# The tests run in parallel (pytest-xdist): TEST_WORKERS processes (default auto: one per core), each test file
# whole on one worker (its module fixtures computed once). Any pytest argument passes through after these, so
# `-n 0` runs everything in this process (for --pdb or a single quick test) and `-n 4` sets the worker count.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# every ROS process started by the tests stays on loopback; tests pick their own ROS_DOMAIN_ID and log dir
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOG_DIR="${ROS_LOG_DIR:-$(mktemp -d)}"
export MPLBACKEND=Agg
exec .venv/bin/python -m pytest -n "${TEST_WORKERS:-auto}" --dist loadfile "$@"
