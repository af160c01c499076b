#!/usr/bin/env bash
# The project's demo command (README): set up .venv, then fly the paper's §6 scenario
# software-in-the-loop: plant-sim (autopilot + world + stereo camera) and the companion
# run as two processes talking MAVLink over UDP and Zenoh on loopback, at 4x speed.
# Prints progress and a verdict; writes Fig. 6-11, the ground-truth and time-history
# CSVs, the MAVLink .tlog, both processes' logs and verdict.json into runs/demo/.
# Extra arguments go to `stereo-avoid sil` (e.g. --json, --speedup 1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export OPENBLAS_NUM_THREADS=1
exec .venv/bin/stereo-avoid sil --out runs/demo "$@"
