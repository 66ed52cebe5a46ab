#!/usr/bin/env bash
# Creates .venv (if needed) with ROS 2 Kilted from the PyPI wheels and the project installed editable.
# Idempotent: re-installs only when requirements*.txt or setup.py changed. Usage: bash scripts/setup.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(0 if (3, 10) <= sys.version_info[:2] <= (3, 12) else 1)'; then
  echo "setup: need CPython 3.10-3.12 for the ROS 2 wheels (set PYTHON=/path/to/python3.11)" >&2
  exit 1
fi
stamp=$(cat requirements.txt requirements-test.txt setup.py | sha256sum | cut -c1-16)
if [ -x .venv/bin/python ] && [ "$(cat .venv/.gimbal_friction_stamp 2>/dev/null)" = "$stamp" ]; then
  exit 0
fi
echo "setup: creating .venv and installing ROS 2 wheels + dependencies (about a minute on a fresh machine)" >&2
[ -x .venv/bin/python ] || "$PY" -m venv .venv
quiet() { grep -v -e "^WARNING: Location 'file:" -e '^$' || true; }
.venv/bin/python -m pip install -q --disable-pip-version-check -r requirements-test.txt 2>&1 | quiet
.venv/bin/python -m pip install -q --disable-pip-version-check --no-deps -e . 2>&1 | quiet
.venv/bin/python -c 'import rclpy, sensor_msgs.msg, diagnostic_msgs.msg, scipy, mcap_ros2, rosbags, gimbal_friction'
echo "$stamp" > .venv/.gimbal_friction_stamp
echo "setup: .venv ready" >&2
