#!/usr/bin/env bash
# Create (or refresh) the project's virtual environment in .venv with everything the
# demo and the tests need. Idempotent: re-running only installs what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e '.[dev]'
# A real ground station for the integration tests. --no-deps: MAVProxy's requirements
# would replace opencv-python-headless with the GUI opencv-python 5.x (see pyproject).
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps 'mavproxy==1.8.75'
