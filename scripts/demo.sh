#!/usr/bin/env bash
# Set everything up and run a simulated trial end to end (simulated hardware, no device needed):
# the whole node stack on the simulated rig, logged to a rosbag2/MCAP bag, then analysed; then
# the same scene as a batch simulation with its phases, metrics and plot.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
. scripts/ros_env.sh
out="${1:-out/demo}"
mkdir -p "$out"
.venv/bin/mantis trial --backend sim --scene air_23mm_rig --out "$out" | tee "$out/trial.txt"
bag="$(sed -n 's/^bag: //p' "$out/trial.txt" | head -n 1)"
.venv/bin/mantis analyze "$bag" --plot "$out/analysis.png"
.venv/bin/mantis sim --scene air_23mm_rig --out "$out/air_23mm_rig_trajectory.csv" \
  --plot "$out/air_23mm_rig_simulated.png"
