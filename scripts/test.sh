#!/usr/bin/env bash
# The project's test command (README): set up .venv, lint, then run the whole suite.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -k frames`.
# `bash scripts/test.sh --fast`: the fast loop, tiers `unit`, `contracts` and the quick part of
# `lockstep` (the paper's §6, walls, waypoints, the envelope's kills, the views): no process,
# SITL or Dask cluster, and none of the `slow` lockstep flights (the Monte Carlo samples,
# the speed bound at the fast airframe; tiers in tests/_tiers.py and docs/testing.md).
set -euo pipefail
cd "$(dirname "$0")/.."
select=()
if [ "${1:-}" = "--fast" ]; then
    shift
    select=(-m "not processes and not (lockstep and slow)")
fi
bash scripts/setup.sh
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
.venv/bin/ruff check .
.venv/bin/ruff format --check .
# Two workers by default (PYTEST_WORKERS=0, or `-n 0`: one process). --dist loadscope with
# tests/_schedule.py: a module's tests share one worker, so module-scoped fixtures (a lockstep
# run, the SITL binary) are built once and a file's flights never run beside each other,
# while each `own_flight` test (a Monte Carlo seed, a speed-bound scene) is a unit of its
# own; units go out longest first, in the order tests/conftest.py sorts them.
.venv/bin/python -m pytest -n "${PYTEST_WORKERS:-2}" --dist loadscope --no-loadscope-reorder \
    "${select[@]}" "$@"
