"""The companion's pure core, in process (no sockets, no sleeps): pipeline and core."""

from __future__ import annotations

import math

import numpy as np

from companion.pipeline import AvoidancePipeline, PoseAtCapture
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import StereoFrame

CAMERA = CameraModel()


def _blank_frame(seq: int, capture_ns: int) -> StereoFrame:
    """A textureless pair: nothing matched, so no obstacle and no free space."""
    flat = np.full((CAMERA.height_px, CAMERA.width_px), 128, dtype=np.uint8)
    return StereoFrame(seq, capture_ns, CAMERA.intrinsics, flat, flat.copy())


def test_pipeline_first_yaw_is_the_vehicles_own_when_no_direction_is_defined():
    """At the goal (no direction to face) the first yaw command keeps the vehicle's yaw.

    Guidance falls back to the vehicle's yaw only if it is given one; before the fix the
    pipeline did not pass it, so a vehicle facing east was turned north (yaw 0).
    """
    yaw_east_rad = math.pi / 2
    pos = np.array([3.0, -2.0, -7.0])
    pipeline = AvoidancePipeline(goal_ned_m=pos)
    pose = PoseAtCapture(pos, np.zeros(3), rotation_321(0.0, 0.0, yaw_east_rad))
    out = pipeline.process(_blank_frame(0, 1_000_000), pose)
    assert math.isclose(out.yaw_rad, yaw_east_rad, abs_tol=1e-12), out.yaw_rad

