#!/usr/bin/env bash
# Set up .venv if needed, then run the main job. Results land in bags/ (ignored by git).
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
bash tools/bootstrap.sh

export VIRTUAL_ENV="$repo/.venv"
export PATH="$VIRTUAL_ENV/bin:$PATH"
unset PYTHONHOME
mkdir -p bags

# ---- main job: the paper's rig, 0 -> 65 mL -> 0 at 0.05 mL/s, pump 50 Hz, camera 10 Hz ----
# Runs the pump, actuator and camera nodes in lock-step simulated time, records every topic to
# bags/paper (an MCAP bag in the rosbag2 layout), then prints a summary and writes figures to
# bags/paper/report/. A previous bags/paper from this script is replaced.
rm -rf bags/paper
softseq run paper --out bags/paper
