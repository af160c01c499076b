"""Depth-camera recordings drive a running companion (issue 35), as
``test_rosbag_source.py`` does for pairs: plant-sim as the autopilot only (hovering at the
paper's start, facing south), the companion with ``--frame-clock host``, and
``stereo-camera`` publishing depth frames of an obstacle 3 m ahead from (a) a ROS 2 bag
with a depth topic written by rosbags and (b) a RealSense ROS 1 ``.bag`` written without a
camera in librealsense's layout and read by pyrealsense2's own playback (``stereo-camera
realsense --bag``; the ``.db3`` pyrealsense2 2.59 records takes the same path after the
source and is read back frame for frame in ``test_depth_camera_sources.py``). The
companion (which runs no matcher on them) must place the obstacle where it is and start
avoiding it.
"""

from __future__ import annotations

import pytest
from _companion_rig import VEHICLE_ID, companion_rig, sees_sphere
from _ros_msgs import OBSTACLE, START_NED_M
from test_depth_camera_sources import DEPTH, PICTURE, write_depth_bag, write_realsense_bag


def _drives_the_companion(rig, camera, n_frames, rate_hz):
    ready = camera.wait_line(r"^STEREO_CAMERA READY ", 30)
    assert "size=320x240" in ready.string and "rectify=depth-camera" in ready.string, ready
    assert rig.avoiding.wait(n_frames / rate_hz + 15.0), (
        f"no avoiding status in {len(rig.docs)} docs\n{rig.logs()}"
    )
    # the obstacle model guidance steers on (the map's boundaries, status schema 2)
    first = next(d for d in rig.docs if d["obstacles"])
    why = sees_sphere(first, START_NED_M, OBSTACLE)
    assert why is None, why
    log = rig.companion.stderr_text()
    assert "bad camera frame" not in log and "unsupported pixel encoding" not in log
    assert "DEPTH16 320x240 (depth camera, no matcher)" in log, log[-3000:]


@pytest.mark.slow
def test_ros2_depth_bag_drives_the_companion(tmp_path):
    n, rate_hz = 60, 10.0
    write_depth_bag(tmp_path / "bag", n=n, rate_hz=rate_hz)
    with companion_rig() as rig:
        camera = rig.start(
            "stereo-camera",
            "companion.camera",
            ["replay", str(tmp_path / "bag"), "--depth", DEPTH, "--image", PICTURE,
             "--baseline", "0.2", "--zenoh-connect", rig.companion_zenoh,
             "--vehicle-id", VEHICLE_ID],
        )  # fmt: skip
        _drives_the_companion(rig, camera, n, rate_hz)


@pytest.mark.slow
def test_realsense_bag_drives_the_companion(tmp_path):
    """The issue's Done-when: a ``.bag`` made without a camera, read by pyrealsense2's
    playback, replays through ``stereo-camera realsense --bag`` into the companion (the
    ``.db3`` takes the same path after the source: read back frame for frame in
    ``test_depth_camera_sources.py``)."""
    pytest.importorskip("pyrealsense2")
    n, rate_hz = 60, 10.0
    path = tmp_path / "rec.bag"
    write_realsense_bag(path, n=n, rate_hz=rate_hz)
    with companion_rig() as rig:
        camera = rig.start(
            "stereo-camera",
            "companion.camera",
            ["realsense", "--bag", str(path), "--zenoh-connect", rig.companion_zenoh,
             "--vehicle-id", VEHICLE_ID],
        )  # fmt: skip
        _drives_the_companion(rig, camera, n, rate_hz)
