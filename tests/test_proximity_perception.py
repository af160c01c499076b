"""A reporting-only companion keeps up with the camera however slow guidance is (issue 34).

Real processes on 127.0.0.1: plant-sim (ArduCopter flavour, hovering in LOITER, the
paper's sphere 10 m ahead, 30 Hz stereo) and a companion that never asks for a mode and
whose guidance costs an artificial 0.2 s a step (``tests/_slow_guidance_companion.py``).
Guidance is skipped while the companion is not in control, so the companion processes
most frames; had it run, at most one frame in six would have been processed (30 Hz
against 0.2 s a frame). Every wait bounded; the children's logs printed on failure.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
from pathlib import Path

import pytest
from _plant_sim_proc import PlantProcess

from evaluation.sil import ChildProcess, free_port

pytestmark = [pytest.mark.processes, pytest.mark.slow]

_SCENE = """\
profile = "fast"
goal_ned_m = [0.0, 0.0, -7.0]

[start]
pos_ned_m = [20.0, 0.0, -7.0]
yaw_deg = 180.0
airborne = true
mode = "LOITER"

[[obstacles]]
center_ned_m = [10.0, 0.0, -7.0]
radius_m = 1.5
"""
_GUIDANCE_COST_S = 0.2
_SIM_S = 6.0


def test_reporting_companion_processes_most_frames_however_slow_guidance_is(tmp_path):
    """Frames processed / received ≥ 1.5 × what guidance at 0.2 s a step would allow
    (≤ 1/6 of the 30 Hz frames had it run on them): 0.25 (measured 0.39 at load 18-20,
    the other engineers' work on 2 cores), guidance run on no frame and skipped on every
    processed one, the map and the sectors made on every one."""
    scene = tmp_path / "hover.toml"
    scene.write_text(_SCENE, encoding="utf-8")
    mav_port = free_port()
    companion_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    tests_dir = str(Path(__file__).resolve().parent)
    env = {
        "PYTHONPATH": os.pathsep.join(filter(None, [tests_dir, os.environ.get("PYTHONPATH")])),
        "SLOW_GUIDANCE_S": f"{_GUIDANCE_COST_S:g}",
    }
    companion = ChildProcess(
        "companion",
        "_slow_guidance_companion",
        ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", companion_zenoh,
         "--no-request-mode"],
        env=env,
    )  # fmt: skip
    with contextlib.ExitStack() as stack:
        stack.callback(companion.close)
        stack.callback(lambda: print(companion.logs()))
        companion.wait_line(r"^COMPANION READY ", 60)
        plant = PlantProcess(
            ["--scenario", str(scene), "--mavlink", f"udpin:127.0.0.1:{mav_port}",
             "--zenoh-listen", f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}",
             "--zenoh-connect", companion_zenoh, "--duration", f"{_SIM_S:g}",
             "--log-dir", str(tmp_path / "run"), "--autopilot-flavour", "ardupilot"],
        )  # fmt: skip
        stack.callback(plant.close)
        stack.callback(lambda: print(plant.logs()))
        plant.wait_ready()
        plant.proc.wait(timeout=3.0 * _SIM_S + 60.0)
        plant_stats = plant.stop()
        assert plant_stats is not None and plant_stats["obstacle_distance_received"] > 0
        companion.stop()
        stats = json.loads(companion.wait_line(r"^COMPANION STATS (.*)$", 10.0).group(1))
        received, processed = stats["frames_received"], stats["frames_processed"]
        phases = stats["phases"]
        print(f"frames received {received}, processed {processed}; phases {phases}")
        assert received >= 0.5 * 30.0 * _SIM_S, received
        had_guidance_run = received / 30.0 / _GUIDANCE_COST_S  # frames' seconds / cost
        assert processed >= 1.5 * had_guidance_run, (processed, received)
        assert "steering" not in [name for name, _ in companion.events()]
        assert phases["guidance"]["runs"] == 0
        assert phases["guidance"]["skipped"] == processed
        assert phases["envelope"]["skipped"] == processed
        for phase in ("perception", "known_space", "sectors"):
            assert phases[phase]["runs"] == processed, phase
        assert stats["obstacle_distance_sent"] >= processed
