#!/usr/bin/env bash
# Sets up .venv (scripts/setup.sh) and runs the whole test suite. Usage: bash scripts/test.sh [pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# every ROS process started by the tests stays on loopback; tests pick their own ROS_DOMAIN_ID and log dir
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOG_DIR="${ROS_LOG_DIR:-$(mktemp -d)}"
export MPLBACKEND=Agg
exec .venv/bin/python -m pytest "$@"
