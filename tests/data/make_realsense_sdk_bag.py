"""Make ``realsense_sdk2.56.5.bag``: a ROS 1 RealSense recording written by librealsense's
own recorder (SDK 2.56.5, the last whose recorder writes ROS 1 ``.bag``), without a camera.

pyrealsense2 2.59 (the project's) records only ``.db3``; this file is what an existing
user recording is, made by the SDK itself rather than by ``tests/_realsense_ros1.py``.
Run once, with the old SDK ahead of the project's on the path::

    pip install --no-deps --target /tmp/rs256 pyrealsense2==2.56.5.9235
    PYTHONPATH=/tmp/rs256:. python tests/data/make_realsense_sdk_bag.py

Content (``frames()``, checked by ``tests/test_depth_camera_sources.py``): 3 frames of
64 × 48, depth ``1000 + 10 x + 100 y + i`` mm, infrared 1 ``(4 x + 2 y + 8 i) mod 256``,
device stamps 1000, 1100, 1200 ms; fx = fy = 40 px, principal point (31.5, 23.5), baseline
50 mm (the D435's), depth units 1 mm.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from protocols.camera import StereoIntrinsics

HERE = Path(__file__).resolve().parent
BAG = HERE / "realsense_sdk2.56.5.bag"
K = StereoIntrinsics(64, 48, 40.0, 40.0, 31.5, 23.5, 0.050)
N_FRAMES = 3


def frames() -> list[tuple[np.ndarray, np.ndarray]]:
    """The recorded (depth [mm] uint16, infrared 1 uint8) planes."""
    y, x = np.mgrid[0 : K.height_px, 0 : K.width_px]
    return [
        (
            (1000 + 10 * x + 100 * y + i).astype(np.uint16),
            ((4 * x + 2 * y + 8 * i) % 256).astype(np.uint8),
        )
        for i in range(N_FRAMES)
    ]


def main() -> None:
    import pyrealsense2 as rs

    sys.path.insert(0, str(HERE.parent))
    from _realsense_recorder import record_with_sdk

    BAG.unlink(missing_ok=True)
    record_with_sdk(rs, BAG, K, frames())
    print(f"{BAG} ({BAG.stat().st_size} bytes) by {rs.__file__}")


if __name__ == "__main__":
    main()
