"""A RealSense recording made by pyrealsense2 itself, without a camera: its software device
under its own recorder. Whichever SDK is imported writes its own format: 2.59 a ROS 2
``.db3``, 2.58 and older a ROS 1 ``.bag`` (``tests/data/make_realsense_sdk_bag.py``)."""

from __future__ import annotations

import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from protocols.camera import StereoIntrinsics

__all__ = ["record_with_sdk"]


def record_with_sdk(
    rs,
    path: Path | str,
    k: StereoIntrinsics,
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    *,
    rate_hz: float = 10.0,
    first_stamp_ms: float = 1000.0,
) -> None:
    """Record (Z16 depth plane [mm], Y8 infrared 1 picture) frames with the module ``rs``
    (``pyrealsense2``): a "Stereo Module" with depth, infrared 1 and 2 streams of ``k``'s
    intrinsics at 30 fps, "Depth Units" 0.001 m, the baseline as the "Stereo Baseline"
    option [mm] and the infrared 1 → 2 extrinsics; device stamps ``rate_hz`` apart from
    ``first_stamp_ms``."""
    device = rs.software_device()
    sensor = device.add_sensor("Stereo Module")
    intr = rs.intrinsics()
    intr.width, intr.height = k.width_px, k.height_px
    intr.fx, intr.fy, intr.ppx, intr.ppy = k.fx_px, k.fy_px, k.cx_px, k.cy_px
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5

    def stream(kind, index, bpp, fmt):
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid = kind, index, index
        vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = k.width_px, k.height_px, 30, bpp, fmt
        vs.intrinsics = intr
        return sensor.add_video_stream(vs)

    depth = stream(rs.stream.depth, 0, 2, rs.format.z16)
    ir1 = stream(rs.stream.infrared, 1, 1, rs.format.y8)
    ir2 = stream(rs.stream.infrared, 2, 1, rs.format.y8)
    sensor.add_read_only_option(rs.option.depth_units, 0.001)
    sensor.add_read_only_option(rs.option.stereo_baseline, 1000.0 * k.baseline_m)
    to_ir2 = rs.extrinsics()
    to_ir2.rotation, to_ir2.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [-k.baseline_m, 0, 0]
    ir1.register_extrinsics_to(ir2, to_ir2)
    recorder = rs.recorder(str(path), device)
    sensor.open([depth, ir1])
    sensor.start(rs.frame_queue(100))
    for i, (plane, left) in enumerate(frames):
        for profile, pixels, bpp in ((ir1, left, 1), (depth, plane, 2)):
            frame = rs.software_video_frame()
            frame.pixels, frame.bpp = np.ascontiguousarray(pixels), bpp
            frame.stride = bpp * k.width_px
            frame.timestamp = first_stamp_ms + i * 1000.0 / rate_hz
            frame.domain, frame.frame_number = rs.timestamp_domain.hardware_clock, i
            frame.profile = profile.as_video_stream_profile()
            sensor.on_video_frame(frame)
        time.sleep(0.005)  # the recorder writes from its own thread
    sensor.stop()
    sensor.close()
    del recorder  # closes the file
