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
import time

import cv2
import numpy as np
from _companion_rig import VEHICLE_ID, companion_rig, sees_sphere

from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import GroundPlane, Sphere, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321

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
    with companion_rig() as rig:
        camera = rig.start(
            "stereo-camera",
            "companion.camera",
            ["replay", str(rec), "--rate", f"{RATE_HZ:g}", "--zenoh-connect",
             rig.companion_zenoh, "--vehicle-id", VEHICLE_ID],
        )  # fmt: skip
        camera.wait_line(r"^STEREO_CAMERA READY ", 30)
        docs = rig.docs
        assert rig.avoiding.wait(N_PAIRS / RATE_HZ + 10.0), (
            f"no avoiding status in {len(docs)} docs\n{rig.logs()}"
        )
        # the obstacle model guidance steers on (the map's boundaries, status schema 2)
        first = next(d for d in docs if d["obstacles"])
        why = sees_sphere(first, START_NED_M, OBSTACLE)
        assert why is None, why
        assert any(d["mode"] == "avoid" for d in docs)
        deadline = time.monotonic() + 5.0  # and it steers the autopilot
        while not any(d["setpoint_sent"] for d in docs) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert any(d["setpoint_sent"] for d in docs), rig.logs()
