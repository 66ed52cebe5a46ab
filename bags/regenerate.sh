#!/bin/sh
# Regenerates the shipped sample chamber-test bag bags/chamber_sample/ and its truth bags/chamber_sample.truth.yaml.
# The output is fully determined by these options (seeded); see bags/README.md.
# Uses `gimbal-friction` from PATH, or `$PYTHON -m gimbal_friction.cli.main` (PYTHON defaults to python3).
set -eu
cd "$(dirname "$0")/.."
if command -v gimbal-friction >/dev/null 2>&1; then GF="gimbal-friction"; else GF="${PYTHON:-python3} -m gimbal_friction.cli.main"; fi
$GF synth-bag --out bags/chamber_sample --force --seed 2017 --plateaus=-40,-20,0,20,40,60 --hold-s 40 --ramp-rate 15 --bearing-lag-s 30 --joint-rate-hz 25 --temperature-rate-hz 2 --storage mcap --compression zstd --truth-out bags/chamber_sample.truth.yaml
