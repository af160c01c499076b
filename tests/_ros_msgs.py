"""ROS 2 messages for the camera tests, built with rosbags' typestore (no ROS install):
images, CameraInfo of the stereo convention, and the scene the bag tests film (plant-sim's
default start facing south, a sphere whose surface is 3 m ahead of the camera)."""

from __future__ import annotations

import numpy as np
from rosbags.typesys import Stores, get_typestore

from plant_sim.world import Sphere

__all__ = [
    "OBSTACLE",
    "START_NED_M",
    "TS",
    "CameraInfo",
    "Header",
    "Image",
    "Time",
    "_header",
    "_image",
    "_info",
]

TS = get_typestore(Stores.ROS2_HUMBLE)
Image = TS.types["sensor_msgs/msg/Image"]
CameraInfo = TS.types["sensor_msgs/msg/CameraInfo"]
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]
ROI = TS.types["sensor_msgs/msg/RegionOfInterest"]

START_NED_M = np.array([20.0, 0.0, -7.0])  # plant-sim's default start, facing south
OBSTACLE = Sphere((20.0 - 1.5 - 3.0, 0.0, -7.0), 1.5)  # surface 3 m ahead of the camera


def _header(stamp_ns: int, frame_id: str = "camera") -> object:
    return Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame_id)


def _image(stamp_ns: int, pixels: np.ndarray, encoding: str = "mono8") -> object:
    h, w = pixels.shape[:2]
    data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
    step = data.size // h
    return Image(
        header=_header(stamp_ns),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=data,
    )


def _info(stamp_ns: int, k, tx: float) -> object:
    p = np.array([k.fx_px, 0, k.cx_px, tx, 0, k.fy_px, k.cy_px, 0, 0, 0, 1, 0], dtype=float)
    kk = np.array([k.fx_px, 0, k.cx_px, 0, k.fy_px, k.cy_px, 0, 0, 1], dtype=float)
    return CameraInfo(
        header=_header(stamp_ns),
        height=k.height_px,
        width=k.width_px,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=kk,
        r=np.eye(3).reshape(-1),
        p=p,
        binning_x=0,
        binning_y=0,
        roi=ROI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )
