"""Recorded stereo pairs replayed by ``stereo-camera`` drive the companion process.

Three real processes on loopback: plant-sim (autopilot only, hovering at the paper's
start, no camera), the companion with ``--frame-clock host`` (frames stamped with this
host's monotonic clock, mapped to autopilot time with TIMESYNC, as with a real camera),
and ``stereo-camera replay`` of pairs rendered with an obstacle 3 m ahead. The companion's
Zenoh status must report that obstacle at its NED position and start avoiding it.
"""

from __future__ import annotations

import json
import math
import socket
import threading
import time

import cv2
import numpy as np
import pytest
import zenoh
from _plant_sim_proc import free_port

from plant_sim.lockstep.sil import ChildProcess
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import GroundPlane, Sphere, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.keys import companion_status_key
from protocols.zenoh_session import ZenohSettings, zenoh_config

START_NED_M = np.array([20.0, 0.0, -7.0])  # plant-sim's default start, facing south
OBSTACLE = Sphere((20.0 - 1.5 - 3.0, 0.0, -7.0), 1.5)  # surface 3 m ahead of the camera
N_PAIRS = 40
RATE_HZ = 10.0


def _record(folder) -> None:
    camera = CameraModel()
    renderer = StereoCameraRenderer(camera)
    R = rotation_321(0.0, 0.0, math.pi)
    world = World(spheres=(OBSTACLE,), ground=GroundPlane(0.0))
    pairs = []
    for i in range(N_PAIRS):
        out = renderer.render(world, START_NED_M, R, noise_seed=i)
        cv2.imwrite(str(folder / f"left_{i}.png"), out.left)
        cv2.imwrite(str(folder / f"right_{i}.png"), out.right)
        pairs.append({"left": f"left_{i}.png", "right": f"right_{i}.png"})
    k = camera.intrinsics
    intrinsics = {f: getattr(k, f) for f in k.__dataclass_fields__}
    (folder / "manifest.json").write_text(json.dumps({"pairs": pairs, "intrinsics": intrinsics}))


def test_replayed_pairs_drive_the_companion(tmp_path):
    rec = tmp_path / "recording"
    rec.mkdir()
    _record(rec)
    mav_port = free_port()
    companion_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    test_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    children: list[ChildProcess] = []
    docs: list[dict] = []
    got = threading.Event()

    def on_status(sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        docs.append(doc)
        if doc["obstacles"] and doc["avoidance_flag"]:
            got.set()

    # The status subscriber exists before the companion starts and the companion connects
    # to it, so its declaration is known before the first frame (no missed statuses).
    session = zenoh.open(zenoh_config(ZenohSettings(listen=(test_zenoh,))))
    session.declare_subscriber(companion_status_key("cam"), on_status)
    try:
        plant = ChildProcess(
            "plant-sim",
            "plant_sim",
            ["--mavlink", f"udpin:127.0.0.1:{mav_port}", "--no-camera", "--no-logs"],
        )
        children.append(plant)
        plant.wait_line(r"^PLANT_SIM READY ", 60)
        companion = ChildProcess(
            "companion",
            "companion",
            [
                "--mavlink",
                f"udpout:127.0.0.1:{mav_port}",
                "--zenoh-listen",
                companion_zenoh,
                "--zenoh-connect",
                test_zenoh,
                "--vehicle-id",
                "cam",
                "--frame-clock",
                "host",
            ],
        )
        children.append(companion)
        companion.wait_line(r"^COMPANION READY ", 60)
        camera = ChildProcess(
            "stereo-camera",
            "companion.camera",
            [
                "replay",
                str(rec),
                "--rate",
                f"{RATE_HZ:g}",
                "--zenoh-connect",
                companion_zenoh,
                "--vehicle-id",
                "cam",
            ],
        )
        children.append(camera)
        camera.wait_line(r"^STEREO_CAMERA READY ", 30)
        assert got.wait(N_PAIRS / RATE_HZ + 10.0), f"no avoiding status in {len(docs)} docs\n" + (
            "\n".join(c.logs() for c in children)
        )
        first = next(d for d in docs if d["obstacles"])
        centre = np.array(first["obstacles"][0]["center_ned_m"])
        # perception's centre error is < 0.3 m at 3 m (test_perception); the vehicle has
        # barely moved when the first frame with the obstacle is processed
        assert np.linalg.norm(centre - OBSTACLE.center_ned_m) < 0.5, centre
        assert first["obstacles"][0]["range_m"] == pytest.approx(3.0, abs=0.3)
        assert any(d["mode"] == "avoid" for d in docs)
        deadline = time.monotonic() + 5.0  # and it steers the autopilot
        while not any(d["setpoint_sent"] for d in docs) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert any(d["setpoint_sent"] for d in docs), "\n".join(c.logs() for c in children)
    finally:
        session.close()
        for child in reversed(children):
            child.stop()
        for child in children:
            child.close()
