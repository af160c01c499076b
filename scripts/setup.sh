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
# .[dev] = tests + the optional extras: [view] (Rerun, MCAP, rosbags: issue 15's tests),
# [realsense] and [eval] (figures, Monte Carlo on Dask)
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e '.[dev]'
# A real ground station for the integration tests. --no-deps: MAVProxy's requirements
# would replace opencv-python-headless with the GUI opencv-python 5.x (see pyproject).
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps 'mavproxy==1.8.75'
# Headless Chromium for the live web-view test (tests/test_view_sil.py): Debian's package,
# installed when missing and apt is usable (root, or passwordless sudo); otherwise say so.
if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""
        if [ "$(id -u)" -ne 0 ]; then
            if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
                SUDO="sudo -n"
            fi
        fi
        if [ "$(id -u)" -eq 0 ] || [ -n "$SUDO" ]; then
            echo "setup: installing chromium (apt) for the web-view test" >&2
            $SUDO apt-get update -qq
            DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends chromium
        else
            echo "setup: chromium missing and apt needs root: install Debian's 'chromium' package" >&2
        fi
    else
        echo "setup: chromium missing (no apt): install Chromium for tests/test_view_sil.py" >&2
    fi
fi
# pyrealsense2 (the [realsense] extra) loads libusb-1.0: Debian's libusb-1.0-0, when missing
# and apt is usable as root (tests/test_depth_camera_sources.py plays back a recording).
if ! ldconfig -p 2>/dev/null | grep 'libusb-1.0.so.0' >/dev/null; then
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" -eq 0 ]; then
        echo "setup: installing libusb-1.0-0 (apt) for pyrealsense2" >&2
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libusb-1.0-0
    else
        echo "setup: libusb-1.0 missing: install it for pyrealsense2 (stereo-camera realsense)" >&2
    fi
fi
# Compile the numba kernels into their cache once (~50 s on a fresh install, seconds after):
# otherwise the first plant-sim, companion, Monte Carlo worker or test pays it at its first
# frame.
.venv/bin/stereo-avoid compile
