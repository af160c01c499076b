#!/usr/bin/env bash
# The project's demo command (README): set up .venv, then fly the paper's §6 scenario in
# lockstep (plant + synthetic stereo camera + the companion's perception and guidance),
# print progress and a verdict, and write Fig. 6-11, the time history and verdict.json
# into runs/paper/. Extra arguments go to `stereo-avoid paper` (e.g. --json).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export OPENBLAS_NUM_THREADS=1
exec .venv/bin/stereo-avoid paper --out runs/paper "$@"
