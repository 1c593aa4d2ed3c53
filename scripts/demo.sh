#!/usr/bin/env bash
# Set everything up and run a simulated trial end to end (simulated hardware, no device needed).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
. scripts/ros_env.sh
out="${1:-out/demo}"
mkdir -p "$out"
.venv/bin/mantis sim --scene air_23mm --out "$out/air_23mm_trajectory.csv" --plot "$out/air_23mm.png"
