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

# ---- main job: the one line to change when the main job changes ----
softseq solve config/paper.yaml --out bags/paper_solve.csv
