#!/usr/bin/env bash
# The main job: sets up .venv, then replays the sample chamber-test bag live through the three nodes
# (friction_feedforward, friction_estimator, residual_logger + chamber_replay at 20x), refits the lubricant
# viscosity from the residual log and draws the report. Usage: bash scripts/demo.sh [--rate 20] [--out DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST MPLBACKEND=Agg
exec .venv/bin/python -m gimbal_friction.demo "$@"
