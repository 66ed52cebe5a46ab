#!/usr/bin/env bash
# The main job: sets up .venv, then prints the paper's Fig. 11 table from the model and writes the figures.
# Usage: bash scripts/demo.sh [OUT_DIR]   (default OUT_DIR=out/demo)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST MPLBACKEND=Agg
OUT=${1:-out/demo}
mkdir -p "$OUT"
.venv/bin/gimbal-friction model --temperature -40:60:10 --plot "$OUT/fig11_model.png"
.venv/bin/gimbal-friction report --out "$OUT/report" > /dev/null
echo "figures: $OUT/fig11_model.png and $OUT/report/*.png"
