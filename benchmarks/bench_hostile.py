"""plant-sim under floods (issue 10): another client's heartbeat gap, per flood kind.

Starts a real ``python -m plant_sim`` on 127.0.0.1 for each flood, floods its MAVLink port
for 10 s at 5,000 messages/s from one peer while a second client watches the 1 Hz
heartbeat, and prints the largest gap (goal < 1.5 s) and what plant-sim dropped.
Asserts nothing. Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_hostile.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from _hostile import flood_and_watch_heartbeats  # noqa: E402
from _plant_sim_proc import PlantProcess  # noqa: E402

RATE_HZ, DURATION_S = 5000.0, 10.0


def _floods() -> dict[str, bytes]:
    enc = mavlink.MAVLink(None, srcSystem=66, srcComponent=190)
    return {
        "PARAM_REQUEST_LIST": mavlink.MAVLink_param_request_list_message(1, 1).pack(enc),
        "MISSION_REQUEST_LIST": mavlink.MAVLink_mission_request_list_message(1, 1, 0).pack(enc),
        "COMMAND_LONG REQUEST_MESSAGE": mavlink.MAVLink_command_long_message(
            1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0
        ).pack(enc),
        "TIMESYNC": mavlink.MAVLink_timesync_message(0, 1).pack(enc),
    }


def main() -> int:
    print(f"flood {RATE_HZ:.0f}/s for {DURATION_S:.0f} s from one peer; heartbeat gap goal < 1.5 s")
    for name, frame in _floods().items():
        plant = PlantProcess(["--mavlink", "udpin:127.0.0.1:0", "--no-logs", "--no-camera"])
        try:
            plant.wait_ready()
            sent, gap_s = flood_and_watch_heartbeats(
                plant.mavlink_port, bytes(frame), RATE_HZ, DURATION_S
            )
            stats = plant.stop() or {}
        finally:
            plant.close()
        limited = sum(stats.get("rate_limited", {}).values())
        print(
            f"{name:30s} sent {sent:6d}  largest heartbeat gap {gap_s:5.2f} s  "
            f"rate-limited {limited:6d}  received {stats.get('link', {}).get('frames_ok', 0):6d}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
